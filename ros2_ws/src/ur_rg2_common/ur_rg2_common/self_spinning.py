"""A node for command-line drivers that wait by spinning themselves, on one thread.

The ``dataset`` and ``demos`` commands drive a running graph step by step: call a service,
wait for a topic, set the sim's parameters. :class:`SelfSpinningNode` holds those waits and
calls; a subclass says which exception a timeout or a failed call raises and how a stop
request shows (:meth:`check_stop`).
"""

from collections.abc import Callable, Sequence
import time
from typing import Any

from rcl_interfaces.srv import GetParameters
from rclpy.client import Client
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python

# How long one wait for work lasts before the loop looks at its predicate again, s.
SPIN_STEP_S = 0.02


class SelfSpinningNode(Node):
    """A node with an executor of its own, for a driver that waits on one thread.

    ``timeout`` (s) is the default limit of :meth:`spin_until`; ``error`` is the exception
    type raised when a wait times out or a call fails.
    """

    error: type[Exception] = RuntimeError

    def __init__(self, node_name: str, timeout: float) -> None:
        super().__init__(node_name)
        self.timeout = timeout
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self)

    def check_stop(self) -> None:
        """Raise if the driver has been asked to stop now (by default never)."""

    def spin_until(self, predicate: Callable[[], Any], what: str,
                   timeout: float | None = None) -> Any:
        """Spin until ``predicate`` returns a truthy value, and return it.

        :attr:`error` after ``timeout`` s (default :attr:`timeout`); whatever
        :meth:`check_stop` raises before each look.
        """
        limit = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + limit
        while True:
            self.check_stop()
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                raise self.error(f'timed out after {limit:g} s waiting for {what}')
            self._executor.spin_once(timeout_sec=SPIN_STEP_S)

    def call(self, client: Client, request: Any, what: str) -> Any:
        """Call a service and return its response; :attr:`error` if the call fails."""
        future = client.call_async(request)
        self.spin_until(future.done, what)
        if future.exception() is not None:
            raise self.error(f'{what} failed: {future.exception()}')
        return future.result()

    def parameters_of(self, client: Client, names: Sequence[str]) -> dict[str, Any]:
        """Return another node's values of parameters ``names`` (its get_parameters client)."""
        response = self.call(client, GetParameters.Request(names=list(names)),
                             f'the parameters of {client.srv_name.rsplit("/", 1)[0]}')
        return {name: parameter_value_to_python(value)
                for name, value in zip(names, response.values)}
