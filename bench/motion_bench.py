"""Benchmark of Cartesian control (ur_rg2_motion): IK time, tool_jog latency, the pick.

* IK: the node's solve (with floor and pedestal checks) on random reachable poses.
* tool_jog: ``keys`` on a pseudo-terminal in tool mode, the sim and motion as separate
  processes; a key press to joint_states showing the arm moving, seen in this process.
* pick: sim, vision and motion at real-time factor 1 with the camera on; the ball placed
  (seeded) across the floor the camera sees in the arm's reach, then ``pick_ball``. The ball's
  true pose and the TCP from /tf judge whether the ball is really held, so a success claimed
  for a ball not held (a false claim) is counted.
* the learned pick beside it: the same graph with the ``policy`` node running the shipped
  Pick policy (``policy_dir:=pick``), ``policy/run`` until ``policy/driving`` falls, on the
  placements of the region Pick trains on, judged by the same ground truth.

Run alone with ``python -m bench.motion_bench [--parts ...] [--picks N] [--policy-picks N]
[--seed N] [--region pick_ball|pick_env]`` (``--help`` says more); ``python -m bench motion``
runs it with its defaults. Each row names its seed and region.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
import math
import os
from pathlib import Path
import statistics
import sys
import tempfile
import threading
import time

from geometry_msgs.msg import PointStamped, PoseStamped
import numpy as np
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import LATCHED_QOS
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer, set_pose
from ur_rg2_learning.tasks import BALL_DISTANCE, BALL_HEADING
from ur_rg2_motion.kinematics import ArmKinematics, Box, KinematicsError
from ur_rg2_motion.planning import gripper_down
from ur_rg2_sim.robot_model import write_robot_urdf
from ur_rg2_sim.world import PEDESTAL_HEIGHT

from bench.processes import bench_env, call_service, node_process, spun_node
from bench.teleop_bench import _keys_terminal

IK_SOLVES = 5000
IK_WARMUP = 100
IK_TARGET_MS = 0.5
SEED = 20261123
PICKS = 100
POLICY_PICKS = 20
PICK_SUCCESS_TARGET = 0.97
PICK_TIME_TARGET_S = 10.0
JOG_TRIALS = 100
JOG_WARMUP = 5
JOG_TARGET_MS = 40.0
START_TIMEOUT_S = 120.0
CALL_TIMEOUT_S = 60.0
BALL_RADIUS = 0.03  # m, the sim's default
MOVED_RAD = 1e-4  # a joint change larger than any jitter at rest


def ik_solve_times(model: str = 'ur5') -> tuple[list[float], int]:
    """Return the wall time (s) of each solve of random reachable poses and how many failed.

    The checks are those of the running node: floor and pedestal of the sim's world.
    """
    with tempfile.TemporaryDirectory() as directory:
        urdf = write_robot_urdf(model, Path(directory)).read_text()
    arm = ArmKinematics.from_urdf(urdf, floor_z=-PEDESTAL_HEIGHT, keep_out=[
        Box((-0.11, -0.11, -PEDESTAL_HEIGHT - 1.0), (0.11, 0.11, 0.0))])
    rng = np.random.default_rng(SEED)
    joints = rng.uniform(arm.lower, arm.upper, size=(IK_WARMUP + IK_SOLVES, 6))
    targets = arm.tcp_pose(joints)
    starts = joints + rng.normal(0.0, 0.3, joints.shape)
    times, refused = [], 0
    for i, (target, start) in enumerate(zip(targets, starts)):
        began = time.perf_counter()
        try:
            arm.solve(target, start)
        except KinematicsError:
            refused += 1  # below the floor, in the pedestal: timed all the same
        if i >= IK_WARMUP:
            times.append(time.perf_counter() - began)
    return times, refused


# Where the ball is placed (world, on the floor), as (distance from the base axis, m) and
# (heading, rad) ranges: pick_ball's region is an annulus sector in front of the arm, on the
# camera's side, clear of the pedestal; pick_env is where the Pick environment places balls.
REGIONS = {
    'pick_ball': ((0.35, 0.6), (-1.3, 0.2)),
    'pick_env': (tuple(BALL_DISTANCE), tuple(BALL_HEADING)),
}


def region_name(region: str) -> str:
    """Describe a region for a row: its name and ranges."""
    (near, far), (low, high) = REGIONS[region]
    return (f'region {region}: {near:g}-{far:g} m, {math.degrees(low):.0f} to '
            f'{math.degrees(high):.0f} deg')


def placement(region: str) -> Callable[[np.random.Generator], tuple[float, float, float]]:
    """Return a function drawing seeded ball positions (world) in ``region``."""
    distance, heading = REGIONS[region]

    def draw(rng: np.random.Generator) -> tuple[float, float, float]:
        radius = rng.uniform(*distance)
        angle = rng.uniform(*heading)
        return (radius * math.cos(angle), radius * math.sin(angle), BALL_RADIUS)
    return draw


class _Probe:
    """This process's view of the graph: joints, tree, ball, and calls into the nodes."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.changed = threading.Condition()
        self.tree = TransformBuffer()
        self.joints: np.ndarray | None = None
        self.moved_at: float | None = None
        self.baseline: np.ndarray | None = None
        self.still = 0
        self.sim_time = 0.0  # s, the latest joint_states stamp
        self.truth: PoseStamped | None = None
        self.seen = 0
        self.driving: bool | None = None
        node.create_subscription(Bool, 'policy/driving', self._on_driving, LATCHED_QOS)
        node.create_subscription(TFMessage, '/tf_static', self.tree.add_message, LATCHED_QOS)
        node.create_subscription(TFMessage, '/tf', self.tree.add_message, 100)
        node.create_subscription(JointState, 'joint_states', self._on_state, 100)
        node.create_subscription(PoseStamped, 'ball/true_pose', self._on_truth, 10)
        node.create_subscription(PointStamped, 'ball/position', self._on_ball, 10)
        self.command = node.create_publisher(PoseStamped, 'tool_command', 10)
        self._clients: dict[str, object] = {}

    def _on_state(self, msg: JointState) -> None:
        now = time.monotonic()
        joints = np.array(msg.position[:6])
        self.sim_time = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self.changed:
            moving = self.joints is None or np.abs(joints - self.joints).max() > MOVED_RAD / 2
            self.still = 0 if moving else self.still + 1
            self.joints = joints
            if (self.moved_at is None and self.baseline is not None
                    and np.abs(joints - self.baseline).max() > MOVED_RAD):
                self.moved_at = now
            self.changed.notify_all()

    def _on_truth(self, msg: PoseStamped) -> None:
        self.truth = msg

    def _on_driving(self, msg: Bool) -> None:
        with self.changed:
            self.driving = msg.data
            self.changed.notify_all()

    def run_policy(self, timeout: float = 120.0) -> Trigger.Response:
        """Start a policy episode and wait for its end (policy/driving false)."""
        deadline = time.monotonic() + CALL_TIMEOUT_S
        answer = self.call('policy/run')
        # Just started, the node may not have the sim's joint_states or controllers yet.
        while (not answer.success and time.monotonic() < deadline
               and ('received yet' in answer.message or 'not available' in answer.message)):
            time.sleep(0.5)
            answer = self.call('policy/run')
        if answer.success:
            self.wait(lambda: self.driving is True, CALL_TIMEOUT_S, 'policy/driving true')
            self.wait(lambda: self.driving is False, timeout, 'the policy episode to end')
        return answer

    def _on_ball(self, _msg: PointStamped) -> None:
        with self.changed:
            self.seen += 1
            self.changed.notify_all()

    def wait(self, predicate, timeout: float, what: str) -> None:
        with self.changed:
            if not self.changed.wait_for(predicate, timeout):
                raise RuntimeError(f'timed out after {timeout:.0f} s waiting for {what}')

    def call(self, service: str, kind=Trigger, request=None, timeout: float = CALL_TIMEOUT_S):
        return call_service(self.node, self._clients, service, kind, request, timeout)

    def set_ball(self, position) -> None:
        request = SetParameters.Request(parameters=[
            Parameter('ball_position', value=[float(v) for v in position]).to_parameter_msg()])
        self.call('ur_rg2_sim/set_parameters', SetParameters, request)

    def held(self, timeout: float = 5.0) -> bool:
        """Whether the ball is up between the pads (ground truth, not the node's word).

        This process's /tf and ball/true_pose may lag the answer: judged on the latest of
        each for up to ``timeout`` s.
        """
        deadline = time.monotonic() + timeout
        while True:
            truth = self.truth
            try:
                tcp = self.tree.lookup('world', 'rg2_tcp')[:3, 3]
            except FrameLookupError:
                tcp = None
            if truth is not None and tcp is not None:
                ball = truth.pose.position
                if (ball.z > BALL_RADIUS + 0.1
                        and float(np.linalg.norm(tcp - (ball.x, ball.y, ball.z))) < 0.03):
                    return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)


