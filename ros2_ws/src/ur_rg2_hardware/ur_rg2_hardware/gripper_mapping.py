"""Our GripperCommand contract in terms of OnRobot's ParallelGripperCommand. Plain Python.

Ours (INTERFACES.md, ``gripper_controller/gripper_cmd``): ``command.position`` is the opening
between the pads in m (0-0.110, clamped), ``max_effort`` in N (<= 0: 40 N; clamped to 3-40 N);
a grasp ends SUCCEEDED with ``stalled`` (stopped on an object before the target) and
``reached_goal`` is true within 2 mm of the target. OnRobot's RG2 driver (onrobot-ros2) moves
one joint, ``grip_stroke``: the opening in m. Its controller ends a stall SUCCEEDED with
``stalled`` when it allows stalling (OnRobot's configuration), ros2_controllers' gripper
controllers ABORTED (``allow_stalling: false``, their default): either is our grasp.
"""

from dataclasses import dataclass
import math

from ur_rg2_common.contract import RG2_MAX_FORCE, RG2_MAX_OPENING

RG2_MIN_FORCE = 3.0  # N (RG2 datasheet)
REACHED_TOLERANCE = 0.002  # m: reached_goal within this of the target
# A goal that ends this far short of a closing target stopped on something.
STALL_GAP = 0.002  # m


@dataclass(frozen=True)
class GripGoal:
    """A goal in the driver's terms: the stroke (m) and the force (N)."""

    position: float
    effort: float


@dataclass(frozen=True)
class GripOutcome:
    """Our result: whether the goal succeeded, and the GripperCommand result's fields."""

    succeeded: bool
    position: float
    effort: float
    stalled: bool
    reached_goal: bool


def grip_goal(position: float, max_effort: float) -> GripGoal:
    """Return the driver's goal for our ``command`` (opening m, max_effort N), clamped.

    Raises ValueError when a value is not finite.
    """
    if not (math.isfinite(position) and math.isfinite(max_effort)):
        raise ValueError(f'position {position} / max_effort {max_effort} is not finite')
    effort = RG2_MAX_FORCE if max_effort <= 0 else min(max(max_effort, RG2_MIN_FORCE),
                                                       RG2_MAX_FORCE)
    return GripGoal(min(max(position, 0.0), RG2_MAX_OPENING), effort)


def outcome(goal: GripGoal, start: float | None, succeeded: bool, aborted: bool,
            stalled: bool, position: float | None) -> GripOutcome:
    """Return our result of a driver's goal that ended.

    ``start``: the stroke when the goal was sent (None: unknown); ``succeeded`` / ``aborted``:
    how the driver ended it; ``stalled``: its flag; ``position``: the stroke at the end (None:
    unknown, taken as not reached).
    """
    if position is None:
        return GripOutcome(False, math.nan, goal.effort, False, False)
    reached = abs(position - goal.position) <= REACHED_TOLERANCE
    closing = start is None or goal.position < start
    # Ended SUCCEEDED short of a closing target: on an object, whatever the driver's flag says;
    # ended ABORTED, only with its stalled flag (else a fault).
    short = closing and not reached and position - goal.position > STALL_GAP
    grasp = closing and not reached and (stalled or (succeeded and short))
    ok = (succeeded and (reached or grasp)) or (aborted and grasp)
    return GripOutcome(ok, position, goal.effort, grasp, reached)
