"""The protective stop through the sim node's contract (INTERFACES.md, "Safety").

Each wedge of issue 21 (joint_command, a key held down in ``keys``, a trajectory) stops at the
contact with one warning naming the link and what it touched; then ``reset`` brings the arm
home within 10 s of simulation time and the RG2 opens and closes.
"""

import math

from conftest import start_sim, wait_for
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from test_sim_controllers import STILL, Controllers, trajectory
from test_sim_node import FAST, stamp_ns
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_sim.trajectory import PATH_TOLERANCE_VIOLATED

HOME_WITHIN = 10.0  # s of simulation time, the contract's
HOME_TOLERANCE = math.radians(0.5)
KEY_STEP = math.radians(5.0)  # keys' default step_deg
KEY_REPEATS = 40  # a key held down for over a second


class Sim(Controllers):
    """The controllers' probe, also keeping every joint state's stamp and arm positions."""

    def __init__(self, graph) -> None:
        super().__init__(graph)
        self.states: list[tuple[int, np.ndarray]] = []
        self.node.create_subscription(JointState, 'joint_states', lambda msg: self.states.append(
            (stamp_ns(msg), np.array(msg.position[:6]))), 1000)


@pytest.fixture
def sim(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    return Sim(ros_graph)


def protective_stops(sim) -> list[str]:
    return [w for w in sim.warnings() if w.startswith('protective stop')]


def wait_held(sim) -> np.ndarray:
    """Wait until the arm holds still away from home (joint_states may lag /rosout)."""
    def held():
        recent = [positions for _, positions in sim.states[-31:]]
        return (len(recent) == 31 and np.ptp(recent, axis=0).max() < STILL
                and np.abs(recent[-1]).max() > 0.05 and list(recent[-1]))
    return np.array(wait_for(held, 60, 'the arm to hold still where it stopped'))


def reset_home_time(sim) -> float:
    """Call reset; return the simulation time (s) the arm took to get home."""
    first = len(sim.states)
    answer = sim.call('reset')
    assert answer.success, answer.message

    def home():
        return next((stamp for stamp, positions in sim.states[first:]
                     if np.abs(positions).max() < HOME_TOLERANCE), None)
    arrived = wait_for(home, 60, 'the arm at home')
    # From the last state still where the arm was before the reset (which came after it):
    # the probe may see the states late on a loaded machine, the stamps are the simulation's.
    before = sim.states[first - 1][1]
    left = max(stamp for stamp, positions in sim.states
               if stamp < arrived and np.abs(positions - before).max() < 1e-3)
    return (arrived - left) / 1e9


def recover(sim, seen: int) -> None:
    """Check the arm holds after a stop, the RG2 answers and reset takes the arm home."""
    held = wait_held(sim)
    for service in ('gripper/close', 'gripper/open'):
        answer = sim.call(service)
        assert answer.success, (service, answer.message)
    assert sim.arm_positions() == pytest.approx(held, abs=1e-3)  # still held there
    assert reset_home_time(sim) < HOME_WITHIN
    assert len(protective_stops(sim)) == seen, 'the way home was stopped'
    for service in ('gripper/close', 'gripper/open'):
        answer = sim.call(service)
        assert answer.success, (service, answer.message)


def test_every_wedge_stops_with_one_warning_and_reset_brings_the_arm_home(sim):
    wedges = [
        ({'elbow_joint': 100.0}, 'the floor'),  # clamped to +pi
        ({'shoulder_lift_joint': 1.6}, 'the floor'),
        ({'shoulder_lift_joint': -0.9, 'elbow_joint': 2.9}, 'wrist_2_link touched the pedestal'),
        ({'elbow_joint': -4.0}, 'touched the arm itself (upper_arm_link)'),
    ]
    seen = 0
    for command, touched in wedges:
        sim.send(sim.command, list(command), list(command.values()))
        warnings = wait_for(lambda seen=seen: protective_stops(sim)[seen:], 60,
                            f'a stop on {touched}')
        seen += 1
        assert touched in warnings[0], warnings
        assert '_link' in warnings[0] or 'rg2_' in warnings[0]  # names the link
        assert len(protective_stops(sim)) == seen, protective_stops(sim)
        recover(sim, seen)


def test_a_key_held_down_into_the_floor_stops_once_and_a_jog_back_moves(sim):
    # What keys publishes while 'z' is held: one joint_jog of +step_deg per key repeat.
    for _ in range(KEY_REPEATS):
        sim.send(sim.jog, ['elbow_joint'], [KEY_STEP])
    wait_for(lambda: protective_stops(sim), 60, 'a protective stop')
    held = wait_held(sim)
    assert held[2] < math.radians(60), 'not stopped where it touched'
    assert len(protective_stops(sim)) == 1, protective_stops(sim)
    sim.send(sim.jog, ['elbow_joint'], [-2 * KEY_STEP])
    sim.wait_positions({'elbow_joint': held[2] - 2 * KEY_STEP}, tolerance=HOME_TOLERANCE)
    recover(sim, 1)


def test_a_blocked_trajectory_is_aborted_with_path_tolerance_violated(sim):
    goal = trajectory(['shoulder_lift_joint'], [(2.0, [1.6])])
    result, _ = sim.run(sim.arm, goal)
    assert result.result.error_code == PATH_TOLERANCE_VIOLATED, result.result.error_string
    assert 'protective stop' in result.result.error_string
    assert 'touched the floor' in result.result.error_string
    held = wait_held(sim)
    assert held[1] < 1.0  # stopped on the floor, not at the last point
    # A trajectory back up is obeyed.
    back = trajectory(ARM_JOINTS, [(2.0, [0.0] * 6)])
    result, _ = sim.run(sim.arm, back)
    assert result.result.error_code == 0, result.result.error_string


def test_a_reset_whose_straight_way_is_blocked_goes_round(ros_graph):
    # A UR3 with its RG2 turned back past the upper arm (wrist_1 turned first): wrist_2 alone,
    # straight home, would sweep the fingers through the upper arm.
    start_sim(ros_graph, robot_model='ur3', camera_rate=0.0, real_time_factor=FAST)
    sim = Sim(ros_graph)
    for command in ({'wrist_1_joint': 1.57}, {'wrist_2_joint': -2.2}, {'wrist_1_joint': 0.0}):
        sim.send(sim.command, list(command), list(command.values()))
        sim.wait_positions(command, tolerance=HOME_TOLERANCE)
    assert not protective_stops(sim)
    assert reset_home_time(sim) < HOME_WITHIN
    stops = wait_for(lambda: protective_stops(sim), 60, 'the stop on the straight way')
    assert len(stops) == 1 and 'touched the arm itself (upper_arm_link)' in stops[0], stops
    assert not [w for w in sim.warnings() if 'no way home' in w]


def test_a_reset_with_no_way_home_warns_and_the_arm_holds(ros_graph):
    node = start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    sim = Sim(ros_graph)
    # A home in the floor: the straight way there is stopped, and no way reaches it.
    floor_home = [0.0, 1.6, 0.0, 0.0, 0.0, 0.0]
    assert node.set_parameters([Parameter('home_position', value=floor_home)])[0].successful
    assert sim.call('reset').success
    warning, = wait_for(lambda: [w for w in sim.warnings() if 'no way home' in w], 60,
                        "reset's warning")
    assert 'the arm holds there' in warning and 'Jog it clear' in warning
    wait_held(sim)
    assert node.set_parameters([Parameter('home_position', value=[0.0] * 6)])[0].successful
    assert reset_home_time(sim) < HOME_WITHIN