@contextmanager
def _graph(domain_id: int, camera: bool, policy: bool = False,
           policy_dir: str = 'pick') -> Iterator[_Probe]:
    sim_parameters = {} if camera else {'camera_rate': '0.0'}
    with node_process('sim', sim_parameters, domain_id, ready='simulating',
                      timeout=START_TIMEOUT_S), \
            node_process('vision', {}, domain_id, ready='looking for the ball',
                         timeout=START_TIMEOUT_S) if camera else nullcontext(), \
            node_process('motion', {}, domain_id, ready='ready:', timeout=START_TIMEOUT_S), \
            node_process('policy', {'policy_dir': policy_dir}, domain_id,
                         ready='starts an episode', timeout=START_TIMEOUT_S) if policy \
            else nullcontext(), \
            spun_node('motion_bench', domain_id) as node:
        yield _Probe(node)


def pick_trials(count: int, domain_id: int, policy: bool = False, seed: int = SEED,
                region: str = 'pick_ball', policy_dir: str = 'pick') -> dict:
    """Run ``count`` picks placed in ``region`` by ``seed``; return tallies and times.

    ``policy``: the learned pick (``policy/run``, the policy node's ``policy_dir``) instead of
    ``pick_ball``; it claims no success in its answer, so a held ball is its success.
    """
    rng = np.random.default_rng(seed)
    draw = placement(region)
    tally = {'success': 0, 'false_claim': 0, 'failed': 0, 'not_seen': 0, 'times': [],
             'sim_times': [], 'failures': []}
    with _graph(domain_id, camera=True, policy=policy, policy_dir=policy_dir) as probe:
        for trial in range(count):
            at = draw(rng)
            # Each pick starts where the last one ended (the ball up in the gripper): drop it,
            # then place it anew. Only the first starts from home.
            probe.call('gripper/open')
            probe.set_ball(at)
            # Frames rendered before the move may still come: count those after the sim has
            # the ball there.
            probe.wait(lambda at=at: probe.truth is not None and math.dist(
                (probe.truth.pose.position.x, probe.truth.pose.position.y), at[:2]) < 0.005,
                10.0, 'the ball at its placement')
            with probe.changed:
                wanted = probe.seen + 6  # a few frames may predate the move
            try:
                probe.wait(lambda wanted=wanted: probe.seen >= wanted, 10.0,
                           'vision to see the ball')
            except RuntimeError:
                tally['not_seen'] += 1
                continue
            started, sim_started = time.monotonic(), probe.sim_time
            answer = probe.run_policy() if policy else probe.call('pick_ball')
            took, sim_took = time.monotonic() - started, probe.sim_time - sim_started
            held = probe.held()
            if policy and answer.success:
                answer.success = held
            print(f'pick {trial + 1}/{count} at {at[0]:.3f} {at[1]:.3f}: '
                  f"{'held' if held else 'not held'}, {took:.1f} s ({sim_took:.1f} s simulated): "
                  f'{answer.message}', file=sys.stderr, flush=True)
            if answer.success and held:
                tally['success'] += 1
                tally['times'].append(took)
                tally['sim_times'].append(sim_took)
            elif answer.success:
                tally['false_claim'] += 1
                tally['failures'].append(f'{at}: claimed, not held: {answer.message}')
            else:
                tally['failed'] += 1
                tally['failures'].append(f'{at}: {answer.message}')
    return tally


