"""Plain unit tests of the teleop's key map, step logic, key splitting and display logic."""

import io
import math
import os
import signal
import termios
import threading

import pytest
from ur_rg2_teleop.display import Console, SettleWatcher, arm_values, format_angles
from ur_rg2_teleop.keymap import (
    BINDINGS,
    MAX_STEP_DEG,
    MAX_STEP_MM,
    MIN_STEP_DEG,
    MIN_STEP_MM,
    STEP_LADDER_MM,
    CallService,
    CancelGoal,
    Command,
    Jog,
    Mark,
    Mode,
    SendGoal,
    action_for,
    describe_key,
    describe_step,
    help_text,
    larger_step,
    mode_line,
    smaller_step,
    tool_step,
)
from ur_rg2_teleop.terminal import KeyReader, Stop, raw_mode, signal_pipe, split_keys

CONTRACT_JOGS = {
    'q': Jog(0, 1), 'w': Jog(0, -1),
    'a': Jog(1, 1), 's': Jog(1, -1),
    'z': Jog(2, 1), 'x': Jog(2, -1),
    'e': Jog(3, 1), 'r': Jog(3, -1),
    'd': Jog(4, 1), 'f': Jog(4, -1),
    'c': Jog(5, 1), 'v': Jog(5, -1),
}
CONTRACT_OTHERS = {
    't': CallService('gripper/close'),
    'y': CallService('gripper/open'),
    'l': CallService('reset'),
    ' ': CallService('vision/save_frame'),
    'g': SendGoal('pick_ball'),
    'k': CancelGoal('pick_ball'),
    'b': Mark('start'),
    'n': Mark('success'),
    'j': Mark('failure'),
    'm': Command.MODE,
    '+': Command.STEP_UP,
    '-': Command.STEP_DOWN,
    'h': Command.HELP,
    'p': Command.QUIT,
    '\x03': Command.QUIT,
}


def test_bindings_are_exactly_the_contract():
    assert BINDINGS == {**CONTRACT_JOGS, **CONTRACT_OTHERS}


@pytest.mark.parametrize('key', sorted(CONTRACT_JOGS) + ['t', 'y', 'l', 'g', 'k', 'm', 'h',
                                                         'p'])
def test_upper_case_acts_like_lower_case(key):
    assert action_for(key.upper()) == action_for(key)


@pytest.mark.parametrize('key', ['o', 'O', '1', '\r', '\x1b', '\x1b[A', '\x1bOB', '\x1b[1;5C',
                                 '\x1bq', 'é', '\x1a'])
def test_unknown_keys_have_no_action(key):
    assert action_for(key) is None


@pytest.mark.parametrize(('key', 'name'), [
    ('k', "'k'"), ('\x1b[A', 'Up'), ('\x1bOD', 'Left'), ('\x1b', 'Esc'), ('\x1a', 'Ctrl-Z'),
    ('\r', 'Enter'), ('é', "'é'"), ('\x1b[5~', "'\\x1b[5~'"),
])
def test_describe_key(key, name):
    assert describe_key(key) == name


def test_help_names_every_key_and_the_step():
    text = help_text(7.5)
    key_column = {word for line in text.splitlines()[1:]
                  for word in line[:13].replace(',', ' ').split()}
    labels = {' ': 'space', '\x03': 'Ctrl-C'}
    assert {labels.get(key, key) for key in BINDINGS} <= key_column
    assert '7.5 deg' in text


@pytest.mark.parametrize(('step', 'larger', 'smaller'), [
    (5.0, 10.0, 2.0),
    (0.5, 1.0, 0.5),
    (45.0, 45.0, 30.0),
    (7.0, 10.0, 5.0),
    (0.6, 1.0, 0.5),
    (44.0, 45.0, 30.0),
])
def test_step_ladder(step, larger, smaller):
    assert larger_step(step) == larger
    assert smaller_step(step) == smaller


def test_help_in_tool_mode_names_the_axes_the_mode_and_the_steps():
    text = help_text(7.5, Mode.TOOL, 20.0)
    assert 'tool mode' in text.splitlines()[0]
    assert 'q / w' in text and 'TCP along base_link x + / -' in text
    assert 'c / v' in text and 'TCP about base_link z + / -' in text
    assert '20 mm' in text and '7.5 deg' in text
    assert 'switch to joint mode' in text
    assert 'joint mode' in help_text(5.0).splitlines()[0]
    assert 'pick the ball' in help_text(5.0) and 'cancel the pick' in help_text(5.0)


