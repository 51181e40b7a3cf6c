"""The protective stop in the plain world (no ROS): every wedge of issue 21 stops and recovers.

Each case drives the arm from home into the floor, the pedestal or itself with one accepted
command (the sim node's joint_command path, SimWorld.move_arm), then checks that the arm holds
where it touched, that the RG2 still opens and closes, and that going home works.
"""

from contextlib import closing
from dataclasses import dataclass
import math

import numpy as np
import pytest
from ur_rg2_common.contract import ARM_JOINTS, RG2_MAX_OPENING
from ur_rg2_sim.planning import CollisionModel
from ur_rg2_sim.safety import MIN_INCIDENCE, Homing, ProtectiveStop, describe
from ur_rg2_sim.simulation import NS
from ur_rg2_sim.world import SELF_COLLISION_PAIRS, SimWorld, WorldConfig

# The contract's bound for reset, s of simulation time.
HOME_WITHIN = 10.0
HOME_TOLERANCE = math.radians(0.5)
STILL = math.radians(0.2)  # a held joint moves less than this in a second

WEDGES = {
    # issue 21's cases: the elbow clamped to +pi from home, the shoulder into the floor, the
    # wrist into the pedestal; folding the elbow shut meets the arm itself.
    'elbow to +pi': ({'elbow_joint': 100.0}, 'the floor'),
    'shoulder_lift 1.6': ({'shoulder_lift_joint': 1.6}, 'the floor'),
    'wrist into the pedestal': ({'shoulder_lift_joint': -0.9, 'elbow_joint': 2.9},
                                'wrist_2_link touched the pedestal'),
    'elbow folded shut': ({'elbow_joint': -4.0}, 'the arm itself (upper_arm_link)'),
}


class Rig:
    """A world stepped with reset's homing and the protective stop, as the sim node does."""

    def __init__(self, model: str = 'ur5') -> None:
        self.world = SimWorld(WorldConfig(robot_model=model))
        self.stops: list[tuple[str, bool]] = []
        self.now_ns = 0
        self.gave_up: list[list[float]] = []
        self.model = CollisionModel(model)
        self.homing = Homing(self.model, self.gave_up.append)
        self.stop = ProtectiveStop(self._on_stop)

    def _on_stop(self, contact, _held, new: bool) -> None:
        self.stops.append((describe(contact), new))
        self.homing.blocked()

    def close(self) -> None:
        self.model.close()
        self.world.close()

    def reset(self) -> None:
        """Send the arm home, as the sim's reset service does."""
        self.homing.start(self.world, dict.fromkeys(ARM_JOINTS, 0.0))

    def run(self, seconds: float, until=None) -> float:
        """Step up to ``seconds``; return the time taken until ``until()`` held (or all)."""
        for i in range(round(seconds / self.world.dt)):
            if until is not None and until():
                return i * self.world.dt
            self.homing.step(self.world)
            self.stop.step(self.world, self.now_ns)
            self.world.step()
            self.now_ns += round(self.world.dt * NS)
        return seconds

    def arm(self) -> list[float]:
        return self.world.joint_states().positions[:len(ARM_JOINTS)]

    def at_home(self) -> bool:
        return all(abs(p) < HOME_TOLERANCE for p in self.arm())

    def gripper_answers(self, target: float, free: bool = True) -> None:
        """Drive the fingers to ``target``; check they settle (there, if ``free``)."""
        self.world.command_gripper(target)
        # Asked every step, as the gripper services and action do: stopped for the last 0.1 s.
        stopped = []
        for _ in range(round(3.0 / self.world.dt)):
            self.run(self.world.dt)
            stopped.append(self.world.gripper_stopped())
        assert all(stopped[-round(0.1 / self.world.dt):])
        if free:
            assert self.world.gripper_opening() == pytest.approx(target, abs=2e-3)


@pytest.fixture
def rig():
    made = Rig()
    yield made
    made.close()


@pytest.mark.parametrize('case', list(WEDGES))
def test_a_wedge_stops_at_the_touch_and_every_way_out_works(rig, case):
    command, touched = WEDGES[case]
    rig.world.move_arm(command)
    rig.run(3.0)
    warned = [what for what, new in rig.stops if new]
    assert len(warned) == 1 and touched in warned[0], rig.stops
    # Held where it touched: no load building up, nothing creeping.
    before = rig.arm()
    rig.run(1.0)
    assert max(abs(a - b) for a, b in zip(rig.arm(), before)) < STILL
    assert all(c.force < 200.0 for c in rig.world.obstacle_contacts())
    # The RG2 answers: its fingers settle, though one may rest on the floor.
    rig.gripper_answers(0.0, free=False)
    rig.gripper_answers(RG2_MAX_OPENING, free=False)
    rig.reset()
    assert rig.run(HOME_WITHIN, rig.at_home) < HOME_WITHIN, rig.arm()
    rig.gripper_answers(0.0)
    rig.gripper_answers(RG2_MAX_OPENING)


