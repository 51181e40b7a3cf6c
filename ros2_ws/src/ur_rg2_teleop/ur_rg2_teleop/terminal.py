"""Raw terminal input: mode switching that always restores, key reading, signal-driven exit."""

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
import errno
import os
import select
import signal
import termios

# A terminal sends an escape sequence in one write, but a slow link (SSH) may split it; wait
# this long for the rest before taking a lone ESC as the Esc key.
ESCAPE_TIMEOUT = 0.05
# Longer CSI sequences than this are not keys; stop waiting for their final byte.
_MAX_CSI = 16

_IFLAG, _OFLAG, _LFLAG, _CC = 0, 1, 3, 6


class Stop(Exception):  # noqa: N818 - a request to end, not an error
    """A signal asked the process to end (raised by :meth:`KeyReader.read`)."""


def raw_attributes(attributes: list) -> list:
    r"""Return a copy of termios ``attributes`` with raw input and cooked output.

    Input: no echo, no line editing, no signals from keys (Ctrl-C arrives as a byte and quits
    cleanly; Ctrl-Z would suspend the process with the terminal left raw), no flow control,
    reads return after one byte. Output keeps newline translation so that log lines written
    by ROS with a bare ``\n`` still start at column 0.
    """
    raw = [*attributes[:_CC], list(attributes[_CC])]
    raw[_IFLAG] &= ~(termios.BRKINT | termios.ICRNL | termios.INPCK | termios.ISTRIP
                     | termios.IXON)
    raw[_OFLAG] |= termios.OPOST | termios.ONLCR
    raw[_LFLAG] &= ~(termios.ECHO | termios.ICANON | termios.IEXTEN | termios.ISIG)
    raw[_CC][termios.VMIN] = 1
    raw[_CC][termios.VTIME] = 0
    return raw


@contextmanager
def raw_mode(fd: int) -> Iterator[None]:
    """Put terminal ``fd`` in raw input mode; restore its exact attributes on any exit."""
    saved = termios.tcgetattr(fd)
    # TCSAFLUSH on both edges: keys typed before start must not jog, keys left unread at exit
    # must not spill into the shell.
    termios.tcsetattr(fd, termios.TCSAFLUSH, raw_attributes(saved))
    try:
        yield
    finally:
        try:
            termios.tcsetattr(fd, termios.TCSAFLUSH, saved)
        except termios.error as error:
            # A terminal that hung up (closed SSH session) has nothing left to restore.
            if error.args[0] != errno.EIO:
                raise


@contextmanager
def signal_pipe(
    signums: Iterable[signal.Signals] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP),
) -> Iterator[int]:
    """Record ``signums`` instead of acting on them; yield a descriptor readable after one.

    Nothing is raised in the middle of other code, so no cleanup (restoring the terminal) can
    be cut short: the key loop sees the signal in its ``select`` and ends in order. The
    previous handlers are back after the block.
    """
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)  # set_wakeup_fd must never block in a signal handler
    previous_fd = signal.set_wakeup_fd(write_fd)
    # A Python handler, even one doing nothing, is what makes the signal reach the pipe.
    previous = {s: signal.signal(s, lambda *_: None) for s in signums}
    try:
        yield read_fd
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        signal.set_wakeup_fd(previous_fd)
        os.close(read_fd)
        os.close(write_fd)


def _sequence_length(data: bytes, start: int) -> int | None:
    """Length of the key starting at ``data[start]``, or None when ``data`` ends inside it."""
    first = data[start]
    available = len(data) - start
    if first == 0x1b:
        if available < 2:
            return None
        second = data[start + 1]
        if second == ord('['):
            for i in range(start + 2, min(len(data), start + _MAX_CSI)):
                if 0x40 <= data[i] <= 0x7e:
                    return i - start + 1
            return None if available < _MAX_CSI else _MAX_CSI
        if second == ord('O'):
            return 3 if available >= 3 else None
        if second == 0x1b:
            return 1
        # Alt+key: ESC followed by that key (one character).
        rest = _sequence_length(data, start + 1)
        return None if rest is None else 1 + rest
    # UTF-8: the lead byte says how many continuation bytes follow.
    length = 1 if first < 0xc0 else 2 if first < 0xe0 else 3 if first < 0xf0 else 4
    return length if available >= length else None


def split_keys(data: bytes) -> tuple[list[str], bytes]:
    r"""Split terminal input into keys; return them and an incomplete tail to complete later.

    A key is one character or one whole escape sequence (an arrow key is ``'\x1b[A'``, never
    ``'['`` and ``'A'``).
    """
    keys = []
    i = 0
    while i < len(data):
        length = _sequence_length(data, i)
        if length is None:
            break
        keys.append(data[i:i + length].decode(errors='replace'))
        i += length
    return keys, data[i:]


class KeyReader:
    """Read whole keys from a terminal file descriptor with ``select`` and ``os.read``."""

    def __init__(self, fd: int, stop_fd: int | None = None) -> None:
        """Read keys from ``fd``; end with :class:`Stop` once ``stop_fd`` (a signal_pipe)."""
        self._fd = fd
        self._stop_fd = stop_fd

    def _read(self) -> bytes:
        try:
            data = os.read(self._fd, 1024)
        except OSError as error:
            # A pseudo-terminal whose other side closed reports EIO instead of end of file.
            if error.errno != errno.EIO:
                raise
            data = b''
        if not data:
            raise EOFError('terminal closed')
        return data

    def _ready(self, timeout: float | None) -> bool:
        return bool(select.select([self._fd], [], [], timeout)[0])

    def read(self, timeout: float | None) -> list[str]:
        """Return the keys pressed, waiting up to ``timeout`` s for one; [] on timeout.

        Raises EOFError when the terminal is gone, Stop when a signal came.
        """
        watched = [self._fd] if self._stop_fd is None else [self._fd, self._stop_fd]
        ready = select.select(watched, [], [], timeout)[0]
        if self._stop_fd in ready:
            signum = os.read(self._stop_fd, 1)[0]
            raise Stop(signal.Signals(signum).name)
        if not ready:
            return []
        keys, tail = split_keys(self._read())
        while tail and self._ready(ESCAPE_TIMEOUT):
            more, tail = split_keys(tail + self._read())
            keys += more
        if tail:
            keys.append(tail.decode(errors='replace'))
        return keys