def test_tool_steps_move_along_and_turn_about_base_link_axes():
    translation, rotation = tool_step(Jog(1, -1), 10.0, 5.0)  # s: -10 mm along y
    assert translation == pytest.approx((0.0, -0.01, 0.0)) and rotation == (0, 0, 0, 1)
    translation, rotation = tool_step(Jog(5, 1), 10.0, 90.0)  # c: +90 deg about z
    assert translation == (0.0, 0.0, 0.0)
    assert rotation == pytest.approx((0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)))


def test_mode_line_says_what_the_keys_do():
    assert mode_line(Mode.TOOL, 5.0, 10.0).startswith('tool mode: q/w a/s z/x move the TCP '
                                                      '+/- 10 mm')
    assert mode_line(Mode.JOINT, 5.0, 10.0).startswith('joint mode')


def test_millimetre_ladder():
    assert larger_step(10.0, STEP_LADDER_MM) == 20.0
    assert smaller_step(1.0, STEP_LADDER_MM) == MIN_STEP_MM
    assert larger_step(100.0, STEP_LADDER_MM) == MAX_STEP_MM
    assert describe_step(MAX_STEP_MM, 'mm', STEP_LADDER_MM) == 'step 100 mm (the largest)'


def test_the_step_line_names_the_limits():
    assert describe_step(5.0) == 'step 5 deg'
    assert describe_step(MAX_STEP_DEG) == 'step 45 deg (the largest)'
    assert describe_step(MIN_STEP_DEG) == 'step 0.5 deg (the smallest)'


def test_steps_stay_within_bounds_however_often_pressed():
    step = 5.0
    for _ in range(20):
        step = larger_step(step)
    assert step == MAX_STEP_DEG
    for _ in range(20):
        step = smaller_step(step)
    assert step == MIN_STEP_DEG


@pytest.mark.parametrize(('data', 'keys', 'tail'), [
    (b'qwQ', ['q', 'w', 'Q'], b''),
    (b'\x1b[Aq', ['\x1b[A', 'q'], b''),
    (b'\x1b[1;5Cx', ['\x1b[1;5C', 'x'], b''),
    (b'\x1bOBz', ['\x1bOB', 'z'], b''),
    (b'\x1b\x1b[D', ['\x1b', '\x1b[D'], b''),
    (b'\x1bq', ['\x1bq'], b''),
    ('é€q'.encode(), ['é', '€', 'q'], b''),
    (b'q\x1b', ['q'], b'\x1b'),
    (b'q\x1b[1;', ['q'], b'\x1b[1;'),
    (b'\x1bO', [], b'\x1bO'),
    ('€'.encode()[:2], [], '€'.encode()[:2]),
    (b'\x1b[' + b'1' * 20 + b'q', ['\x1b[' + '1' * 14, *'111111', 'q'], b''),
])
def test_split_keys(data, keys, tail):
    assert split_keys(data) == (keys, tail)


def test_split_keys_never_returns_bracket_letters_of_an_arrow():
    keys, tail = split_keys(b'\x1b[A\x1b[B\x1b[C\x1b[D')
    assert keys == ['\x1b[A', '\x1b[B', '\x1b[C', '\x1b[D'] and tail == b''
    assert not any(action_for(k) for k in keys)


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    yield master, slave
    os.close(master)
    os.close(slave)


def test_key_reader_joins_an_escape_sequence_split_across_reads(pty_pair):
    master, slave = pty_pair
    with raw_mode(slave):
        reader = KeyReader(slave)
        os.write(master, b'\x1b[')
        timer = threading.Timer(0.01, os.write, (master, b'Aq'))
        timer.start()
        keys = reader.read(timeout=1.0)
        timer.join()
        keys += reader.read(timeout=0.0)
    assert keys == ['\x1b[A', 'q']


def test_key_reader_takes_a_lone_escape_as_esc_and_times_out_empty(pty_pair):
    master, slave = pty_pair
    with raw_mode(slave):
        reader = KeyReader(slave)
        assert reader.read(timeout=0.01) == []
        os.write(master, b'\x1b')
        assert reader.read(timeout=1.0) == ['\x1b']