def test_a_key_held_against_the_floor_stops_once_and_a_jog_back_moves(rig):
    # keys' 'z' held down: elbow +5 degrees per repeat, 30 repeats a second.
    for _ in range(60):
        rig.world.jog_arm({'elbow_joint': math.radians(5.0)})
        rig.run(1 / 30)
    assert [new for _, new in rig.stops].count(True) == 1, rig.stops
    assert 'touched the floor' in rig.stops[0][0]
    held = rig.arm()[2]
    assert held < math.radians(60.0)  # stopped at the touch, not pressed in 300 degrees on
    rig.world.jog_arm({'elbow_joint': -math.radians(10.0)})
    rig.run(1.0)
    assert rig.arm()[2] == pytest.approx(held - math.radians(10.0), abs=HOME_TOLERANCE)


def test_moving_along_the_floor_is_not_stopped(rig):
    rig.world.move_arm({'shoulder_lift_joint': 1.6})
    rig.run(2.0)
    count = len(rig.stops)
    # A turn about the vertical axis slides the fingers over the floor: no deeper in.
    rig.world.jog_arm({'shoulder_pan_joint': 0.5})
    rig.run(2.0)
    assert rig.arm()[0] == pytest.approx(0.5, abs=HOME_TOLERANCE)
    assert len(rig.stops) == count


@pytest.mark.parametrize('model', ['ur5', 'ur3'])
def test_self_collision_pairs_are_clear_in_ordinary_poses(model):
    world = SimWorld(WorldConfig(robot_model=model))
    try:
        index = {name: world.link_index(name) for pair in SELF_COLLISION_PAIRS for name in pair}
        ready = dict(zip(ARM_JOINTS, (0.0, -1.57, 1.57, -1.57, -1.57, 0.0)))
        for pose in ({}, ready, {'wrist_1_joint': 2.5}, {'wrist_1_joint': -2.5}):
            world.set_arm_positions({**dict.fromkeys(ARM_JOINTS, 0.0), **pose})
            for a, b in SELF_COLLISION_PAIRS:
                points = world._p.getClosestPoints(world.robot, world.robot, 0.02, index[a],
                                                   index[b])
                assert not points, (pose, a, b)
    finally:
        world.close()


@dataclass(frozen=True)
class Walk:
    """How a random walk drives the arm: which joints, how far."""

    joints: int  # the first this many of ARM_JOINTS
    most_at_once: int  # joints in one command, at most
    reach: float  # rad, joint commands go anywhere within plus or minus this
    jog: float  # rad, a jog's step
    shortest_wait: float  # s of simulation time between commands, at least


UPPER_ARM = Walk(joints=4, most_at_once=2, reach=math.pi, jog=math.radians(30.0),
                 shortest_wait=0.5)
WHOLE_ARM = Walk(joints=6, most_at_once=3, reach=2 * math.pi, jog=math.radians(45.0),
                 shortest_wait=0.3)


def wedge_walk(rig: Rig, rng: np.random.Generator, walk: Walk = UPPER_ARM) -> None:
    """Drive the arm by a few random joint commands and jogs, into whatever."""
    for _ in range(int(rng.integers(1, 8))):
        joints = rng.choice(ARM_JOINTS[:walk.joints],
                            size=int(rng.integers(1, walk.most_at_once + 1)), replace=False)
        if rng.random() < 0.5:
            rig.world.move_arm(
                {str(j): float(rng.uniform(-walk.reach, walk.reach)) for j in joints})
        else:
            rig.world.jog_arm({str(j): float(rng.choice([-1, 1]) * walk.jog) for j in joints})
        rig.run(float(rng.uniform(walk.shortest_wait, 3.0)))


# Walks after which reset's straight joint path home is blocked (the wrist or the fingers
# on the floor): 5 of 1,400 walks. The way round is planned.
@pytest.mark.parametrize('seed', [531, 1001, 1178, 1182])
def test_reset_takes_a_detour_home_when_its_straight_path_is_blocked(rig, seed):
    wedge_walk(rig, np.random.default_rng(seed))
    stops = len(rig.stops)
    rig.reset()
    assert rig.run(HOME_WITHIN, rig.at_home) < HOME_WITHIN, rig.arm()
    assert len(rig.stops) > stops  # the straight way was blocked
    rig.gripper_answers(0.0)
    rig.gripper_answers(RG2_MAX_OPENING)


