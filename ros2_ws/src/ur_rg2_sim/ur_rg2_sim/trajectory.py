"""Joint trajectories as ros2_control's joint_trajectory_controller runs them. No ROS here.

:func:`validate` checks a goal the way the controller does and answers with its error codes;
:func:`plan` fits a C1 spline from the arm's current state through the goal's points
(cubic Hermite, quintic where accelerations are given) and refuses one that needs more than a
joint's velocity limit; ur_rg2_sim.execution's :class:`Execution` samples it each physics step
and decides the outcome from the goal and path tolerances.

Timing follows the goal, as ros2_control does: a trajectory too fast for a joint is refused
with the reason (which segment, how fast, the limit) rather than slowed down, so that a
client's timing is either honoured or reported, never silently changed.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from typing import Optional

import numpy as np

# control_msgs/action/FollowJointTrajectory result codes.
SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5

DEFAULT_GOAL_TOLERANCE = 0.01  # rad, per joint
DEFAULT_GOAL_TIME_TOLERANCE = 1.0  # s after the last point's time
# A first point due at once may be this far from where the joint is (MoveIt's trajectories
# start with the current state at time 0).
START_TOLERANCE = 0.01  # rad
# A start further ahead than this is a stamp in the wrong clock (wall time, not /clock).
MAX_START_DELAY = 3600.0  # s
# Relative slack on velocity limits, for rounding in a client's own time parametrisation.
_VELOCITY_SLACK = 1e-3
_SAMPLES_PER_SEGMENT = 65  # odd: the middle, where a rest-to-rest cubic peaks, is one


class TrajectoryError(ValueError):
    """A goal is refused; ``code`` is the FollowJointTrajectory error code, str() the reason."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Point:
    """One trajectory point as given: seconds from the start, and per-joint values."""

    time: float
    positions: Sequence[float]
    velocities: Sequence[float] = ()
    accelerations: Sequence[float] = ()


@dataclass(frozen=True)
class Tolerance:
    """A JointTolerance entry: > 0 is the tolerance, 0 the default, < 0 no check."""

    name: str
    position: float = 0.0
    velocity: float = 0.0


@dataclass(frozen=True)
class Goal:
    """A validated goal: the joints it names, in its order, and its points and tolerances."""

    joints: tuple[str, ...]
    times: np.ndarray  # (N,) s from the start
    positions: np.ndarray  # (N, J)
    velocities: list[Optional[np.ndarray]]  # per point, (J,) or None when not given
    accelerations: list[Optional[np.ndarray]]
    path_position: np.ndarray  # (J,) rad, inf = not checked
    path_velocity: np.ndarray
    goal_position: np.ndarray
    goal_velocity: np.ndarray
    goal_time_tolerance: float


