"""The trajectory logic alone: validation codes, spline shape, limits, outcomes (no ROS)."""

import math

import numpy as np
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_sim.execution import Execution
from ur_rg2_sim.trajectory import (
    GOAL_TOLERANCE_VIOLATED,
    INVALID_GOAL,
    INVALID_JOINTS,
    OLD_HEADER_TIMESTAMP,
    PATH_TOLERANCE_VIOLATED,
    SUCCESSFUL,
    Point,
    Tolerance,
    TrajectoryError,
    plan,
    validate,
)

JOINTS = ('elbow_joint', 'shoulder_pan_joint')
LIMITS = np.array([3.15, 3.15])


def goal(points, joints=JOINTS, **kwargs):
    return validate(joints, points, ARM_JOINTS, **kwargs)


def refused(code, *args, **kwargs):
    with pytest.raises(TrajectoryError) as error:
        goal(*args, **kwargs)
    assert error.value.code == code
    return str(error.value)


def test_each_invalid_goal_class_has_its_code():
    ok = [Point(1.0, [0.1, 0.2])]
    assert 'no_such_joint' in refused(INVALID_JOINTS, ok, joints=('elbow_joint', 'no_such_joint'))
    assert 'no joints' in refused(INVALID_JOINTS, [Point(1.0, [])], joints=())
    assert 'more than once' in refused(INVALID_JOINTS, ok, joints=('elbow_joint',) * 2)
    assert 'no points' in refused(INVALID_GOAL, [])
    assert '1 positions for 2' in refused(INVALID_GOAL, [Point(1.0, [0.1])])
    assert '1 velocities' in refused(INVALID_GOAL, [Point(1.0, [0.1, 0.2], [0.0])])
    assert 'not after' in refused(INVALID_GOAL, [Point(1.0, [0, 0]), Point(1.0, [0.1, 0])])
    assert 'not after' in refused(INVALID_GOAL, [Point(2.0, [0, 0]), Point(1.0, [0.1, 0])])
    assert 'finite' in refused(INVALID_GOAL, [Point(1.0, [math.nan, 0])])
    assert 'finite' in refused(INVALID_GOAL, [Point(1.0, [0, 0], [math.inf, 0])])
    assert 'finite' in refused(INVALID_GOAL, [Point(math.inf, [0, 0])])
    assert 'not a joint' in refused(INVALID_GOAL, ok, goal_tolerance=[Tolerance('wrist_1_joint')])


def test_cubic_through_points_is_c1_and_stops_at_the_end():
    g = goal([Point(1.0, [0.5, -0.2]), Point(2.0, [0.8, 0.3]), Point(3.0, [0.2, 0.3])])
    spline = plan(g, 10.0, None, np.zeros(2), np.zeros(2), LIMITS)
    for k, t in enumerate((11.0, 12.0, 13.0)):
        assert spline.sample(t)[0] == pytest.approx(g.positions[k])
        # C1: position and velocity continuous across each knot.
        before, after = spline.sample(t - 1e-7), spline.sample(t + 1e-7)
        assert before[0] == pytest.approx(after[0], abs=1e-6)
        assert before[1] == pytest.approx(after[1], abs=1e-5)
    assert spline.sample(10.0)[0] == pytest.approx([0, 0])
    assert spline.sample(13.0)[1] == pytest.approx([0, 0])
    # No overshoot: a joint turning round at a point stops there; a monotone one stays between.
    ts = np.linspace(10, 13, 3001)
    elbow = np.array([spline.sample(t)[0][0] for t in ts])
    pan = np.array([spline.sample(t)[0][1] for t in ts])
    assert elbow.max() == pytest.approx(0.8, abs=1e-9)
    assert pan.min() == pytest.approx(-0.2, abs=1e-9) and pan.max() == pytest.approx(0.3)


