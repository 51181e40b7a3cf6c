"""``record`` run as a child process, for commands that record what they make the graph do."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
import signal
import subprocess
import sys
import threading


class Recorder:
    """``record`` as a child process in its own session (a Ctrl-C in the terminal is ours)."""

    def __init__(self, output: str, topics: Sequence[str] | None, wait: float) -> None:
        """Start recording ``topics`` (None: every topic) to ``output``."""
        command = [sys.executable, '-m', 'ur_rg2_tools.record_node', '-o', output,
                   '--wait', f'{wait:g}', *(['--all'] if topics is None else topics)]
        self.lines: deque[str] = deque(maxlen=20)
        self.process = subprocess.Popen(command, stdin=subprocess.DEVNULL,
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                        text=True, start_new_session=True)
        self._drain = threading.Thread(target=self._read, daemon=True)
        self._drain.start()

    def _read(self) -> None:
        for line in self.process.stdout:
            self.lines.append(line.rstrip())

    def alive(self) -> bool:
        """Tell whether it still runs."""
        return self.process.poll() is None

    def output(self) -> str:
        """Return its last lines."""
        return '\n'.join(self.lines)

    def stop(self) -> str | None:
        """Stop it as Ctrl-C does (the file finished); return what went wrong, or None."""
        if self.alive():
            self.process.send_signal(signal.SIGINT)
        try:
            code = self.process.wait(timeout=120)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
            return 'the recorder did not stop within 120 s and was killed'
        self._drain.join(timeout=5)
        return None if code == 0 else f'the recorder ended with code {code}:\n{self.output()}'