def jog_latencies(domain_id: int) -> list[float]:
    """Return key press -> arm moving (s) for tool-mode jog keys, alternating up and down."""
    env = bench_env(domain_id)
    with tempfile.TemporaryDirectory(prefix='motion-bench-') as tmp, \
            _graph(domain_id, camera=False) as probe, \
            _keys_terminal(env, Path(tmp, 'keys.log')) as master:
        # A working posture first: from home (stretched out) most steps are out of reach.
        start = gripper_down((0.4, -0.2, 0.1), 0.0)
        probe.wait(lambda: probe.command.get_subscription_count() > 0, START_TIMEOUT_S,
                   'the motion node')
        probe.call('reset')
        os.write(master, b'm')
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            msg = PoseStamped()
            msg.header.frame_id = 'base_link'
            set_pose(msg.pose, start)
            probe.command.publish(msg)
            try:
                tcp = probe.tree.lookup('base_link', 'rg2_tcp')
                if np.linalg.norm(tcp[:3, 3] - start[:3, 3]) < 0.003:
                    break
            except FrameLookupError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError('the arm never reached the start pose')
            time.sleep(0.5)
        latencies = []
        for trial in range(JOG_WARMUP + JOG_TRIALS):
            probe.wait(lambda: probe.still >= 20, CALL_TIMEOUT_S, 'the arm at rest')
            with probe.changed:
                probe.baseline, probe.moved_at = probe.joints.copy(), None
            pressed = time.monotonic()
            os.write(master, b'z' if trial % 2 == 0 else b'x')
            probe.wait(lambda: probe.moved_at is not None, 10.0, 'the arm moving after a key')
            if trial >= JOG_WARMUP:
                latencies.append(probe.moved_at - pressed)
    return latencies


