"""The pick as the motion node serves it, without ROS: one at a time, its progress, its outcome.

``pick_ball`` is an action (ur_rg2_interfaces/action/PickBall: feedback, cancel) and a
std_srvs/Trigger service; both run the pick through :func:`attempt` while a :class:`PickRun`
holds, and answer from the :class:`PickOutcome`. :class:`PickProgress` keeps the phase the
pick (ur_rg2_motion.pick) reported last and turns it and the TCP's position into the action's
feedback: the phase and the distance still to go.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math
import threading
import time

import numpy as np

from ur_rg2_motion.kinematics import KinematicsError
from ur_rg2_motion.pick import PLANNING, PickCancelledError, PickError
from ur_rg2_motion.urdf import BASE_LINK

# Why a pick stops when its action client cancels it.
CANCELED = "canceled by the action's client; the arm holds where it was"


@dataclass(frozen=True)
class PickOutcome:
    """How a pick ended: the answer of the service and the action's result."""

    success: bool
    message: str
    ball: np.ndarray | None  # the ball's centre in base_link (m), None before it was placed
    seconds: float  # from the request to the answer


REFUSED = PickOutcome(False, 'refused: a pick is already running', None, 0.0)


class PickRun:
    """Whether a pick runs, and why it is to stop; safe from any thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._running = False
        self._stop: str | None = None
        self._canceled: Callable[[], bool] = _never

    @property
    def running(self) -> bool:
        """Whether a pick runs now."""
        with self._lock:
            return self._running

    def start(self, canceled: Callable[[], bool] | None = None) -> bool:
        """Mark a pick as running; return False when one runs already.

        ``canceled`` says whether its action client has asked to cancel it (CANCELED).
        """
        with self._lock:
            if self._running:
                return False
            self._running, self._stop, self._canceled = True, None, canceled or _never
            return True

    def end(self) -> None:
        """Mark the pick as ended."""
        with self._lock:
            self._running = False

    def stop(self, reason: str) -> None:
        """Ask the running pick to stop, saying why (the first reason stands)."""
        with self._lock:
            if self._running and self._stop is None:
                self._stop = reason

    def check(self) -> None:
        """Raise PickCancelledError with the reason once the running pick was asked to stop."""
        with self._lock:
            reason, canceled = self._stop, self._canceled
        if reason is None and canceled():
            reason = CANCELED
        if reason is not None:
            raise PickCancelledError(reason)


def _never() -> bool:
    return False


def attempt(locate: Callable[[], np.ndarray], pick: Callable[[np.ndarray], float],
            clock: Callable[[], float] = time.monotonic) -> PickOutcome:
    """Place the ball (``locate``) and pick it (``pick`` returns the opening it is held at).

    A pick that cannot go on (PickError, PickCancelledError, KinematicsError) is a failed
    outcome saying why, with the ball's position once it was placed.
    """
    started = clock()
    ball = None
    try:
        ball = locate()
        opening = pick(ball)
    except (PickError, PickCancelledError, KinematicsError) as error:
        seconds = clock() - started
        where = f'ball at {xyz(ball)} m in {BASE_LINK}: ' if ball is not None else ''
        return PickOutcome(False, f'{where}{error} (after {seconds:.1f} s)', ball, seconds)
    seconds = clock() - started
    return PickOutcome(True, f'picked the ball at {xyz(ball)} m in {BASE_LINK} in {seconds:.1f} s '
                             f'(held at {opening * 1000:.0f} mm)', ball, seconds)


def xyz(point: Sequence[float]) -> str:
    """Return a position as the answers write it, e.g. ``(0.400, -0.300, -0.170)``."""
    return '({:.3f}, {:.3f}, {:.3f})'.format(*point)


def distance_to_go(tcp: Sequence[float] | None, waypoints: Sequence[Sequence[float]]) -> float:
    """Return the path from ``tcp`` through ``waypoints`` (m); NaN when either is unknown."""
    if tcp is None or not len(waypoints):
        return math.nan
    points = np.array([tcp, *waypoints], dtype=float)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


class PickProgress:
    """The running pick's phase and its waypoints, as the pick reports them; thread-safe.

    Called as the pick's ``progress`` (ur_rg2_motion.pick.run_pick); :meth:`feedback` gives the
    phase and the distance to go from the TCP's position now.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._phase = PLANNING
        self._waypoints: tuple = ()

    def __call__(self, phase: str, waypoints: Sequence[np.ndarray]) -> None:
        """Note that ``phase`` started, going through ``waypoints`` (base_link, m)."""
        with self._lock:
            self._phase, self._waypoints = phase, tuple(waypoints)

    def feedback(self, tcp: Sequence[float] | None) -> tuple[str, float]:
        """Return the phase and the distance to go (m, NaN when unknown) from ``tcp``."""
        with self._lock:
            phase, waypoints = self._phase, self._waypoints
        return phase, distance_to_go(tcp, waypoints)
