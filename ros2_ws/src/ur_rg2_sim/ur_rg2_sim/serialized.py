"""Messages serialized once whose numbers are then rewritten in the serialized bytes.

At real-time factor 0 the sim publishes ``joint_states``, ``/tf`` and ``ball/true_pose`` at
thousands of messages per second. rclpy converts a Python message to C field by field on every
publish (about 190 us for the /tf message of eight transforms), while publishing bytes costs
about 2 us. Only numbers change between two messages of one stream (names, frame ids and array
lengths stay), so the message is serialized once and its numbers written into a copy of those
bytes at offsets found once, by serializing it with distinct marker values.
"""

from collections.abc import Callable, Iterator, Sequence

import numpy as np
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message

# The encapsulation header of little-endian plain CDR (the payload follows it).
_CDR_LE = b'\x00\x01'
_HEADER = 4


class SerializedMessage:
    """The bytes of a message built by ``build(doubles, words)`` for any values of the two.

    ``build`` takes a float64 array of ``n_doubles`` and a uint32 array of ``n_words`` and
    returns the message with each value in its own field (float64 fields and 32-bit integer
    fields); every other field must not depend on them.
    """

    def __init__(self, build: Callable[[np.ndarray, np.ndarray], object], n_doubles: int,
                 n_words: int) -> None:
        # Markers no other field of a message holds: doubles around 1e300, words with a high
        # byte no length or count reaches. Drawn afresh for every instance because the
        # alignment padding of the serialized bytes is not cleared: it can hold what an
        # earlier serialization left in that memory, fixed markers of an earlier instance
        # among it (seen once in about 50 sim starts in one process).
        rng = np.random.default_rng()
        doubles = 1e300 * (1.0 + rng.random(n_doubles))
        words = 0x7E000000 + rng.choice(0x01000000, n_words, replace=False).astype(np.uint32)
        template = serialize_message(build(doubles, words))
        if template[:2] != _CDR_LE:
            raise ValueError(f'expected little-endian CDR, got encapsulation {template[:2]!r}')
        double_index = _find(template, doubles.astype('<f8'), 8)
        word_index = _find(template, words.astype('<u4'), 4)
        # Views of one buffer that every fill rewrites whole: use one instance from one thread.
        self._buffer = bytearray(template)
        count = (len(template) - _HEADER) // 8
        self._doubles = np.frombuffer(self._buffer, '<f8', offset=_HEADER, count=count)
        self._words = np.frombuffer(self._buffer, '<u4', count=len(template) // 4)
        self._double_index, self._word_index = double_index, word_index

    def fill(self, doubles: Sequence[float], words: Sequence[int]) -> bytes:
        """Return the serialized message holding ``doubles`` and ``words``."""
        self._doubles[self._double_index] = doubles
        self._words[self._word_index] = words
        return bytes(self._buffer)


class SerializedPublisher:
    """A publisher of a :class:`SerializedMessage` stream, silent while no one subscribes.

    Whether a subscription is matched comes from the publisher's matched events, which the
    node's executor delivers; :meth:`publish` may be called from another thread.
    """

    def __init__(self, node: Node, msg_type: type, topic: str, qos: QoSProfile | int,
                 build: Callable[[np.ndarray, np.ndarray], object], n_doubles: int,
                 n_words: int) -> None:
        self.subscribers = 0  # matched subscriptions, as the last matched event said
        self._message = SerializedMessage(build, n_doubles, n_words)
        self._publisher = node.create_publisher(
            msg_type, topic, qos, event_callbacks=PublisherEventCallbacks(matched=self._matched))

    def _matched(self, status) -> None:
        self.subscribers = status.current_count

    def publish(self, doubles: Sequence[float], words: Sequence[int]) -> None:
        """Publish the message holding ``doubles`` and ``words`` if anyone subscribes."""
        if self.subscribers:
            self._publisher.publish(self._message.fill(doubles, words))


def _find(template: bytes, markers: np.ndarray, size: int) -> np.ndarray:
    """Return where each marker is, in units of ``size`` from the aligned payload start."""
    base = _HEADER if size == 8 else 0
    index = []
    for marker in markers:
        raw = marker.tobytes()
        found = [i for i in _occurrences(template, raw) if (i - base) % size == 0]
        if len(found) != 1:
            raise ValueError(f'marker {marker!r} found {len(found)} times at alignment {size}')
        index.append((found[0] - base) // size)
    return np.array(index, dtype=np.intp)


def _occurrences(data: bytes, part: bytes) -> Iterator[int]:
    start = data.find(part)
    while start >= 0:
        yield start
        start = data.find(part, start + 1)