def validate(joints: Sequence[str], points: Sequence[Point], known: Sequence[str],
             path_tolerance: Sequence[Tolerance] = (), goal_tolerance: Sequence[Tolerance] = (),
             goal_time_tolerance: float = 0.0) -> Goal:
    """Return the goal checked as joint_trajectory_controller checks it, or raise TrajectoryError.

    ``known`` are the joints the controller drives; ``goal_time_tolerance`` <= 0 means the
    default 1 s.
    """
    joints = tuple(joints)
    if not joints:
        raise TrajectoryError(INVALID_JOINTS, 'the trajectory names no joints')
    unknown = [name for name in joints if name not in known]
    if unknown:
        raise TrajectoryError(INVALID_JOINTS, f"unknown joint {', '.join(map(repr, unknown))} "
                              f"(this controller drives {', '.join(known)})")
    repeated = sorted({name for name in joints if joints.count(name) > 1})
    if repeated:
        raise TrajectoryError(INVALID_JOINTS,
                              f"joint {', '.join(map(repr, repeated))} named more than once")
    if not points:
        raise TrajectoryError(INVALID_GOAL, 'the trajectory has no points')
    count = len(joints)
    previous = -math.inf
    for index, point in enumerate(points):
        where = f'point {index}'
        if not math.isfinite(point.time) or point.time < 0:
            raise TrajectoryError(INVALID_GOAL,
                                  f'{where}: time_from_start {point.time} s is not a finite '
                                  'time >= 0')
        if point.time <= previous:
            raise TrajectoryError(INVALID_GOAL,
                                  f'{where}: time_from_start {point.time:g} s is not after the '
                                  f'previous point ({previous:g} s): times must increase')
        previous = point.time
        for field, values, required in (('positions', point.positions, True),
                                        ('velocities', point.velocities, False),
                                        ('accelerations', point.accelerations, False)):
            if len(values) != count and (required or len(values)):
                raise TrajectoryError(INVALID_GOAL,
                                      f'{where}: {len(values)} {field} for {count} joints')
            bad = [name for name, value in zip(joints, values) if not math.isfinite(value)]
            if bad:
                raise TrajectoryError(INVALID_GOAL, f"{where}: {field} of {', '.join(bad)} "
                                      'not a finite number')
        if point.accelerations and not point.velocities:
            raise TrajectoryError(INVALID_GOAL,
                                  f'{where}: accelerations given without velocities')
    path_position, path_velocity = _tolerances('path_tolerance', path_tolerance, joints,
                                               math.inf)
    goal_position, goal_velocity = _tolerances('goal_tolerance', goal_tolerance, joints,
                                               DEFAULT_GOAL_TOLERANCE)
    if not math.isfinite(goal_time_tolerance):
        raise TrajectoryError(INVALID_GOAL, 'goal_time_tolerance is not a finite duration')
    return Goal(
        joints=joints,
        times=np.array([p.time for p in points], dtype=float),
        positions=np.array([p.positions for p in points], dtype=float).reshape(-1, count),
        velocities=[np.array(p.velocities, dtype=float) if len(p.velocities) else None
                    for p in points],
        accelerations=[np.array(p.accelerations, dtype=float) if len(p.accelerations) else None
                       for p in points],
        path_position=path_position, path_velocity=path_velocity,
        goal_position=goal_position, goal_velocity=goal_velocity,
        goal_time_tolerance=(goal_time_tolerance if goal_time_tolerance > 0
                             else DEFAULT_GOAL_TIME_TOLERANCE))


def _tolerances(field: str, entries: Sequence[Tolerance], joints: tuple[str, ...],
                default_position: float) -> tuple[np.ndarray, np.ndarray]:
    position = np.full(len(joints), default_position)
    velocity = np.full(len(joints), math.inf)
    for entry in entries:
        if entry.name not in joints:
            raise TrajectoryError(INVALID_GOAL, f'{field} names {entry.name!r}, which is not a '
                                  'joint of the trajectory')
        if not (math.isfinite(entry.position) and math.isfinite(entry.velocity)):
            raise TrajectoryError(INVALID_GOAL, f'{field} of {entry.name} is not finite')
        index = joints.index(entry.name)
        for values, value in ((position, entry.position), (velocity, entry.velocity)):
            if value > 0:
                values[index] = value
            elif value < 0:
                values[index] = math.inf
    return position, velocity


