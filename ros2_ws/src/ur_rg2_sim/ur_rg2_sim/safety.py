"""The protective stop: the arm stops where it touches the floor, the pedestal or itself.

Plain Python, no ROS; runs on the simulation thread before every physics step, after the
controllers have set the joints' targets.

Why the arm used to wedge: the position motors push with their full torque (150 N·m at the
UR5's shoulder and elbow) for as long as the target lies beyond an obstacle, so a link driven
into the floor ends up pressed on it with 200-800 N. Friction on that contact is then more
than the other joints' motors can overcome, and the RG2's 40 N finger motors, pressed on
the floor, neither move nor settle. A reset does not help: the joints move independently,
and the shortest move (the shoulder, back down) presses the link in again before the others
have pulled it clear.

So the arm is stopped at the touch, before the load builds up: whenever a link presses on an
obstacle and the joints' targets would take it further in, steeply, the arm goes back a
little the way it came and holds there (the targets become those positions). A target that
moves the link away from the obstacle or along it is never held back, so every command that
moves away is obeyed. A reset whose straight way home is blocked so takes a detour
(``Homing``). With it go two fixes in the world (ur_rg2_sim.world): joint commands
and reset move the joints together (``SimWorld.move_arm``), and a finger at its target counts
as stopped, however the solver jitters its speed (``SimWorld.gripper_stopped``).
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Optional

from ur_rg2_common.contract import ARM_JOINTS

from ur_rg2_sim.simulation import NS
from ur_rg2_sim.world import Contact, SimWorld

# A link is driven into an obstacle when it is sent into it at more than 30 degrees from the
# surface (the sine of that); more shallowly it slides along it, as a reset from a grasp on
# the floor scrapes the fingers over it (at about 16 degrees) and goes on home. Every wedge
# of issue 21 came in at 40 degrees or more.
MIN_INCIDENCE = 0.5
# Sent along an obstacle but stuck on it (no arm joint faster than this, rad/s) for this long
# (s of simulation time): blocked all the same.
BLOCKED_SPEED = 0.05
BLOCKED_TIME = 0.25
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
# Reset's detour when its straight path is blocked: one joint after another, the upper arm
# first, so that each move lifts the arm off what it touched rather than sweeping it along.
HOMING_ORDER = ('shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint', 'wrist_2_joint',
                'wrist_3_joint', 'shoulder_pan_joint')
# rad: on the detour a joint this near home is home enough for the next one to go (at the end
# all of them go the rest of the way together).
HOME_TOLERANCE = 0.01


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
    _blocked_since_ns: Optional[int] = None

    def step(self, world: SimWorld, now_ns: int) -> Optional[Contact]:
        """Check the contacts of the last physics step; stop the arm if it is driven in."""
        pressed = [c for c in world.obstacle_contacts() if c.approach > APPROACH_TOLERANCE]
        driven = [c for c in pressed if c.incidence > MIN_INCIDENCE]
        if pressed and not driven:
            # Sent along the obstacle: fine while it slides, a stop once it is stuck there.
            if max(abs(v) for v in world.joint_states().velocities[:len(ARM_JOINTS)]) > \
                    BLOCKED_SPEED:
                self._blocked_since_ns = None
            elif self._blocked_since_ns is None:
                self._blocked_since_ns = now_ns
            elif now_ns - self._blocked_since_ns >= BLOCKED_TIME * NS:
                driven = pressed
        if not driven:
            if not pressed:
                self._blocked_since_ns = None
            return None
        self._blocked_since_ns = None
        stop = max(driven, key=lambda c: c.approach)
        held = world.hold_arm(BACK_OFF)
        pair = (stop.link, stop.obstacle)
        last = self._last_stop_ns.get(pair)
        self._last_stop_ns[pair] = now_ns
        self.on_stop(stop, held, last is None or now_ns - last > REWARN_AFTER * NS)
        return stop


class Homing:
    """Reset's way home: straight in joint space, or joint by joint when that is blocked.

    ``start`` sends every joint home together (SimWorld.move_arm). From some poses on the
    floor that straight path is blocked: the elbow opening presses the wrist into the floor
    faster than the shoulder lifts it, and the protective stop holds the arm at once. After
    such a stop (``blocked``) the joints go home one at a time in HOMING_ORDER; a joint that
    is stopped in its turn is tried again after the others, round after round, until every
    joint is home or a round brought the arm no nearer (then it holds where it is). Any
    other command of the arm ends it (``cancel``). Runs on the simulation thread: ``step``
    before every physics step, before the protective stop judges the targets.
    """

    def __init__(self) -> None:
        self._home: Optional[dict[str, float]] = None
        self._detour = False
        self._joint: Optional[str] = None  # the joint going home on the detour
        self._stopped: set[str] = set()  # joints stopped in this round of the detour
        # The joints' summed distance from home when the round began, rad.
        self._round_distance: Optional[float] = None

    def start(self, world: SimWorld, home: Mapping[str, float]) -> dict[str, float]:
        """Send the arm home, all joints together; return the targets set."""
        applied = world.move_arm(home)
        self._home = dict(applied)
        self._detour, self._joint, self._stopped, self._round_distance = False, None, set(), None
        return applied

    def cancel(self) -> None:
        """Give the arm up to another command."""
        self._home = None

    def blocked(self) -> None:
        """Hear of a protective stop: the way home, or the joint going home, is blocked."""
        if self._home is None:
            return
        if self._joint is not None:
            self._stopped.add(self._joint)
        self._detour, self._joint = True, None

    def step(self, world: SimWorld) -> None:
        """Send the next joint home when the one going home is there or was stopped."""
        if self._home is None:
            return
        positions = dict(zip(ARM_JOINTS, world.joint_states().positions))
        errors = {name: abs(positions[name] - self._home[name]) for name in HOMING_ORDER}
        away = [name for name in HOMING_ORDER if errors[name] > HOME_TOLERANCE]
        if not away:
            if self._detour:
                # The last few mrad together (a stop's hold may have left some joints short).
                world.move_arm(self._home)
            self._home = None
            return
        if not self._detour or self._joint in away:
            return
        distance = sum(errors.values())
        if self._round_distance is None:
            self._round_distance = distance
        waiting = [name for name in away if name not in self._stopped]
        if not waiting:  # the round is over
            if distance >= self._round_distance:
                self._home = None  # no nearer: hold where it is
                return
            self._stopped, self._round_distance, waiting = set(), distance, away
        self._joint = waiting[0]
        world.move_arm({self._joint: self._home[self._joint]})


def describe(contact: Contact) -> str:
    """Return what touched what, for a person: 'wrist_1_link touched the floor'."""
    obstacle = (f'the {contact.obstacle}' if contact.obstacle in ('floor', 'pedestal')
                else f'the arm itself ({contact.obstacle})')
    return f'{contact.link} touched {obstacle}'
