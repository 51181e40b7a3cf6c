"""The pick sequence (ur_rg2_motion.pick) alone, driving a scripted arm: no ROS, no sim."""

import numpy as np
import pytest
from real_robot_standins import ur_description
from ur_rg2_common.contract import RG2_MAX_OPENING
from ur_rg2_motion.kinematics import ArmKinematics, urdf_velocity_limits
from ur_rg2_motion.pick import (
    GripResult,
    PickCancelledError,
    PickError,
    PickSettings,
    run_pick,
    wait_for_rest,
)

URDF = ur_description('ur5')
SETTINGS = PickSettings(approach_height=0.1, lift_height=0.15, speed_scale=0.7,
                        approach_speed=0.25, grasp_tolerance=0.02)
BALL = np.array([0.4, -0.2, 0.03])  # base_link, on the table (floor at z = 0)
START = np.array([0.0, -1.9, 1.9, -1.57, -1.57, 0.0])


class ScriptedArm:
    """An arm that goes wherever it is sent at once; its gripper stops on a ball ``width``."""

    def __init__(self, width: float | None = 0.06) -> None:
        self.velocity_limits = urdf_velocity_limits(URDF)
        self.q = START.copy()
        self.width = width
        self.grip = RG2_MAX_OPENING
        self.steps: list[str] = []
        self.speeds = [0.0]  # the speed() answers, last one repeated
        self.on_close = None  # called when the gripper has closed
        self.after_lift = None  # the opening once lifted, if it changes

    def joints(self) -> np.ndarray:
        return self.q.copy()

    def speed(self) -> float:
        return self.speeds.pop(0) if len(self.speeds) > 1 else self.speeds[0]

    def opening(self) -> float:
        return self.grip

    def check(self) -> None:
        pass

    def vision_done(self) -> None:
        self.steps.append('vision done')

    def move(self, trajectory, what: str) -> None:
        self.steps.append(what)
        self.q = np.array(trajectory.positions[-1])
        if what == 'lifting the ball' and self.after_lift is not None:
            self.grip = self.after_lift

    def start_grip(self, opening: float) -> float:
        return opening

    def finish_grip(self, target: float, what: str) -> GripResult:
        self.steps.append(what)
        stalled = self.width is not None and target < self.width
        self.grip = self.width if stalled else target
        if target == 0.0 and self.on_close is not None:
            self.on_close(self)
        return GripResult(self.grip, stalled)


@pytest.fixture
def model() -> ArmKinematics:
    return ArmKinematics.from_urdf(URDF, tcp_offset=(0.0, 0.0, 0.18), floor_z=0.0,
                                   clearance=0.005)


def test_a_pick_opens_goes_above_descends_closes_and_lifts_holding_the_ball(model):
    arm = ScriptedArm()
    held = run_pick(arm, model, BALL, SETTINGS)
    assert held == pytest.approx(0.06)
    assert arm.steps == ['moving above the ball', 'opening the gripper',
                         'descending to the ball', 'closing the gripper', 'vision done',
                         'lifting the ball']
    lifted = model.tcp_pose(arm.q)
    assert np.allclose(lifted[:3, 3], BALL + (0, 0, SETTINGS.lift_height), atol=1e-6)
    assert lifted[2, 2] == pytest.approx(-1.0)  # pointing down


def test_a_gripper_closing_on_nothing_is_a_miss_before_the_lift(model):
    arm = ScriptedArm(width=None)
    with pytest.raises(PickError, match='missed: the gripper closed on nothing'):
        run_pick(arm, model, BALL, SETTINGS)
    assert 'lifting the ball' not in arm.steps


def test_a_stop_far_from_the_balls_diameter_is_a_miss(model):
    with pytest.raises(PickError, match="stopped at 100.0 mm, not about the ball's 60 mm"):
        run_pick(ScriptedArm(width=0.1), model, BALL, SETTINGS)


def test_a_ball_slipping_out_in_the_lift_is_dropped(model):
    arm = ScriptedArm()
    arm.after_lift = 0.0
    with pytest.raises(PickError, match='dropped: the gripper is at 0.0 mm after the lift, '
                                        '60.0 mm when it closed'):
        run_pick(arm, model, BALL, SETTINGS)


def test_an_arm_moved_by_another_command_while_closing_cancels_the_pick(model):
    arm = ScriptedArm()

    def reset(moved: ScriptedArm) -> None:
        moved.q = moved.q + 0.3
    arm.on_close = reset
    with pytest.raises(PickCancelledError, match='moved by another command while closing'):
        run_pick(arm, model, BALL, SETTINGS)
    assert 'lifting the ball' not in arm.steps


def test_a_ball_out_of_reach_is_refused_before_any_motion(model):
    arm = ScriptedArm()
    with pytest.raises(PickError, match='out of reach'):
        run_pick(arm, model, np.array([2.0, 0.0, 0.03]), SETTINGS)
    assert arm.steps == []


def test_the_pick_waits_for_the_arm_to_rest_and_gives_up_when_it_does_not():
    arm = ScriptedArm()
    arm.speeds = [0.5, 0.5, 0.0]
    wait_for_rest(arm, timeout=5.0)
    assert arm.speeds == [0.0]
    arm.speeds = [0.5]
    with pytest.raises(PickError, match='did not come to rest within 0.1 s'):
        wait_for_rest(arm, timeout=0.1)