PARTS = ('ik', 'jog', 'pick', 'policy')


def run(picks: int = PICKS, policy_picks: int = POLICY_PICKS, parts: tuple[str, ...] = PARTS,
        seed: int = SEED, region: str | None = None,
        policy_dir: str = 'pick') -> list[tuple[str, str, str]]:
    """Return the benchmark rows (metric, measured, target) of ``parts``.

    ``region``: where both picks place the ball (default: pick_ball's for pick_ball, the Pick
    environment's for the learned pick).
    """
    rows = []
    domain_id = 100 + os.getpid() % 40
    if 'ik' in parts:
        times, _ = ik_solve_times()
        p50, p99 = np.percentile(np.array(times) * 1e3, [50, 99])
        rows.append((f'IK solve (UR5, {len(times)} random poses, seed {SEED}, floor and '
                     'pedestal checks) p50 / p99', f'{p50:.3f} / {p99:.3f} ms '
                     f'(load {os.getloadavg()[0]:.1f})', f'p99 <= {IK_TARGET_MS} ms'))
    if 'jog' in parts:
        jog = np.array(jog_latencies(domain_id)) * 1e3
        rows.append(('tool mode key → tool_jog → the arm moving (joint_states), p50 / p99',
                     f'{np.percentile(jog, 50):.1f} / {np.percentile(jog, 99):.1f} ms '
                     f'({len(jog)} keys, load {os.getloadavg()[0]:.1f})',
                     f'p99 <= {JOG_TARGET_MS:g} ms'))
    if 'pick' in parts and picks:
        rows += pick_rows(picks, domain_id + 1, seed, region or 'pick_ball')
    if 'policy' in parts and policy_picks:
        rows += policy_pick_rows(policy_picks, domain_id + 2, seed, region or 'pick_env',
                                 policy_dir)
    return rows