def test_terminal_going_away_ends_reading_and_needs_no_restore():
    master, slave = os.openpty()
    try:
        with pytest.raises(EOFError), raw_mode(slave):
            os.close(master)
            KeyReader(slave).read(timeout=1.0)
    finally:
        os.close(slave)


def test_raw_mode_restores_exact_attributes_on_exception(pty_pair):
    _, slave = pty_pair
    before = termios.tcgetattr(slave)
    with pytest.raises(ZeroDivisionError), raw_mode(slave):
        raw = termios.tcgetattr(slave)
        assert not raw[3] & (termios.ECHO | termios.ICANON | termios.ISIG)
        assert raw[1] & termios.OPOST
        1 / 0  # noqa: B018 - the exception under test
    assert termios.tcgetattr(slave) == before


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_a_signal_stops_the_key_reader_and_handlers_come_back(pty_pair, signum):
    _, slave = pty_pair
    previous = signal.getsignal(signum)
    with signal_pipe() as stop_fd:
        signal.raise_signal(signum)  # recorded, not raised here
        with pytest.raises(Stop, match=signal.Signals(signum).name):
            KeyReader(slave, stop_fd).read(timeout=5.0)
    assert signal.getsignal(signum) is previous


def test_arm_values_picks_the_arm_joints_by_name():
    names = ['rg2_finger_joint', 'elbow_joint', 'shoulder_pan_joint', 'shoulder_lift_joint',
             'wrist_1_joint', 'wrist_2_joint', 'wrist_3_joint']
    values = [9.0, 2.0, 0.0, 1.0, 3.0, 4.0, 5.0]
    assert arm_values(names, values) == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert arm_values(names, []) is None
    assert arm_values(names[:-1], values[:-1]) is None


def test_format_angles_shows_degrees_and_step():
    line = format_angles([0.2617993877991494, -1e-6, -0.08726646259971647, 0.0, 0.0, 3.14159],
                         2.5)
    assert line.startswith('pan  +15.0  lift   +0.0  elbow   -5.0')
    assert 'wrist3 +180.0' in line and line.endswith('(step 2.5)')
    assert '\n' not in line


def test_console_writes_whole_lines():
    stream = io.StringIO()
    Console(stream).line('a\nb')
    assert stream.getvalue() == 'a\nb\n'


def test_settle_watcher_shows_once_after_motion_stops():
    watcher = SettleWatcher(settle_time=0.1)
    watcher.moved(0.0)
    assert not watcher.observe(0.01, [0.0] * 6)  # not started yet
    assert not watcher.observe(0.02, [0.5, 0, 0, 0, 0, 0])
    assert not watcher.observe(0.03, [0.2, 0, 0, 0, 0, 0])
    assert not watcher.observe(0.04, [0.0] * 6)
    assert not watcher.observe(0.13, [0.0] * 6)
    assert watcher.observe(0.14, [0.0] * 6)
    assert not watcher.observe(0.15, [0.0] * 6)


def test_settle_watcher_waits_out_an_overshoot():
    watcher = SettleWatcher(settle_time=0.1)
    watcher.moved(0.0)
    for t, speed in ((0.02, 1.0), (0.05, 0.0), (0.08, -0.3), (0.16, 0.0)):
        assert not watcher.observe(t, [speed])
    assert watcher.observe(0.26, [0.0])


def test_settle_watcher_shows_when_nothing_moves():
    watcher = SettleWatcher(start_timeout=0.5)
    watcher.moved(0.0)
    assert not watcher.observe(0.4, [])
    assert watcher.observe(0.6, [])


def test_settle_watcher_shows_after_max_wait_even_while_moving():
    watcher = SettleWatcher(max_wait=5.0)
    watcher.moved(0.0)
    assert not watcher.observe(4.9, [1.0])
    assert watcher.observe(5.1, [1.0])


def test_settle_watcher_a_new_move_restarts_the_wait():
    watcher = SettleWatcher(start_timeout=0.5)
    watcher.moved(0.0)
    watcher.observe(0.1, [1.0])
    watcher.moved(0.2)
    assert not watcher.observe(0.3, [0.0])
    assert watcher.observe(0.8, [0.0])


def test_settle_watcher_silent_without_a_move():
    assert not SettleWatcher().observe(10.0, [0.0])
