"""The controllers' simulation-thread halves on a world of their own (no ROS, no threads)."""

import math

import numpy as np
import pybullet
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_sim.drivers import ArmDriver, GripperDriver
from ur_rg2_sim.simulation import NS
from ur_rg2_sim.trajectory import SUCCESSFUL, Point, validate
from ur_rg2_sim.world import SimWorld, WorldConfig


class Stepper:
    """A world stepped by hand with the drivers' hooks, as SimulationLoop does."""

    def __init__(self) -> None:
        self.world = SimWorld(WorldConfig())
        self.arm, self.gripper = ArmDriver(), GripperDriver()
        self.now_ns = 0

    def step(self, seconds: float = 0.0, until=None, limit: float = 30.0) -> None:
        end = self.now_ns + round(seconds * NS)
        deadline = self.now_ns + round(limit * NS)
        while (self.now_ns < end or (until is not None and not until())):
            assert self.now_ns < deadline, 'no end within the simulated time limit'
            self.arm.step(self.world, self.now_ns)
            self.gripper.step(self.world, self.now_ns)
            self.world.step()
            self.now_ns += round(self.world.dt * NS)

    def arm_positions(self) -> np.ndarray:
        return np.array(self.world.joint_states().positions[:6])


@pytest.fixture
def stepper():
    s = Stepper()
    yield s
    s.world.close()


def test_tracking_error_across_the_workspace_stays_under_one_degree(stepper):
    points = [Point(2.0, [0.8, -1.0, 1.2, -0.5, 1.0, 1.5]),
              Point(4.0, [-0.5, -1.5, 2.0, 0.5, -1.0, -1.0]), Point(5.5, [0.0] * 6)]
    run = stepper.arm.start(stepper.world, 0, validate(ARM_JOINTS, points, ARM_JOINTS), None)
    errors = []
    while not run.done.done():
        stepper.step(stepper.world.dt)
        sample = run.sample
        if sample is not None and sample.time <= run.execution.spline.end_time:
            errors.append(np.abs(sample.desired[0] - sample.actual[0]).max())
    assert run.done.result().code == SUCCESSFUL
    assert math.degrees(np.percentile(errors, 99)) < 1.0
    assert stepper.arm_positions() == pytest.approx(np.zeros(6), abs=0.01)


def test_cancel_and_preempt_hold_the_arm(stepper):
    goal = validate(['shoulder_pan_joint'], [Point(3.0, [1.5])], ARM_JOINTS)
    run = stepper.arm.start(stepper.world, 0, goal, None)
    stepper.step(1.5)
    stepper.arm.cancel(stepper.world, run)
    assert run.done.result().status == 'canceled'
    stepper.step(1.0)
    held = stepper.arm_positions()
    assert 0.3 < held[0] < 1.2
    stepper.step(1.0)
    assert stepper.arm_positions() == pytest.approx(held, abs=1e-3)
    run = stepper.arm.start(stepper.world, stepper.now_ns, goal, None)
    stepper.step(0.5)
    stepper.arm.preempt('preempted by joint_jog')
    assert run.done.result().status == 'aborted'
    assert 'joint_jog' in run.done.result().message


def test_gripper_openings_and_a_grasp(stepper):
    for target, force in ((0.06, 0.0), (0.2, 10.0), (0.0, 2.0)):
        run = stepper.gripper.start(stepper.world, stepper.now_ns, target, force)
        stepper.step(until=run.done.done)
        assert run.done.result().status == 'succeeded'
        assert run.state.reached_goal and not run.state.stalled
        assert run.state.position == pytest.approx(min(target, 0.110), abs=0.002)
        assert run.force == (max(force, 3.0) if force > 0 else 40.0)
    open_run = stepper.gripper.start(stepper.world, stepper.now_ns, 0.11, 0.0)
    stepper.step(until=open_run.done.done)
    ball = np.array(stepper.world.config.ball_position)
    down = pybullet.getQuaternionFromEuler([math.pi, 0, 0])
    stepper.world.set_arm_positions(stepper.world.inverse_kinematics(ball, down))
    stepper.step(0.2)
    run = stepper.gripper.start(stepper.world, stepper.now_ns, 0.0, 0.0)
    stepper.step(until=run.done.done)
    assert run.state.stalled and not run.state.reached_goal
    assert run.state.position == pytest.approx(0.06, abs=0.005)
    assert run.state.effort == pytest.approx(40.0, abs=2.0)
    # A gripper service call preempts a running goal.
    run = stepper.gripper.start(stepper.world, stepper.now_ns, 0.11, 0.0)
    stepper.world.close_gripper()
    stepper.step(stepper.world.dt * 2)
    assert run.done.result().status == 'aborted'