class Spline:
    """Piecewise polynomials through knots at absolute times (s); holds outside them."""

    def __init__(self, times: np.ndarray, coefficients: np.ndarray, end: np.ndarray) -> None:
        self.times = times  # (K,) knot times
        self.coefficients = coefficients  # (K-1, 6, J): c0 + c1 t + ... + c5 t^5 per segment
        self.end = end  # (J,) the last knot's positions

    @property
    def start_time(self) -> float:
        """Return the time of the first knot."""
        return float(self.times[0])

    @property
    def end_time(self) -> float:
        """Return the time of the last knot."""
        return float(self.times[-1])

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return positions, velocities and accelerations at time ``t``."""
        if t >= self.times[-1] or len(self.coefficients) == 0:
            zero = np.zeros_like(self.end)
            return self.end.copy(), zero, zero.copy()
        index = max(int(np.searchsorted(self.times, t, side='right')) - 1, 0)
        return _evaluate(self.coefficients[index], max(t - self.times[index], 0.0))


def _evaluate(c: np.ndarray, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float)[..., None] if np.ndim(t) else t
    position = c[0] + t * (c[1] + t * (c[2] + t * (c[3] + t * (c[4] + t * c[5]))))
    velocity = c[1] + t * (2 * c[2] + t * (3 * c[3] + t * (4 * c[4] + t * 5 * c[5])))
    acceleration = 2 * c[2] + t * (6 * c[3] + t * (12 * c[4] + t * 20 * c[5]))
    return position, velocity, acceleration


def plan(goal: Goal, now: float, start: Optional[float], positions: np.ndarray,
         velocities: np.ndarray, velocity_limits: np.ndarray,
         position_limits: Optional[tuple[np.ndarray, np.ndarray]] = None) -> Spline:
    """Return the spline that takes the goal's joints from their current state through it.

    ``now`` is the current time and ``start`` the goal's start time (None: now), both in s;
    ``positions``, ``velocities`` and the limits are per goal joint. Points due before now are
    skipped, as ros2_control does for a stamp in the past. Raises TrajectoryError when nothing
    is left, or when a point is out of the joints' range or a segment needs more than a
    joint's velocity limit.
    """
    begin = now if start is None else start
    if begin - now > MAX_START_DELAY:
        raise TrajectoryError(INVALID_GOAL, f'header.stamp is {begin - now:.0f} s ahead of '
                              'simulation time: stamps are simulation time (/clock); a zero '
                              'stamp starts at once')
    times = begin + goal.times
    keep = times >= now
    if not keep.any():
        raise TrajectoryError(OLD_HEADER_TIMESTAMP,
                              f'the trajectory ended {now - times[-1]:.3f} s ago (header.stamp '
                              'in the past)')
    first = int(np.argmax(keep))
    indices = range(first, len(times))
    if position_limits is not None:
        lower, upper = position_limits
        for i in indices:
            out = np.flatnonzero((goal.positions[i] < lower - 1e-9)
                                 | (goal.positions[i] > upper + 1e-9))
            if out.size:
                j = int(out[0])
                raise TrajectoryError(
                    INVALID_GOAL, f'point {i}: {goal.joints[j]} at {goal.positions[i, j]:.4f} '
                    f'rad is outside its range [{lower[j]:.4f}, {upper[j]:.4f}]')
    knot_times = [max(begin, now)]
    knot_positions = [np.asarray(positions, dtype=float)]
    # Held until a future start: the arm is then at rest when the motion begins.
    knot_velocities: list[Optional[np.ndarray]] = [
        np.asarray(velocities, dtype=float) if knot_times[0] <= now else
        np.zeros(len(goal.joints))]
    knot_accelerations: list[Optional[np.ndarray]] = [np.zeros(len(goal.joints))]
    labels = ['the current state']
    for i in indices:
        knot_times.append(float(times[i]))
        knot_positions.append(goal.positions[i])
        knot_velocities.append(goal.velocities[i])
        knot_accelerations.append(goal.accelerations[i])
        labels.append(f'point {i}')
    if knot_times[1] - knot_times[0] < 1e-9:
        # Due at once: the first point must be where the arm already is.
        distance = np.abs(knot_positions[1] - knot_positions[0])
        j = int(np.argmax(distance))
        if distance[j] > START_TOLERANCE:
            raise TrajectoryError(
                INVALID_GOAL, f'{labels[1]} is due at once but {goal.joints[j]} is '
                f'{distance[j]:.4f} rad away from it (more than {START_TOLERANCE} rad): give '
                'the first point a time_from_start > 0')
        for values in (knot_times, knot_positions, knot_velocities, knot_accelerations, labels):
            del values[0]
    knot_t = np.array(knot_times)
    knot_p = np.array(knot_positions)
    filled = _fill_velocities(knot_t, knot_p, knot_velocities)
    coefficients = np.empty((len(knot_t) - 1, 6, len(goal.joints)))
    for k in range(len(knot_t) - 1):
        a0, a1 = knot_accelerations[k], knot_accelerations[k + 1]
        coefficients[k] = _segment(knot_t[k + 1] - knot_t[k], knot_p[k], knot_p[k + 1],
                                   filled[k], filled[k + 1],
                                   None if a0 is None or a1 is None else (a0, a1))
        _check_velocity(coefficients[k], knot_t[k + 1] - knot_t[k], velocity_limits,
                        goal.joints, labels[k], labels[k + 1])
    return Spline(knot_t, coefficients, knot_p[-1].copy())


def _fill_velocities(t: np.ndarray, p: np.ndarray,
                     given: list[Optional[np.ndarray]]) -> list[np.ndarray]:
    """Velocities at the knots: the given ones, else shape-preserving estimates, 0 at the end.

    The estimate (Fritsch-Butland) is 0 where a joint turns round and a weighted harmonic
    mean of the neighbouring slopes elsewhere, so the curve never overshoots a point.
    """
    filled = []
    last = len(t) - 1
    for k, velocity in enumerate(given):
        if velocity is not None:
            filled.append(velocity)
        elif k == 0 or k == last:
            filled.append(np.zeros(p.shape[1]))
        else:
            h0, h1 = t[k] - t[k - 1], t[k + 1] - t[k]
            d0, d1 = (p[k] - p[k - 1]) / h0, (p[k + 1] - p[k]) / h1
            w0, w1 = 2 * h1 + h0, h1 + 2 * h0
            same_sign = d0 * d1 > 0
            with np.errstate(divide='ignore', invalid='ignore'):
                estimate = (w0 + w1) / (w0 / d0 + w1 / d1)
            filled.append(np.where(same_sign, estimate, 0.0))
    return filled


def _segment(h: float, p0, p1, v0, v1, accelerations) -> np.ndarray:
    """Coefficients (6, J) of the cubic (or quintic, given accelerations) on [0, h]."""
    c = np.zeros((6, len(p0)))
    c[0], c[1] = p0, v0
    dp = p1 - p0
    if accelerations is None:
        c[2] = (3 * dp / h - 2 * v0 - v1) / h
        c[3] = (-2 * dp / h + v0 + v1) / h ** 2
    else:
        a0, a1 = accelerations
        c[2] = a0 / 2
        c[3] = (20 * dp - (8 * v1 + 12 * v0) * h - (3 * a0 - a1) * h ** 2) / (2 * h ** 3)
        c[4] = (-30 * dp + (14 * v1 + 16 * v0) * h + (3 * a0 - 2 * a1) * h ** 2) / (2 * h ** 4)
        c[5] = (12 * dp - 6 * (v1 + v0) * h - (a0 - a1) * h ** 2) / (2 * h ** 5)
    return c


def _check_velocity(c: np.ndarray, h: float, limits: np.ndarray, joints: Sequence[str],
                    start: str, end: str) -> None:
    _, velocity, _ = _evaluate(c, np.linspace(0.0, h, _SAMPLES_PER_SEGMENT))
    peak = np.abs(velocity).max(axis=0)
    over = peak > limits * (1 + _VELOCITY_SLACK)
    if over.any():
        j = int(np.argmax(np.where(over, peak / limits, 0.0)))
        raise TrajectoryError(
            INVALID_GOAL, f'from {start} to {end} ({h:.3f} s) {joints[j]} would need '
            f'{peak[j]:.3f} rad/s, above its limit of {limits[j]:.3f} rad/s: give that segment '
            f'at least {h * peak[j] / limits[j]:.3f} s')


def limits_of(joints: Sequence[str], limits: Mapping[str, object]) -> tuple[np.ndarray, ...]:
    """Return (velocity, lower, upper) arrays for ``joints`` from JointLimit-like objects."""
    return tuple(np.array([getattr(limits[name], field) for name in joints])
                 for field in ('velocity', 'lower', 'upper'))
