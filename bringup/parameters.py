"""Tell the user about ``NAME:=VALUE`` options that no node of the graph takes.

ROS ignores a parameter override that no node declares, so a typo (``camera_rte:=15.0``)
would otherwise pass unnoticed. Once the nodes are up, each is asked for the names it declares
(its ``list_parameters`` service), in a background thread with its own ROS context: the graph
starts as fast as without the check, and a node that never answers only means that nothing is
said about the parameters it might have taken.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
import difflib
import threading
import time

# How long the nodes get to come up and answer; the first start on a loaded machine is slow.
ANSWER_TIMEOUT_S = 60.0
# A request still unanswered after this long is sent again (one sent just as the service
# appeared can be lost).
RETRY_S = 5.0


@dataclass(frozen=True)
class Requested:
    """A parameter given on the command line: for node ``node``, or every node when empty."""

    node: str
    name: str

    @property
    def option(self) -> str:
        """How the user may have typed it."""
        return f'{self.node}:{self.name}' if self.node else self.name


def _suggestion(name: str, candidates: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, sorted(set(candidates)), n=1)
    return f' (did you mean {close[0]}?)' if close else ''


def unknown_parameters(requested: Iterable[Requested],
                       declared: Mapping[str, frozenset[str] | None]) -> list[str]:
    """Return one sentence per requested parameter that no node it is meant for declares.

    ``declared`` maps the ROS name of each running node to the parameters it declares, or to
    ``None`` when it did not answer: then nothing is said about the parameters it may take.
    """
    answered = {node: names for node, names in declared.items() if names is not None}
    everything = set().union(*answered.values())
    messages = []
    for parameter in dict.fromkeys(requested):  # each once, in command-line order
        if not parameter.node:
            if parameter.name not in everything and len(answered) == len(declared):
                messages.append(f'no node declares parameter {parameter.name!r}'
                                + _suggestion(parameter.name, everything))
        elif parameter.node not in declared:
            messages.append(f'no node {parameter.node!r} runs for {parameter.option!r}'
                            + _suggestion(parameter.node, declared))
        elif parameter.node in answered and parameter.name not in answered[parameter.node]:
            messages.append(f'{parameter.node} does not declare parameter {parameter.name!r}'
                            + _suggestion(parameter.name, answered[parameter.node]))
    return messages


def query_declared(nodes: Sequence[str], ros_args: Sequence[str], stop: threading.Event,
                   timeout: float = ANSWER_TIMEOUT_S) -> dict[str, frozenset[str] | None]:
    """Ask each node (a name relative to the graph's namespace) which parameters it declares.

    ``ros_args`` are the nodes' own ``--ros-args`` (their namespace remapping counts). Returns
    when every node has answered, ``timeout`` seconds have passed or ``stop`` is set; a node
    without an answer maps to ``None``.
    """
    # Here, not at the top: only a command line with parameters pays for importing rclpy.
    from rcl_interfaces.srv import ListParameters
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    declared: dict[str, frozenset[str] | None] = dict.fromkeys(nodes)
    # Of the nodes' arguments only their namespace: the graph's names are relative to it, and
    # their log level (say, debug) is not for this query.
    namespace = [arg for flag, value in zip(ros_args, ros_args[1:], strict=False)
                 if flag in ('-r', '--remap') and value.startswith('__ns:=')
                 for arg in (flag, value)]
    context = Context()
    # The supervisor's own signal handlers stay in charge of Ctrl-C and SIGTERM.
    rclpy.init(args=['bringup', '--ros-args', *namespace], context=context,
               signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor(context=context)
    probe = rclpy.create_node('_bringup_parameter_check', context=context,
                              start_parameter_services=False, enable_rosout=False)
    try:
        clients = {node: probe.create_client(ListParameters, f'{node}/list_parameters')
                   for node in nodes}
        executor.add_node(probe)
        pending: dict[str, tuple[Future, float]] = {}
        deadline = time.monotonic() + timeout
        while (any(names is None for names in declared.values())
               and time.monotonic() < deadline and not stop.is_set()):
            now = time.monotonic()
            for node, client in clients.items():
                if declared[node] is not None:
                    continue
                future, sent = pending.get(node, (None, 0.0))
                if future is not None and future.done():
                    declared[node] = frozenset(future.result().result.names)
                elif (future is None or now - sent > RETRY_S) and client.service_is_ready():
                    if future is not None:
                        client.remove_pending_request(future)
                    pending[node] = client.call_async(ListParameters.Request()), now
            executor.spin_once(timeout_sec=0.1)
    finally:
        executor.shutdown()
        probe.destroy_node()
        context.try_shutdown()
    return declared


class ParameterCheck:
    """Runs :func:`query_declared` and reports :func:`unknown_parameters`, in the background."""

    def __init__(self, requested: Sequence[Requested], nodes: Sequence[str],
                 ros_args: Sequence[str], report: Callable[[str], None],
                 timeout: float = ANSWER_TIMEOUT_S) -> None:
        self._requested = list(requested)
        self._nodes = list(nodes)
        self._ros_args = list(ros_args)
        self._report = report
        self._timeout = timeout
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='parameter-check', daemon=True)

    def start(self) -> None:
        """Start asking the nodes (call once they have been started)."""
        self._thread.start()

    def stop(self) -> None:
        """Stop asking and say nothing more (the graph is stopping)."""
        self._stop.set()

    def join(self, timeout: float = 2.0) -> None:
        """Stop, and wait up to ``timeout`` s for the thread to end."""
        self.stop()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def _run(self) -> None:
        try:
            declared = query_declared(self._nodes, self._ros_args, self._stop, self._timeout)
        except Exception as error:  # noqa: BLE001 - a check that cannot run must not stop the graph
            if not self._stop.is_set():
                self._report(f'cannot check the parameters: {error}')
            return
        for message in unknown_parameters(self._requested, declared):
            if self._stop.is_set():
                return
            self._report(message)
