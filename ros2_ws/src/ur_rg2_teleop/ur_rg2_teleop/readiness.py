"""Whether the nodes keys works with have come up: the start-up line, and why a key waits.

keys' screen is up seconds before the graph it drives (the sim, vision and motion load for
several seconds). Until a node's services and subscriptions are there, the keys that need it
are refused with the node's name, instead of a service call failing; once a node has come, its
keys work, and a node that goes away later is reported by the call itself. Free of ROS: the
node hands in what is available.
"""

from __future__ import annotations

from collections.abc import Callable
import threading

from ur_rg2_teleop.keymap import Action, CallService, Jog, Mode, SendGoal

# What each node of the graph offers keys: the services and actions it serves, the topics it
# listens to.
PROVIDERS: dict[str, tuple[str, ...]] = {
    'sim': ('joint_jog', 'gripper/close', 'gripper/open', 'reset'),
    'vision': ('vision/save_frame',),
    'motion': ('tool_jog', 'pick_ball'),
}


def needs(action: Action | None, mode: Mode) -> str | None:
    """Return the service, action or topic ``action`` uses in ``mode``, None if it uses none."""
    if isinstance(action, Jog):
        return 'tool_jog' if mode is Mode.TOOL else 'joint_jog'
    if isinstance(action, CallService):
        return action.service
    if isinstance(action, SendGoal):
        return action.action
    return None


class Readiness:
    """Which of the graph's nodes have come up, from repeated looks at what is available."""

    def __init__(self, providers: dict[str, tuple[str, ...]] = PROVIDERS) -> None:
        self._providers = providers
        self._waiting = list(providers)
        self._lock = threading.Lock()

    @property
    def ready(self) -> bool:
        """True once every node has come up."""
        with self._lock:
            return not self._waiting

    def status(self) -> str:
        """Return the status line: ``starting: waiting for sim, motion``, or ``ready``."""
        with self._lock:
            return f"starting: waiting for {', '.join(self._waiting)}" if self._waiting \
                else 'ready'

    def update(self, available: Callable[[str], bool]) -> str | None:
        """Note the nodes whose names are all ``available``; return the new status, if new."""
        with self._lock:
            came = [node for node in self._waiting
                    if all(available(name) for name in self._providers[node])]
            self._waiting = [node for node in self._waiting if node not in came]
        return self.status() if came else None

    def refusal(self, name: str | None) -> str | None:
        """Return the line refusing a key that uses ``name`` while its node is not up, or None."""
        with self._lock:
            waiting = [node for node in self._waiting if name in self._providers[node]]
        return f'not ready yet: waiting for {waiting[0]}' if waiting else None