def test_given_velocities_and_accelerations_are_honoured():
    g = goal([Point(1.0, [0.5, 0.0], [0.4, 0.0], [0.1, 0.0]),
              Point(2.0, [1.0, 0.0], [0.0, 0.0], [0.0, 0.0])])
    spline = plan(g, 0.0, None, np.zeros(2), np.zeros(2), LIMITS)
    position, velocity, acceleration = spline.sample(1.0)
    assert velocity[0] == pytest.approx(0.4) and acceleration[0] == pytest.approx(0.1)


def test_future_start_holds_then_moves_and_past_points_are_skipped():
    g = goal([Point(1.0, [0.5, 0.0]), Point(2.0, [1.0, 0.0])])
    spline = plan(g, 5.0, 7.0, np.zeros(2), np.array([0.3, 0.0]), LIMITS)
    assert spline.start_time == 7.0 and spline.sample(6.0)[0] == pytest.approx([0, 0])
    assert spline.sample(8.0)[0] == pytest.approx([0.5, 0])
    late = plan(g, 8.5, 7.0, np.array([0.4, 0.0]), np.zeros(2), LIMITS)
    assert late.start_time == 8.5 and len(late.times) == 2
    with pytest.raises(TrajectoryError) as error:
        plan(g, 9.5, 7.0, np.zeros(2), np.zeros(2), LIMITS)
    assert error.value.code == OLD_HEADER_TIMESTAMP


def test_too_fast_and_out_of_range_are_refused_with_the_reason():
    g = goal([Point(0.1, [1.0, 0.0])])
    with pytest.raises(TrajectoryError) as error:
        plan(g, 0.0, None, np.zeros(2), np.zeros(2), LIMITS)
    assert error.value.code == INVALID_GOAL
    assert 'elbow_joint would need 15.000 rad/s' in str(error.value)
    with pytest.raises(TrajectoryError, match='outside its range'):
        plan(goal([Point(2.0, [4.0, 0.0])]), 0.0, None, np.zeros(2), np.zeros(2), LIMITS,
             (np.full(2, -math.pi), np.full(2, math.pi)))
    # A first point due at once must be where the arm is.
    with pytest.raises(TrajectoryError, match='due at once'):
        plan(goal([Point(0.0, [0.5, 0.0])]), 0.0, None, np.zeros(2), np.zeros(2), LIMITS)
    at_once = plan(goal([Point(0.0, [0.005, 0.0]), Point(1.0, [0.3, 0.0])]), 0.0, None,
                   np.zeros(2), np.zeros(2), LIMITS)
    assert at_once.start_time == 0.0 and len(at_once.times) == 2


def test_outcomes():
    g = goal([Point(1.0, [0.5, 0.0])], path_tolerance=[Tolerance('elbow_joint', 0.1)])
    run = Execution(g, plan(g, 0.0, None, np.zeros(2), np.zeros(2), LIMITS))
    assert run.update(0.5, run.desired(0.5)[0], np.zeros(2)) is None
    assert run.update(1.0, np.array([0.495, 0.0]), np.zeros(2)).code == SUCCESSFUL
    off = run.update(0.5, run.desired(0.5)[0] + [0.2, 0.0], np.zeros(2))
    assert off.code == PATH_TOLERANCE_VIOLATED and 'elbow_joint' in off.message
    assert run.update(1.5, np.array([0.45, 0.0]), np.zeros(2)) is None
    late = run.update(2.01, np.array([0.45, 0.0]), np.zeros(2))
    assert late.code == GOAL_TOLERANCE_VIOLATED and 'elbow_joint' in late.message
    tight = goal([Point(1.0, [0.5, 0.0])], goal_tolerance=[Tolerance('elbow_joint', 0.001)],
                 goal_time_tolerance=0.2)
    run = Execution(tight, plan(tight, 0.0, None, np.zeros(2), np.zeros(2), LIMITS))
    assert run.update(1.1, np.array([0.495, 0.0]), np.zeros(2)) is None
    assert run.update(1.21, np.array([0.495, 0.0]), np.zeros(2)).code == GOAL_TOLERANCE_VIOLATED
