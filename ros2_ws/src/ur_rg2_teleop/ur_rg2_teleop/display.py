"""What the teleop shows: joint angle lines, and when to show them; free of ROS."""

from collections.abc import Sequence
import math
import sys
import threading
from typing import TextIO

from ur_rg2_common.contract import ARM_JOINTS

SHORT_NAMES = ('pan', 'lift', 'elbow', 'wrist1', 'wrist2', 'wrist3')


class Console:
    """Line output to the user, safe to use from the key loop and from ROS callbacks at once."""

    def __init__(self, stream: TextIO = sys.stdout) -> None:
        self._stream = stream
        self._lock = threading.Lock()

    def line(self, text: str) -> None:
        """Write ``text`` (which may span lines) and a newline, flushed."""
        with self._lock:
            self._stream.write(f'{text}\n')
            self._stream.flush()


def outcome_line(name: str, success: bool, message: str) -> str:
    """Return one line with an outcome: ``NAME: done: MESSAGE`` or ``NAME: FAILED: MESSAGE``."""
    message = ' '.join(message.split())  # one line, whatever the message holds
    return f"{name}: {'done' if success else 'FAILED'}{': ' + message if message else ''}"


def result_outcome(text: str) -> tuple[bool, str]:
    """Split a result topic's line, ``success: ...`` or ``failed: ...``, into success and rest.

    A line with neither prefix is a failure whose message is the whole line.
    """
    status, _, message = text.partition(': ')
    if status not in ('success', 'failed'):
        return False, text
    return status == 'success', message


def arm_values(names: Sequence[str], values: Sequence[float]) -> list[float] | None:
    """Return ``values`` of the six arm joints in ARM_JOINTS order, None if any is missing."""
    if len(values) != len(names):
        return None
    by_name = dict(zip(names, values, strict=True))
    try:
        return [by_name[name] for name in ARM_JOINTS]
    except KeyError:
        return None


def format_angles(positions: Sequence[float], step_deg: float) -> str:
    """Return one line with the arm joint ``positions`` (rad) in degrees and the step."""
    # Adding 0.0 turns the -0.0 of a tiny negative angle into 0.0.
    fields = '  '.join(f'{name} {round(math.degrees(p), 1) + 0.0:+6.1f}'
                       for name, p in zip(SHORT_NAMES, positions, strict=True))
    return f'{fields}  deg  (step {step_deg:g})'


class SettleWatcher:
    """Decide when a move is over, so its result is shown once, not once per joint state.

    After :meth:`moved`, :meth:`observe` is fed the joint speeds of each joint state and says
    True once: when the arm has moved and then stayed still for ``settle_time`` s (a joint
    overshooting its target stands still for an instant only), when it did not start moving
    within ``start_timeout`` s (a joint already at its limit, a sim without velocities), or
    after ``max_wait`` s whatever happens.
    """

    def __init__(self, start_timeout: float = 0.5, settle_time: float = 0.1,
                 max_wait: float = 5.0, still_speed: float = 0.02) -> None:
        self._start_timeout = start_timeout
        self._settle_time = settle_time
        self._max_wait = max_wait
        self._still_speed = still_speed
        self._since: float | None = None
        self._moving_seen = False
        self._still_since: float | None = None

    def moved(self, now: float) -> None:
        """Note that a move was commanded at monotonic time ``now``."""
        self._since = now
        self._moving_seen = False
        self._still_since = None

    def observe(self, now: float, speeds: Sequence[float]) -> bool:
        """Take one joint state's ``speeds`` (rad/s); return True when the move is over."""
        if self._since is None:
            return False
        if any(abs(v) > self._still_speed for v in speeds):
            self._moving_seen = True
            self._still_since = None
        elif self._still_since is None:
            self._still_since = now
        elapsed = now - self._since
        settled = self._still_since is not None and now - self._still_since >= self._settle_time
        done = (
            (self._moving_seen and settled)
            or (not self._moving_seen and elapsed > self._start_timeout)
            or elapsed > self._max_wait
        )
        if done:
            self._since = None
        return done
