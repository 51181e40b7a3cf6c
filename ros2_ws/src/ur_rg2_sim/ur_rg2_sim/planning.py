"""Reset's way home around the floor, the pedestal and the arm itself: a joint-space planner.

When the straight joint-space path home is blocked (the protective stop held the arm on it),
reset plans a path with RRT-Connect (Kuffner and LaValle, 2000) and shortens it by cutting
corners. Poses are tried in a ``CollisionModel``, a second pybullet world that is never
stepped, so that planning never disturbs the simulation. Plain Python and NumPy apart from
that world; ``plan_path`` takes any ``is_free(q)`` and is tested with made-up obstacles.
"""

from collections.abc import Callable, Sequence
from typing import Optional

import numpy as np
from ur_rg2_common.contract import ARM_JOINTS

from ur_rg2_sim.world import SimWorld, WorldConfig

Pose = np.ndarray
IsFree = Callable[[Pose], bool]

# A planned path keeps this far from every obstacle (m) where it can: about how far a link
# moves between two poses checked along a segment (SEGMENT_RESOLUTION at the UR5's reach of
# 0.85 m is 1.7 cm; more where several joints turn at once). A touch missed between two checks
# is still stopped by the protective stop, and reset plans again from there.
MARGIN = 0.02
# Where the arm starts closer than MARGIN (it was stopped at a contact), the path must leave
# the contact: it may come nearer than it started by at most SLIP (m), and must gain LIFT_OFF
# (m per rad of joint motion) from there until it has MARGIN. A path that slid along the floor
# got stuck: the shoulder's motor pressed a finger on, and friction held it.
SLIP = 1e-3
LIFT_OFF = 0.05
# rad: the largest step of any joint between two poses checked along a segment.
SEGMENT_RESOLUTION = 0.02
# rad: how far a tree grows toward a sample in one step.
EXTEND_STEP = 0.3
# rad: samples are drawn this far around the box spanned by the start and the goal (and within
# the joint limits): a way around an obstacle rarely needs a joint further out.
SAMPLE_SLACK = np.pi / 2
# Poses tried before giving up (bounds a fruitless search to about 2 s of the simulation
# thread, docs/design.md), and tries at cutting a corner of a path found.
MAX_CHECKS = 10_000
SHORTCUT_TRIES = 40


def segment_free(is_free: IsFree, a: Pose, b: Pose) -> bool:
    """Return whether the straight joint-space segment from ``a`` (free) to ``b`` is free."""
    steps = max(1, int(np.ceil(np.max(np.abs(b - a)) / SEGMENT_RESOLUTION)))
    return all(is_free(a + (b - a) * (i / steps)) for i in _coarse_to_fine(steps))


def _coarse_to_fine(steps: int) -> list[int]:
    """Return 1..steps, the end first, then halves, quarters...: a blocked segment fails fast."""
    order, seen = [steps], {0, steps}
    stride = 1 << max(steps - 1, 0).bit_length()
    while stride > 1:
        stride //= 2
        for i in range(stride, steps, stride):
            if i not in seen:
                seen.add(i)
                order.append(i)
    return order


def plan_path(is_free: IsFree, start: Pose, goal: Pose, lower: Pose, upper: Pose,
              rng: np.random.Generator) -> Optional[list[Pose]]:
    """Return free waypoints from ``start`` to ``goal`` (both included), or None.

    ``start`` is taken as free; ``lower`` and ``upper`` are the joint limits. None when the
    goal is not free or no way was found within MAX_CHECKS poses.
    """
    checks = 0

    def counted(pose: Pose) -> bool:
        nonlocal checks
        checks += 1
        if checks > MAX_CHECKS:
            raise _OutOfChecksError
        return is_free(pose)

    try:
        path = _connect_trees(counted, start, goal, lower, upper, rng)
    except _OutOfChecksError:
        return None
    return path if path is None else _shortcut(is_free, path, rng)


class _OutOfChecksError(Exception):
    """MAX_CHECKS poses were tried."""


