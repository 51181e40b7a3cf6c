"""The protective stop: the arm stops where it touches the floor, the pedestal or itself.

Plain Python, no ROS; runs on the simulation thread before every physics step, after the
controllers have set the joints' targets.

The arm is stopped at the touch, before the load builds up (docs/design.md says why):
whenever a link presses on an obstacle and the joints' targets would take it further in,
steeply, the arm goes back a little the way it came and holds there (the targets become those
positions). A target that moves the link away from the obstacle or along it is never held
back, so every command that moves away is obeyed. A reset whose straight way home is blocked
plans a way around (``Homing``).
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from ur_rg2_common.contract import ARM_JOINTS

from ur_rg2_sim.outputs import degrees_list
from ur_rg2_sim.planning import CollisionModel
from ur_rg2_sim.simulation import NS
from ur_rg2_sim.world import Contact, SimWorld

# A link is driven into an obstacle when it is sent into it at more than 30 degrees from the
# surface (the sine of that); more shallowly it slides along it, as a reset from a grasp on
# the floor scrapes the fingers over it and goes on home (docs/design.md).
MIN_INCIDENCE = 0.5
# Touching an obstacle and on its way somewhere, but stuck there (no arm joint faster than
# this, rad/s) for this long (s of simulation time): stopped all the same.
STUCK_SPEED = 0.05
STUCK_TIME = 0.25
# A stop on the same link and obstacle within this long of the last is not warned about again
# (s of simulation time).
REWARN_AFTER = 2.0
# On a stop the arm goes back this far (rad, the joint that moved most) the way it came, so
# that its motors stop pressing on the contact: about 4 mm at the UR5's wrist from the elbow.
BACK_OFF = 0.01
# The targets must take the contact point at least this far into the obstacle to count as
# driving into it (m): below, the few tenths of a mm that a held arm is pushed about by a
# contact, and a trajectory starting from there, would count.
APPROACH_TOLERANCE = 1e-3
# rad: a joint this near a waypoint of reset's way home has reached it (home: is home).
WAYPOINT_TOLERANCE = 0.01
# Plans reset makes, one after each stop on its way home, before the arm holds where it is.
MAX_PLANS = 4


@dataclass
class ProtectiveStop:
    """Holds the arm at a contact it is driven into; ``on_stop`` hears of each stop.

    ``on_stop(contact, held, new)`` is called on every stop with the contact that caused it,
    the joint positions held and whether it is new, worth a warning: not the same link on the
    same obstacle as a stop less than ``REWARN_AFTER`` ago (a key held down against the floor
    stops the arm at every repeat; the settling arm may stop again a few times).
    """

    on_stop: Callable[[Contact, dict[str, float], bool], None]
    _last_stop_ns: dict[tuple[str, str], int] = field(default_factory=dict)
    _stuck_since_ns: Optional[int] = None

    def step(self, world: SimWorld, now_ns: int) -> Optional[Contact]:
        """Check the contacts of the last physics step; stop the arm if it is driven in."""
        points = world.robot_contact_points()
        contacts = world.obstacle_contacts(points) if points else None
        if not contacts:  # most steps: nothing to judge, and not stuck on anything
            self._stuck_since_ns = None
            return None
        driven = [c for c in contacts
                  if c.approach > APPROACH_TOLERANCE and c.incidence > MIN_INCIDENCE]
        if driven:
            stop = max(driven, key=lambda c: c.approach)
        elif self._stuck(world, now_ns):
            # Sent along or away from what it touches, but held there: by friction, or by one
            # joint's motor pressing it on while the others pull it away.
            stop = max(contacts, key=lambda c: c.force)
        else:
            return None
        self._stuck_since_ns = None  # the next command gets its own time to move
        # Backing off a link sent along or away would take it back in: held where it is.
        held = world.hold_arm(BACK_OFF if stop.approach > APPROACH_TOLERANCE else 0.0)
        pair = (stop.link, stop.obstacle)
        last = self._last_stop_ns.get(pair)
        self._last_stop_ns[pair] = now_ns
        self.on_stop(stop, held, last is None or now_ns - last > REWARN_AFTER * NS)
        return stop

    def _stuck(self, world: SimWorld, now_ns: int) -> bool:
        """Return whether the arm, touching an obstacle, has not moved on its way for a while."""
        if not world.arm_on_its_way() or max(
                abs(v) for v in world.joint_states().velocities[:len(ARM_JOINTS)]) > STUCK_SPEED:
            self._stuck_since_ns = None
            return False
        if self._stuck_since_ns is None:
            self._stuck_since_ns = now_ns
        return now_ns - self._stuck_since_ns >= STUCK_TIME * NS


class Homing:
    """Reset's way home: straight in joint space, or along a planned path when that is blocked.

    ``start`` sends every joint home together (SimWorld.move_arm). From some poses that
    straight path is blocked: from an arm folded onto the floor the elbow opening presses the
    wrist in faster than the shoulder lifts it; on a UR3 a gripper turned back at the wrist
    meets the upper arm. After such a stop (``blocked``) reset plans a way around in
    ``model`` (ur_rg2_sim.planning) and follows it, waypoint by waypoint, each a straight
    joint move; a stop on the way plans again from there, up to
    MAX_PLANS times. Without a way home the arm holds where it is and ``on_give_up`` hears
    the joint positions it holds at. Any other command of the arm ends it (``cancel``). Runs
    on the simulation thread: ``step`` before every physics step, before the protective stop
    judges the targets.
    """

    def __init__(self, model: CollisionModel,
                 on_give_up: Callable[[list[float]], None]) -> None:
        self._model = model
        self._on_give_up = on_give_up
        self._waypoints: list[Sequence[float]] = []  # still to reach; the last is home
        self._replan = False
        self._plans = 0

    def start(self, world: SimWorld, home: Mapping[str, float]) -> dict[str, float]:
        """Send the arm home, all joints together; return the targets set."""
        applied = world.move_arm(home)
        self._waypoints = [[world.arm_targets[name] for name in ARM_JOINTS]]
        self._replan, self._plans = False, 0
        return applied

    def cancel(self) -> None:
        """Give the arm up to another command."""
        self._waypoints = []

    def blocked(self) -> None:
        """Hear of a protective stop: the way home is blocked."""
        self._replan = bool(self._waypoints)

    def step(self, world: SimWorld) -> None:
        """Plan after a stop; send the arm on to the next waypoint when it reached one."""
        if not self._waypoints:
            return
        positions = world.joint_states().positions
        arm = positions[:len(ARM_JOINTS)]
        if self._replan:
            self._replan = False
            self._plan(world, arm, positions[len(ARM_JOINTS):])
        elif max(abs(a - w) for a, w in zip(arm, self._waypoints[0])) <= WAYPOINT_TOLERANCE:
            self._waypoints.pop(0)
            if self._waypoints:
                world.move_arm(dict(zip(ARM_JOINTS, self._waypoints[0])))

    def _plan(self, world: SimWorld, arm: Sequence[float], gripper: Sequence[float]) -> None:
        home = self._waypoints[-1]
        path = None
        if self._plans < MAX_PLANS:
            self._plans += 1
            # Seeded: the same pose plans the same way, run after run.
            path = self._model.plan(arm, home, gripper, np.random.default_rng(self._plans))
        if path is None:
            self._waypoints = []
            self._on_give_up(list(arm))
            return
        self._waypoints = [list(pose) for pose in path[1:]]
        world.move_arm(dict(zip(ARM_JOINTS, self._waypoints[0])))


def describe(contact: Contact) -> str:
    """Return what touched what, for a person: 'wrist_1_link touched the floor'."""
    obstacle = (f'the {contact.obstacle}' if contact.obstacle in ('floor', 'pedestal')
                else f'the arm itself ({contact.obstacle})')
    return f'{contact.link} touched {obstacle}'


def protective_stop_message(contact: Contact, held: Mapping[str, float]) -> str:
    """Return what the sim says of a protective stop: what touched, where the arm holds."""
    return (f'protective stop: {describe(contact)} ({contact.force:.0f} N); the arm '
            f'holds at {degrees_list(held.values())} deg. Commands that move it away '
            '(reset, a jog or trajectory back) are obeyed')


def no_way_home_message(held: Sequence[float]) -> str:
    """Return what the sim says when reset finds no way home."""
    return (f'reset: no way home clear of the floor, the pedestal and the arm itself from '
            f'{degrees_list(held)} deg; the arm holds there. Jog it clear and reset again')
