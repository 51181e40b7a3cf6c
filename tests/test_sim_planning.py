"""Reset's planner (ur_rg2_sim.planning) alone: made-up obstacles, then the robot's own."""

import numpy as np
import pytest
from ur_rg2_common.contract import RG2_MAX_OPENING
from ur_rg2_sim.planning import (
    MARGIN,
    MAX_CHECKS,
    SEGMENT_RESOLUTION,
    CollisionModel,
    plan_path,
    segment_free,
)

LOWER, UPPER = np.full(2, -np.pi), np.full(2, np.pi)
OPEN = [RG2_MAX_OPENING / 2] * 2  # the RG2's finger joints, fully open


def wall(q: np.ndarray) -> bool:
    """Free unless in a wall 0.1 rad thick across x = 0.5, open above y = 1."""
    return not (abs(q[0] - 0.5) < 0.05 and q[1] < 1.0)


def assert_free_path(is_free, path, start, goal) -> None:
    assert np.array_equal(path[0], start) and np.array_equal(path[-1], goal)
    for a, b in zip(path, path[1:]):
        for t in np.linspace(0.0, 1.0, 200):
            assert is_free(a + (b - a) * t), (a, b, t)


@pytest.mark.parametrize('steps', [1, 2, 3, 7, 8, 33])
def test_a_segment_is_checked_at_every_step_the_end_first(steps):
    checked = []
    step = (steps - 0.5) / steps * SEGMENT_RESOLUTION  # a little under the resolution
    assert segment_free(lambda q: checked.append(round(q[0] / step)) is None, np.zeros(2),
                        np.array([steps * step, 0.0]))
    assert checked[0] == steps
    assert sorted(checked) == list(range(1, steps + 1))


def test_a_segment_through_an_obstacle_thinner_than_two_steps_is_blocked():
    thin = 1.5 * SEGMENT_RESOLUTION

    def is_free(q):
        return abs(q[0] - 0.5) >= thin / 2

    assert not segment_free(is_free, np.zeros(2), np.array([1.0, 0.0]))
    assert segment_free(is_free, np.zeros(2), np.array([0.4, 0.3]))


def test_a_free_straight_way_is_the_plan():
    start, goal = np.zeros(2), np.array([0.3, -0.2])
    path = plan_path(wall, start, goal, LOWER, UPPER, np.random.default_rng(0))
    assert len(path) == 2
    assert_free_path(wall, path, start, goal)


@pytest.mark.parametrize('seed', range(5))
def test_a_wall_is_gone_round(seed):
    start, goal = np.zeros(2), np.array([1.0, 0.0])
    path = plan_path(wall, start, goal, LOWER, UPPER, np.random.default_rng(seed))
    assert path is not None and len(path) >= 3
    assert_free_path(wall, path, start, goal)
    assert max(q[1] for q in path) >= 1.0  # over the top of the wall
    # Cutting corners keeps it short: the way round is 2.2 rad, a detour three times as long.
    length = sum(np.linalg.norm(b - a) for a, b in zip(path, path[1:]))
    assert length < 3 * 2.2


def test_the_same_pose_plans_the_same_way():
    start, goal = np.zeros(2), np.array([1.0, 0.0])
    first, second = (plan_path(wall, start, goal, LOWER, UPPER, np.random.default_rng(3))
                     for _ in range(2))
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


def test_no_way_is_none_after_a_bounded_search():
    calls = []

    def boxed_in(q):  # the goal in a ring: no way in
        calls.append(q)
        return not 0.1 <= np.linalg.norm(q - np.array([1.0, 0.0])) <= 0.3

    start, goal = np.zeros(2), np.array([1.0, 0.0])
    assert plan_path(boxed_in, start, goal, LOWER, UPPER, np.random.default_rng(0)) is None
    assert len(calls) <= MAX_CHECKS + 1
    assert plan_path(lambda q: q[0] < 0.9, start, goal, LOWER, UPPER,
                     np.random.default_rng(0)) is None  # the goal is in an obstacle


@pytest.fixture(scope='module')
def ur3():
    model = CollisionModel('ur3')
    yield model
    model.close()


def test_the_model_measures_the_gap_to_the_arm_itself(ur3):
    # The UR3 stretched out: its RG2 turned back at the wrist meets the upper arm.
    assert ur3.clearance([0.0] * 6, OPEN) == MARGIN  # home: clear by more than the margin
    assert ur3.clearance([0, 0, 0, 0, -1.5, 0], OPEN) < 0.0


def test_a_gripper_turned_back_into_the_upper_arm_plans_its_way_home(ur3):
    start, home = [0, 0, 0, 0, -2.2, 0], [0.0] * 6
    path = ur3.plan(start, home, OPEN, np.random.default_rng(1))
    assert path is not None and len(path) >= 3  # wrist_2 alone sweeps the fingers through it
    for a, b in zip(path, path[1:]):
        for t in np.linspace(0.0, 1.0, 100):
            assert ur3.clearance(a + (b - a) * t, OPEN) > 0.0
