"""Shared fixtures: one rclpy Context per test, on its own DDS domain, spun in the background."""

from collections import deque
from collections.abc import Callable, Iterator, Sequence
import faulthandler
import fcntl
import itertools
import math
import os
from pathlib import Path
import sys
import tempfile
import threading
import time

import pybullet
import pytest

# Keep every byte of DDS traffic on this host, before rclpy is imported anywhere, with the
# transports the run command uses (subprocesses inherit both).
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE',
                      str(Path(__file__).parents[1] / 'config' / 'fastdds.xml'))
# One torch thread per process, as train_policy uses: torch's spinning thread pool crawls on
# a loaded machine.
os.environ.setdefault('OMP_NUM_THREADS', '1')

import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402
from ur_rg2_common.executors import BlockingGroupExecutor  # noqa: E402
from ur_rg2_sim.world import SimWorld, WorldConfig  # noqa: E402

# The TCP's orientation with the gripper pointing straight down at the floor.
GRIPPER_DOWN = pybullet.getQuaternionFromEuler([math.pi, 0, 0])

# Tests take domain ids 1-99 (0 is a user's graph; bench/ takes ids from 100 up), spread over
# concurrent pytest runs by pid. Each id in use is held as a lock file, so that concurrent runs
# on this machine never share one: a test that met another graph on its domain received its
# robot_description, joint_states and tool_jog.
_TEST_DOMAINS = 99
_DOMAIN_LOCKS = Path(tempfile.gettempdir()) / 'ur_rg2_test_domains'
_HELD_DOMAINS = 8  # the ids of the last few tests this process holds; older ones are freed
_held_domains: deque = deque()  # (domain id, its open lock file)


def _worker_domains() -> range:
    """Return the domain ids of this pytest-xdist worker (``-n N``): a slice of its own.

    The workers of one run then never meet on a domain, not even when a module's graph (a
    module-scoped fixture) outlives the last few ids its worker holds locked. Without xdist, or
    with too many workers for a slice each, every id 1-99 (the locks keep them apart).
    """
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    size = _TEST_DOMAINS // workers
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')  # gw0, gw1, ...
    if workers < 2 or size < 2 * _HELD_DOMAINS or not worker.startswith('gw'):
        return range(1, _TEST_DOMAINS + 1)
    first = 1 + int(worker[2:]) * size
    return range(first, first + size)


_DOMAINS = _worker_domains()
_domain_ids = itertools.count((os.getpid() * 37) % len(_DOMAINS))


def next_domain_id() -> int:
    """Return a domain id no other test of this run or of a concurrent run holds."""
    _DOMAIN_LOCKS.mkdir(exist_ok=True)
    for _ in range(len(_DOMAINS)):
        domain = _DOMAINS[next(_domain_ids) % len(_DOMAINS)]
        if any(domain == held for held, _ in _held_domains):
            continue
        lock = open(_DOMAIN_LOCKS / f'{domain}.lock', 'w')  # noqa: SIM115 - held until freed
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # another run's
            lock.close()
            continue
        _held_domains.append((domain, lock))
        while len(_held_domains) > _HELD_DOMAINS:
            _held_domains.popleft()[1].close()
        return domain
    raise RuntimeError(f'every ROS domain id is held by another test run ({_DOMAIN_LOCKS})')


def wait_for(predicate: Callable[[], object], timeout: float, what: str,
             interval: float = 0.01) -> object:
    """Poll ``predicate`` until it returns a truthy value; fail the test after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            # Where every thread was (the executors' too) goes to the failure's captured stderr.
            faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
            raise AssertionError(f'timed out after {timeout:.1f} s waiting for {what}')
        time.sleep(interval)


class RosGraph:
    """Nodes of one test, on a private context and domain, spun by a background executor.

    Callbacks run on the spinning thread, except those of groups registered with
    ``graph.executor.add_blocking_group`` (callbacks that wait, such as the sim's services).
    """

    def __init__(self) -> None:
        self.domain_id = next_domain_id()
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        # Not rclpy's MultiThreadedExecutor: its callback dispatch starves other Python
        # threads (an in-process sim then ran at a third of its real-time factor).
        self.executor = BlockingGroupExecutor(context=self.context)
        self._stopping = False
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()
        self._nodes: list[Node] = []

    @property
    def env(self) -> dict[str, str]:
        """Environment for a subprocess that should join this graph."""
        return dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id),
                    ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - the executor or context is shut down under it
            # A callback still running when shutdown gives up waiting for it (a loaded
            # machine) meets the executor's destroyed handles.
            if self.context.ok() and not self._stopping:
                raise

    def add(self, node: Node) -> Node:
        """Spin ``node`` with the graph's executor; it is destroyed at the end of the test."""
        self._nodes.append(node)
        self.executor.add_node(node)
        return node

    def node(self, name: str, **kwargs) -> Node:
        """Create a plain helper node (for subscribers and clients) in this graph."""
        return self.add(Node(name, context=self.context, **kwargs))

    def shutdown(self) -> None:
        # Stop spinning before destroying nodes, so no callback runs on a destroyed handle.
        self._stopping = True
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        for node in reversed(self._nodes):
            node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def world_config() -> WorldConfig:
    """Configure the ``world`` fixture: the default world; a test module overrides this."""
    return WorldConfig()


@pytest.fixture
def world(world_config: WorldConfig) -> Iterator[SimWorld]:
    """Yield a plain simulated world of ``world_config`` (pybullet, no ROS); close it after."""
    sim = SimWorld(world_config)
    try:
        yield sim
    finally:
        sim.close()


def simulate(world: SimWorld, seconds: float) -> None:
    """Step ``world`` through ``seconds`` of simulated time."""
    for _ in range(round(seconds / world.dt)):
        world.step()


def move_tcp(world: SimWorld, position: Sequence[float], seconds: float = 2.5) -> None:
    """Drive the arm toward the TCP at ``position``, gripper down, for ``seconds``."""
    world.set_arm_targets(world.inverse_kinematics(position, GRIPPER_DOWN))
    simulate(world, seconds)


@pytest.fixture
def ros_graph() -> Iterator[RosGraph]:
    """One ROS graph for this test: private context and domain, shut down afterwards."""
    graph = RosGraph()
    try:
        yield graph
    finally:
        graph.shutdown()


def start_sim(graph: RosGraph, **parameters) -> Node:
    """Start the simulator node in ``graph`` with parameter overrides (Python values)."""
    from rclpy.parameter import Parameter
    from ur_rg2_sim.sim_node import SimNode

    overrides = [Parameter(name, value=value) for name, value in parameters.items()]
    node = SimNode(context=graph.context, parameter_overrides=overrides)
    graph.executor.add_blocking_group(node.blocking_group)
    return graph.add(node)
