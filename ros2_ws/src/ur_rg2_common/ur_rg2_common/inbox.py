"""Subscriptions read when their value is needed, not as their messages come.

A node that keeps only the latest state of a busy topic (``joint_states`` and ``/tf`` at
100 Hz, camera images at 30 Hz) spent most of its idle CPU in rclpy's executor, waking,
taking and deserializing every message (docs/design.md). The executor never takes from an
:class:`Inbox`: DDS keeps up to the QoS depth of newest messages in the reader's history,
and the node takes them when it needs the value (a page asks for it, a command comes).
This relies on rclpy's Python executors (run_node's) asking a callback group whether an
entity may run; the EventsExecutor does not.
"""

from collections.abc import Callable
import threading
import time
from typing import Any, NamedTuple

from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile


class Arrival(NamedTuple):
    """When a message came, and its publisher's count of messages (1 for the first)."""

    received: float  # time.monotonic()'s clock
    sequence: int


class _Unscheduled(CallbackGroup):
    """A callback group whose entities the executor never waits on nor runs."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        pass


def _unscheduled(_message: Any) -> None:
    raise AssertionError('an Inbox subscription is never run by the executor')


class Inbox:
    """A subscription whose messages wait in DDS until :meth:`pull` hands them on."""

    def __init__(self, node: Node, msg_type: type, topic: str, qos: QoSProfile | int,
                 handle: Callable[[Any, Arrival], None], *, raw: bool = False) -> None:
        """Subscribe ``node``; :meth:`pull` calls ``handle(message, arrival)``.

        ``raw``: the message as its serialized bytes (rclpy.serialization to read it).
        """
        self._handle = handle
        # Held while messages are taken and handled, so that they are handled in order
        # whichever thread pulls.
        self._lock = threading.Lock()
        self._subscription = node.create_subscription(
            msg_type, topic, _unscheduled, qos, callback_group=_Unscheduled(), raw=raw)

    def pull(self) -> int:
        """Hand every message come since the last pull on, oldest first; return how many."""
        subscription = self._subscription
        count = 0
        with self._lock, subscription.handle:
            while (taken := subscription.handle.take_message(
                    subscription.msg_type, subscription.raw)) is not None:
                message, info = taken
                # received_timestamp is the system clock's, in ns.
                age = max(0.0, time.time() - info['received_timestamp'] * 1e-9)
                self._handle(message, Arrival(time.monotonic() - age,
                                              info['publication_sequence_number']))
                count += 1
        return count
