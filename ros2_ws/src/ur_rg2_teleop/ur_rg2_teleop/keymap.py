"""Key bindings and jog step logic of the teleop, free of ROS and terminal handling."""

from dataclasses import dataclass
import enum
import math
from typing import Union

from ur_rg2_common.contract import ARM_JOINTS, EPISODE_FAILURE, EPISODE_START, EPISODE_SUCCESS

MIN_STEP_DEG = 0.5
MAX_STEP_DEG = 45.0
# The values + and - walk through; a step_deg set between two of them snaps to the next one.
STEP_LADDER_DEG = (0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 45.0)
# The same for the TCP steps of tool mode, in millimetres.
MIN_STEP_MM = 1.0
MAX_STEP_MM = 100.0
STEP_LADDER_MM = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
# Tool mode: what each jog key pair moves, in the joint order of the pairs.
TOOL_AXES = ('x', 'y', 'z', 'x', 'y', 'z')

CTRL_C = '\x03'


@dataclass(frozen=True)
class Jog:
    """Move arm joint ``joint`` (index into ARM_JOINTS) by one step in ``direction`` (+1/-1)."""

    joint: int
    direction: int


@dataclass(frozen=True)
class CallService:
    """Call the std_srvs/Trigger service ``service`` (a relative name)."""

    service: str


@dataclass(frozen=True)
class SendGoal:
    """Send a goal to the action ``action`` (a relative name), showing its phases and outcome."""

    action: str


@dataclass(frozen=True)
class CancelGoal:
    """Cancel the goal that keys sent to the action ``action``."""

    action: str


@dataclass(frozen=True)
class Mark:
    """Publish the episode marker ``marker`` (EPISODE_START, _SUCCESS, _FAILURE) on ``episode``."""

    marker: str


class Command(enum.Enum):
    """Actions handled by the key loop itself."""

    STEP_UP = enum.auto()
    STEP_DOWN = enum.auto()
    MODE = enum.auto()
    HELP = enum.auto()
    QUIT = enum.auto()


class Mode(enum.Enum):
    """What the six jog key pairs move."""

    JOINT = 'joint'  # one arm joint each (the default)
    TOOL = 'tool'  # the TCP along and about base_link's axes (tool_jog)


Action = Union[Jog, CallService, SendGoal, CancelGoal, Command, Mark]

# One pair per joint, in ARM_JOINTS order: first key +, second key -.
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
    'g': SendGoal('pick_ball'),
    'k': CancelGoal('pick_ball'),
    'b': Mark(EPISODE_START),
    'n': Mark(EPISODE_SUCCESS),
    'j': Mark(EPISODE_FAILURE),
    'm': Command.MODE,
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


def larger_step(step: float, ladder: tuple[float, ...] = STEP_LADDER_DEG) -> float:
    """Return the next ladder step above ``step``, at most the ladder's last."""
    return next((s for s in ladder if s > step + 1e-9), ladder[-1])


def smaller_step(step: float, ladder: tuple[float, ...] = STEP_LADDER_DEG) -> float:
    """Return the next ladder step below ``step``, at least the ladder's first."""
    return next((s for s in reversed(ladder) if s < step - 1e-9), ladder[0])


def describe_step(step: float, unit: str = 'deg',
                  ladder: tuple[float, ...] = STEP_LADDER_DEG) -> str:
    """Return the line shown after + or -, e.g. ``step 45 deg (the largest)``."""
    if step >= ladder[-1] - 1e-9:
        return f'step {step:g} {unit} (the largest)'
    if step <= ladder[0] + 1e-9:
        return f'step {step:g} {unit} (the smallest)'
    return f'step {step:g} {unit}'


def tool_step(jog: Jog, step_mm: float, step_deg: float) -> tuple[tuple, tuple]:
    """Return the tool_jog of a jog key in tool mode: translation (m) and xyzw rotation.

    The first three key pairs move the TCP along base_link x, y, z; the last three turn it
    about those axes.
    """
    axis = [0.0, 0.0, 0.0]
    axis['xyz'.index(TOOL_AXES[jog.joint])] = 1.0
    if jog.joint < 3:
        return tuple(jog.direction * step_mm / 1000 * a for a in axis), (0.0, 0.0, 0.0, 1.0)
    half = jog.direction * math.radians(step_deg) / 2
    return (0.0, 0.0, 0.0), (*(math.sin(half) * a for a in axis), math.cos(half))


def mode_line(mode: Mode, step_deg: float, step_mm: float) -> str:
    """Return the line shown when the mode changes: what the jog keys now do."""
    if mode is Mode.TOOL:
        return (f'tool mode: q/w a/s z/x move the TCP +/- {step_mm:g} mm along base_link x/y/z, '
                f'e/r d/f c/v turn it +/- {step_deg:g} deg about x/y/z (m: joint mode)')
    return f'joint mode: the key pairs jog one joint each by {step_deg:g} deg (m: tool mode)'


def help_text(step_deg: float, mode: Mode = Mode.JOINT, step_mm: float = 10.0) -> str:
    """Return the key table for ``mode``, one binding per line."""
    if mode is Mode.TOOL:
        rows = [(f'{plus} / {minus}',
                 f"TCP {'along' if joint < 3 else 'about'} base_link {TOOL_AXES[joint]} + / -")
                for joint, (plus, minus) in enumerate(_JOG_KEYS)]
        step = f'larger / smaller TCP step (now {step_mm:g} mm; turns {step_deg:g} deg)'
    else:
        rows = [(f'{plus} / {minus}', f'{ARM_JOINTS[joint]} + / -')
                for joint, (plus, minus) in enumerate(_JOG_KEYS)]
        step = f'larger / smaller step (now {step_deg:g} deg)'
    rows += [
        ('t / y', 'close / open the gripper'),
        ('l', 'reset the arm to its home pose'),
        ('space', 'save a camera frame'),
        ('g', 'pick the ball the camera sees'),
        ('k', 'cancel the pick: the arm stops where it is'),
        ('b / n / j', 'begin an episode / end it: a success / a failure'),
        ('m', f"switch to {'joint' if mode is Mode.TOOL else 'tool'} mode"),
        ('+ / -', step),
        ('h', 'this help'),
        ('p, Ctrl-C', 'quit'),
    ]
    lines = [f'UR + RG2 keyboard teleop, {mode.value} mode (upper case acts like lower case)']
    lines += [f'  {keys:<10} {what}' for keys, what in rows]
    return '\n'.join(lines)


def mark_line(marker: str) -> str:
    """Return the line shown when a key marks an episode."""
    if marker == EPISODE_START:
        return 'episode started (n: end it as a success, j: as a failure)'
    return f'episode ended: {marker}'
