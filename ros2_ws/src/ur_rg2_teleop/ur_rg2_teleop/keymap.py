"""Key bindings and jog step logic of the teleop, free of ROS and terminal handling."""

from dataclasses import dataclass
import enum
from typing import Union

JOINT_NAMES = (
    'shoulder_pan_joint',
    'shoulder_lift_joint',
    'elbow_joint',
    'wrist_1_joint',
    'wrist_2_joint',
    'wrist_3_joint',
)

MIN_STEP_DEG = 0.5
MAX_STEP_DEG = 45.0
# The values + and - walk through; a step_deg set between two of them snaps to the next one.
STEP_LADDER_DEG = (0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 45.0)

CTRL_C = '\x03'


@dataclass(frozen=True)
class Jog:
    """Move arm joint ``joint`` (index into JOINT_NAMES) by one step in ``direction`` (+1/-1)."""

    joint: int
    direction: int


@dataclass(frozen=True)
class CallService:
    """Call the std_srvs/Trigger service ``service`` (a relative name)."""

    service: str


class Command(enum.Enum):
    """Actions handled by the key loop itself."""

    STEP_UP = enum.auto()
    STEP_DOWN = enum.auto()
    HELP = enum.auto()
    QUIT = enum.auto()


Action = Union[Jog, CallService, Command]

# One pair per joint, in JOINT_NAMES order: first key +, second key -.
_JOG_KEYS = ('qw', 'as', 'zx', 'er', 'df', 'cv')

BINDINGS: dict[str, Action] = {
    **{
        key: Jog(joint, direction)
        for joint, pair in enumerate(_JOG_KEYS)
        for key, direction in zip(pair, (1, -1), strict=True)
    },
    't': CallService('gripper/close'),
    'y': CallService('gripper/open'),
    'l': CallService('reset'),
    ' ': CallService('vision/save_frame'),
    '+': Command.STEP_UP,
    '-': Command.STEP_DOWN,
    'h': Command.HELP,
    'p': Command.QUIT,
    CTRL_C: Command.QUIT,
}

SERVICES = tuple(a.service for a in BINDINGS.values() if isinstance(a, CallService))

# Names for the keys an unknown-key message is most likely about; escape sequences as xterm sends.
_KEY_NAMES = {
    '\x1b': 'Esc',
    '\x1b[A': 'Up',
    '\x1b[B': 'Down',
    '\x1b[C': 'Right',
    '\x1b[D': 'Left',
    '\x1bOA': 'Up',
    '\x1bOB': 'Down',
    '\x1bOC': 'Right',
    '\x1bOD': 'Left',
    '\r': 'Enter',
    '\n': 'Enter',
    '\t': 'Tab',
    '\x7f': 'Backspace',
}


def action_for(key: str) -> Action | None:
    """Return the action bound to ``key`` (one character or one escape sequence), or None."""
    # Only single characters fold case: the tail of an escape sequence is not a letter key.
    return BINDINGS.get(key.lower() if len(key) == 1 else key)


def describe_key(key: str) -> str:
    """Return a printable name for ``key``, e.g. ``'k'``, ``Up``, ``Ctrl-Z``."""
    if key in _KEY_NAMES:
        return _KEY_NAMES[key]
    if len(key) == 1 and ord(key) < 0x20:
        return f'Ctrl-{chr(ord(key) + 0x40)}'
    if key.isprintable():
        return repr(key)
    return ascii(key)


def larger_step(step_deg: float) -> float:
    """Return the next ladder step above ``step_deg``, at most MAX_STEP_DEG."""
    return next((s for s in STEP_LADDER_DEG if s > step_deg + 1e-9), MAX_STEP_DEG)


def smaller_step(step_deg: float) -> float:
    """Return the next ladder step below ``step_deg``, at least MIN_STEP_DEG."""
    return next((s for s in reversed(STEP_LADDER_DEG) if s < step_deg - 1e-9), MIN_STEP_DEG)


def help_text(step_deg: float) -> str:
    """Return the key table, one binding per line."""
    rows = [
        (f'{plus} / {minus}', f'{JOINT_NAMES[joint]} + / -')
        for joint, (plus, minus) in enumerate(_JOG_KEYS)
    ]
    rows += [
        ('t / y', 'close / open the gripper'),
        ('l', 'reset the arm to its home pose'),
        ('space', 'save a camera frame'),
        ('+ / -', f'larger / smaller step (now {step_deg:g} deg)'),
        ('h', 'this help'),
        ('p, Ctrl-C', 'quit'),
    ]
    lines = ['UR + RG2 keyboard teleop (upper case acts like lower case)']
    lines += [f'  {keys:<10} {what}' for keys, what in rows]
    return '\n'.join(lines)
