"""The bytes a recorder holds for its writer thread, bounded as rosbag2's ``--max-cache-size``."""

from collections import Counter
import threading

DEFAULT_MAX_BYTES = 100 * 2 ** 20  # rosbag2's default cache size


class WriteBacklog:
    """Counts the bytes taken and not yet written; a message past the limit is dropped.

    Without a bound, a writer that falls behind (compression on a busy machine) holds an
    ever longer backlog in memory, and a Ctrl-C then waits for all of it to be written.
    """

    def __init__(self, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        if max_bytes <= 0:
            raise ValueError(f'the cache size must be positive, not {max_bytes}')
        self.max_bytes = max_bytes
        self.dropped: Counter[str] = Counter()  # per topic
        self._held = 0
        self._lock = threading.Lock()

    def take(self, topic: str, size: int) -> bool:
        """Return whether a message of ``size`` bytes fits; count it as dropped if not."""
        with self._lock:
            if self._held and self._held + size > self.max_bytes:
                self.dropped[topic] += 1
                return False
            self._held += size
            return True

    def written(self, size: int) -> None:
        """Release a message's bytes once the writer has taken it from the queue."""
        with self._lock:
            self._held -= size

    @property
    def total_dropped(self) -> int:
        """Return the messages dropped, all topics together."""
        return sum(self.dropped.values())

    @property
    def held(self) -> int:
        """Return the bytes taken and not yet written."""
        return self._held

    def summary(self) -> str:
        """Return the dropped messages per topic, e.g. ``12 (/camera/image_raw: 12)``."""
        topics = ', '.join(f'{t}: {n}' for t, n in sorted(self.dropped.items()))
        return f'{self.total_dropped} ({topics})'