def _summary(tally: dict, what: str) -> tuple[int, float, float, float, str]:
    """Print the failures; return (tried, success rate, median s, median simulated s, load)."""
    for failure in tally['failures']:
        print(f'{what}: {failure}', file=sys.stderr)
    tried = tally['success'] + tally['false_claim'] + tally['failed']
    rate = tally['success'] / tried if tried else float('nan')
    median = statistics.median(tally['times']) if tally['times'] else float('nan')
    simulated = statistics.median(tally['sim_times']) if tally['sim_times'] else float('nan')
    return tried, rate, median, simulated, f'load {os.getloadavg()[0]:.1f}'


def pick_rows(picks: int, domain_id: int, seed: int, region: str) -> list[tuple[str, str, str]]:
    """Return the rows of pick_ball over ``picks`` placements."""
    tally = pick_trials(picks, domain_id, seed=seed, region=region)
    tried, rate, median, simulated, load = _summary(tally, 'pick')
    return [
        (f'pick_ball success over {tried} placements (seed {seed}, {region_name(region)}; '
         'real-time factor 1)',
         f"{rate:.0%} ({tally['success']} held, {tally['failed']} refused or missed, "
         f"{tally['false_claim']} false claims; {tally['not_seen']} not seen; {load})",
         f'>= {PICK_SUCCESS_TARGET:.0%}, 0 false claims'),
        ('pick_ball time, median (service call to answer, real-time factor 1)',
         f'{median:.1f} s ({simulated:.1f} s of simulation time; {load})',
         f'<= {PICK_TIME_TARGET_S:g} s'),
    ]


def policy_pick_rows(picks: int, domain_id: int, seed: int = SEED, region: str = 'pick_env',
                     policy_dir: str = 'pick') -> list[tuple[str, str, str]]:
    """Return the rows of the learned pick (policy_dir:=pick by default) in the live graph."""
    tally = pick_trials(picks, domain_id, policy=True, seed=seed, region=region,
                        policy_dir=policy_dir)
    tried, rate, median, simulated, load = _summary(tally, 'policy pick')
    return [
        (f'learned Pick (policy node, policy_dir:={policy_dir}) in the graph: ball held over '
         f'{tried} placements (seed {seed}, {region_name(region)}; real-time factor 1, camera)',
         f"{rate:.0%} ({tally['success']} held; {tally['not_seen']} not seen; {load})",
         '>= 90%'),
        ('learned Pick time, median (policy/run to the episode end, real-time factor 1)',
         f'{median:.1f} s ({simulated:.1f} s of simulation time; {load})', '-'),
    ]


def main(argv: list[str] | None = None) -> int:
    """Parse the options, run the parts asked for and print their rows."""
    from bench.__main__ import print_table

    parser = argparse.ArgumentParser(prog='python -m bench.motion_bench',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--parts', nargs='+', choices=PARTS, default=list(PARTS),
                        help='what to measure (default: all)')
    parser.add_argument('--picks', type=int, default=PICKS,
                        help=f'pick_ball placements (default {PICKS})')
    parser.add_argument('--policy-picks', type=int, default=POLICY_PICKS,
                        help=f'learned Pick placements (default {POLICY_PICKS})')
    parser.add_argument('--seed', type=int, default=SEED,
                        help=f'seed of the ball placements (default {SEED})')
    parser.add_argument('--policy', default='pick', metavar='DIR',
                        help="the learned pick's policy_dir: a shipped policy's name or a "
                        'directory (default pick)')
    parser.add_argument('--region', choices=sorted(REGIONS),
                        help="where both picks place the ball (default: pick_ball's for "
                             "pick_ball, the Pick environment's for the learned pick)")
    options = parser.parse_args(argv)
    print_table(run(options.picks, options.policy_picks, tuple(options.parts), options.seed,
                    options.region, options.policy))
    return 0


if __name__ == '__main__':
    sys.exit(main())