# Walks that pressed the upper arm onto the pedestal's edge with 1.5-2.3 kN and left it there
# for good, while the contact's motion was reckoned about the link's centre of mass (the
# motion into the edge came out as a motion away from it).
@pytest.mark.parametrize('seed', [40, 168, 250, 262, 276, 283, 346])
def test_the_upper_arm_stops_at_the_pedestal_edge_and_reset_brings_it_home(rig, seed):
    wedge_walk(rig, np.random.default_rng(seed))
    assert all(c.force < 200.0 for c in rig.world.obstacle_contacts())
    rig.reset()
    assert rig.run(HOME_WITHIN, rig.at_home) < HOME_WITHIN, rig.arm()


def test_a_contacts_approach_is_how_far_the_targets_take_it_in(rig):
    # The upper arm on the pedestal's edge (the forearm folded up), sent further down: its
    # contact point lies 0.28 m from the link's centre of mass.
    world = rig.world
    world.set_arm_positions({'shoulder_lift_joint': 0.26, 'elbow_joint': -2.5})
    world.set_arm_targets({'shoulder_lift_joint': 0.31})
    world.step()
    contact, = [c for c in world.obstacle_contacts() if c.link == 'upper_arm_link']
    assert contact.obstacle == 'pedestal'
    assert contact.incidence > MIN_INCIDENCE

    def gap() -> float:
        return min(point[8] for point in world._p.getClosestPoints(
            world.robot, world.pedestal, 0.05, world.link_index('upper_arm_link'), -1))

    # The same motion measured: how much the gap shrinks with the joints at their targets.
    before = gap()
    world.set_arm_positions(world.arm_targets)
    # 0.05 rad at 0.14 m from the joint's axis: first-order, within a millimetre.
    assert contact.approach == pytest.approx(before - gap(), abs=1e-3)


# Walks of the whole arm that stayed stuck before reset planned its way home: the RG2 turned
# back into the UR3's upper arm (wrist_2 alone sweeps it through), the UR5's fingers on the
# floor, pressed on by the shoulder's motor while the wrists pulled away (stuck on friction,
# which the stop did not see: the link was not sent into the floor).
@pytest.mark.parametrize('model, seed', [('ur3', 82), ('ur3', 115), ('ur3', 156), ('ur3', 258),
                                         ('ur5', 824), ('ur5', 829), ('ur5', 927),
                                         ('ur5', 1027)])
def test_reset_plans_its_way_home_after_a_walk_of_the_whole_arm(model, seed):
    with closing(Rig(model)) as rig:
        wedge_walk(rig, np.random.default_rng(seed), WHOLE_ARM)
        rig.reset()
        assert rig.run(HOME_WITHIN, rig.at_home) < HOME_WITHIN, rig.arm()
        assert not rig.gave_up


def test_the_gripper_turned_back_past_the_upper_arm_goes_home_round_it():
    # A UR3: wrist_1 turned first, the RG2 turns back past the upper arm; with wrist_1 back,
    # wrist_2 straight home would sweep the fingers through the upper arm.
    with closing(Rig('ur3')) as rig:
        for command in ({'wrist_1_joint': 1.57}, {'wrist_2_joint': -2.2}, {'wrist_1_joint': 0.0}):
            rig.world.move_arm(command)
            rig.run(3.0)
        assert not rig.stops
        rig.reset()
        assert rig.run(HOME_WITHIN, rig.at_home) < HOME_WITHIN, rig.arm()
        assert [what for what, _ in rig.stops] == [
            'rg2_left_finger touched the arm itself (upper_arm_link)']


def test_with_no_way_home_the_arm_holds_and_reset_says_so(rig):
    # A home in the floor: the straight way is stopped, and no plan reaches it.
    rig.homing.start(rig.world, {**dict.fromkeys(ARM_JOINTS, 0.0), 'shoulder_lift_joint': 1.6})
    rig.run(3.0)
    assert len(rig.gave_up) == 1
    # Held where the stop left it (just clear of the floor), not creeping.
    before = rig.arm()
    rig.run(1.0)
    assert max(abs(a - b) for a, b in zip(rig.arm(), before)) < STILL
    rig.reset()  # the real home
    assert rig.run(HOME_WITHIN, rig.at_home) < HOME_WITHIN, rig.arm()