def _connect_trees(is_free: IsFree, start: Pose, goal: Pose, lower: Pose, upper: Pose,
                   rng: np.random.Generator) -> Optional[list[Pose]]:
    if not is_free(goal):
        return None
    if segment_free(is_free, start, goal):
        return [start, goal]
    low = np.maximum(lower, np.minimum(start, goal) - SAMPLE_SLACK)
    high = np.minimum(upper, np.maximum(start, goal) + SAMPLE_SLACK)
    trees = (_Tree(start), _Tree(goal))
    while True:
        grown = trees[0].extend(is_free, rng.uniform(low, high))
        if grown is not None and trees[1].connect(is_free, grown):
            # Both trees hold ``grown`` now: root, ..., grown, ..., other root.
            path = trees[0].path_to_root()[::-1] + trees[1].path_to_root()[1:]
            return path if trees[0].root is start else path[::-1]
        trees = trees[::-1]


class _Tree:
    """One of RRT-Connect's two trees: poses and each one's parent."""

    def __init__(self, root: Pose) -> None:
        self.root = root
        self.poses = [root]
        self.parents = [-1]

    def extend(self, is_free: IsFree, toward: Pose) -> Optional[Pose]:
        """Grow one step from the nearest pose toward ``toward``; return the new pose."""
        nearest = int(np.argmin(np.linalg.norm(np.asarray(self.poses) - toward, axis=1)))
        base = self.poses[nearest]
        offset = toward - base
        length = float(np.linalg.norm(offset))
        new = toward if length <= EXTEND_STEP else base + offset * (EXTEND_STEP / length)
        if not segment_free(is_free, base, new):
            return None
        self.poses.append(new)
        self.parents.append(nearest)
        return new

    def connect(self, is_free: IsFree, target: Pose) -> bool:
        """Grow toward ``target`` until it is reached (True) or the way is blocked."""
        while True:
            new = self.extend(is_free, target)
            if new is None:
                return False
            if new is target:
                return True

    def path_to_root(self) -> list[Pose]:
        """Return the newest pose's way back to the root."""
        path, index = [], len(self.poses) - 1
        while index >= 0:
            path.append(self.poses[index])
            index = self.parents[index]
        return path


def _shortcut(is_free: IsFree, path: list[Pose], rng: np.random.Generator) -> list[Pose]:
    """Drop the waypoints between two that a free straight segment joins."""
    for _ in range(SHORTCUT_TRIES):
        if len(path) <= 2:
            break
        i, j = sorted(rng.choice(len(path), size=2, replace=False))
        if j - i > 1 and segment_free(is_free, path[i], path[j]):
            path = path[:i + 1] + path[j:]
    return path


class CollisionModel:
    """The robot, the floor and the pedestal in a world of their own, to try poses in."""

    def __init__(self, robot_model: str) -> None:
        self._world = SimWorld(WorldConfig(robot_model=robot_model))
        limits = [self._world.limits[name] for name in ARM_JOINTS]
        self._lower = np.array([limit.lower for limit in limits])
        self._upper = np.array([limit.upper for limit in limits])

    def clearance(self, arm: Sequence[float], gripper: Sequence[float]) -> float:
        """Return the robot's smallest gap to an obstacle in a pose, at most MARGIN (m)."""
        self._world.place_robot([*arm, *gripper])
        return self._world.clearance(MARGIN)

    def plan(self, start: Sequence[float], goal: Sequence[float], gripper: Sequence[float],
             rng: np.random.Generator) -> Optional[list[Pose]]:
        """Plan the arm's joints (ARM_JOINTS order) from ``start`` to ``goal``, or None.

        The gripper's joints stay at ``gripper`` (GRIPPER_JOINTS order).
        """
        start, goal = np.asarray(start, float), np.asarray(goal, float)
        at_start = self.clearance(start, gripper)

        def is_free(arm: Pose) -> bool:
            # Closer than MARGIN at the start (stopped at a contact): leave it, then keep MARGIN.
            needed = at_start - SLIP + LIFT_OFF * float(np.linalg.norm(arm - start))
            return self.clearance(arm, gripper) >= min(MARGIN, needed)

        return plan_path(is_free, start, goal, self._lower, self._upper, rng)

    def close(self) -> None:
        """Release the model's pybullet world."""
        self._world.close()
