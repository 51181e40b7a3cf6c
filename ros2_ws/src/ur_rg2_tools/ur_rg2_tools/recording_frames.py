"""Reading a recording (MCAP) into a data set's episodes and frames. No ROS nodes.

Messages are decoded with the schemas in the file. :func:`read_streams` reads what a LeRobot
data set is made of (joint states, sightings, markers, the images' times), :func:`split_episodes`
cuts it at the markers on ``episode`` and :func:`sample_episode` samples an episode at a frame
rate; ur_rg2_tools.lerobot writes the data set from them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import partial
import math
from pathlib import Path
from typing import Any, NamedTuple

from mcap_ros2.decoder import DecoderFactory
import numpy as np
from ur_rg2_common.contract import (
    ARM_JOINTS,
    EPISODE_FAILURE,
    EPISODE_START,
    EPISODE_SUCCESS,
    EPISODE_TOPIC,
    GRIPPER_JOINTS,
)

from ur_rg2_tools.bag import READ_ERRORS, open_recording

JOINT_STATES, COLOR_IMAGE, BALL = 'joint_states', 'camera/color/image_raw', 'ball/position'
BALL_SEEN_S = 0.25  # a sighting at most this old counts as seen


class ExportError(Exception):
    """A recording that cannot become a data set, or an output that cannot be written."""


class Episode(NamedTuple):
    """A stretch of a recording (log times, ns) and how it ended."""

    start: int
    end: int
    outcome: str | None  # EPISODE_SUCCESS, EPISODE_FAILURE, or None when not marked


def split_episodes(markers: Sequence[tuple[int, str]], start: int, end: int,
                   warn: Callable[[str], None]) -> list[Episode]:
    """Cut [start, end] into episodes by its markers ((time, value) in time order).

    No markers: the whole recording, unmarked. ``start`` opens an episode and ``success`` or
    ``failure`` closes it; an end with no episode open, a start while one is open (that one is
    dropped) and an episode still open at the recording's end are each warned about.
    """
    if not markers:
        return [Episode(start, end, None)]
    episodes: list[Episode] = []
    opened: int | None = None
    for time, value in markers:
        seconds = f'{(time - start) / 1e9:.2f} s'
        if value == EPISODE_START:
            if opened is not None:
                warn(f'a start at {seconds} while an episode was open: the open one is dropped')
            opened = time
        elif value in (EPISODE_SUCCESS, EPISODE_FAILURE):
            if opened is None:
                warn(f'a {value} at {seconds} with no episode open: ignored')
            else:
                episodes.append(Episode(opened, time, value))
                opened = None
        else:
            warn(f'unknown episode marker {value!r} at {seconds}: ignored')
    if opened is not None:
        warn('an episode still open at the end of the recording: dropped')
    return episodes


@dataclass
class Streams:
    """What a recording holds of the topics a data set is made of (log times in ns)."""

    start: int
    end: int
    arm_times: list[int] = field(default_factory=list)
    arm: list[list[float]] = field(default_factory=list)
    gripper_times: list[int] = field(default_factory=list)
    opening: list[float] = field(default_factory=list)
    ball_times: list[int] = field(default_factory=list)
    ball: list[list[float]] = field(default_factory=list)
    image_times: list[int] = field(default_factory=list)
    markers: list[tuple[int, str]] = field(default_factory=list)


def _topic(namespace: str, name: str) -> str:
    prefix = namespace.strip('/')
    return f'/{prefix}/{name}' if prefix else f'/{name}'


class Reader:
    """An open recording and the decoders of its channels."""

    def __init__(self, path: Path, namespace: str) -> None:
        self.path = path
        self.names = {_topic(namespace, name): name
                      for name in (JOINT_STATES, COLOR_IMAGE, BALL, EPISODE_TOPIC)}
        self.recording = open_recording(path)  # RecordingError: missing, not MCAP, cut short
        self._factory = DecoderFactory()
        self._decoders: dict[int, Any] = {}

    def messages(self, names: set[str]) -> Iterator[tuple[str, int, Callable[[], Any]]]:
        """Yield (name, log time, decode) of the messages of ``names`` in log time order."""
        topics = [topic for topic, name in self.names.items() if name in names]
        try:
            for schema, channel, message in self.recording.reader.iter_messages(
                    topics=topics, log_time_order=True):
                decoder = self._decoders.get(channel.id)
                if decoder is None:
                    decoder = self._factory.decoder_for(channel.message_encoding, schema)
                    if decoder is None:
                        raise ExportError(f'{self.path}: cannot decode {channel.topic} '
                                          f'({channel.message_encoding})')
                    self._decoders[channel.id] = decoder
                yield (self.names[channel.topic], message.log_time,
                       partial(self._decode, decoder, channel.topic, message.data))
        except READ_ERRORS as error:
            raise ExportError(f'{self.path}: cannot read its messages ({type(error).__name__}: '
                              f'{error}); `ros2 run ur_rg2_tools recover {self.path}` keeps '
                              'what is readable') from None

    def _decode(self, decoder: Callable[[bytes], Any], topic: str, data: bytes) -> Any:
        try:
            return decoder(data)
        except Exception as error:  # noqa: BLE001 - the CDR decoder raises what it meets
            raise ExportError(f'{self.path}: a {topic} message does not decode as its schema '
                              f'says ({type(error).__name__}: {error})') from None

    def close(self) -> None:
        """Close the file."""
        self.recording.stream.close()


def read_streams(reader: Reader) -> Streams:
    """Read joint states, sightings, markers and the images' times (not their pixels)."""
    recording = reader.recording
    streams = Streams(recording.start_ns, recording.end_ns)
    for name, time, decode in reader.messages({JOINT_STATES, BALL, EPISODE_TOPIC,
                                               COLOR_IMAGE}):
        if name == COLOR_IMAGE:
            streams.image_times.append(time)
        elif name == JOINT_STATES:
            message = decode()
            positions = dict(zip(message.name, message.position))
            if all(joint in positions for joint in ARM_JOINTS):
                streams.arm_times.append(time)
                streams.arm.append([positions[joint] for joint in ARM_JOINTS])
            if all(joint in positions for joint in GRIPPER_JOINTS):
                streams.gripper_times.append(time)
                streams.opening.append(sum(positions[joint] for joint in GRIPPER_JOINTS))
        elif name == BALL:
            point = decode().point
            streams.ball_times.append(time)
            streams.ball.append([point.x, point.y, point.z])
        else:
            streams.markers.append((time, decode().data))
    topic = {name: topic for topic, name in reader.names.items()}
    if not streams.arm_times:
        raise ExportError(f'{reader.path}: no {topic[JOINT_STATES]} message with the six arm '
                          'joints (record it with --all, or name joint_states)')
    if not streams.image_times:
        raise ExportError(f'{reader.path}: no {topic[COLOR_IMAGE]} message (record it with '
                          '--all, or name camera/color/image_raw)')
    return streams


def _held(times: list[int], at: np.ndarray) -> np.ndarray:
    """Return the index of the latest of ``times`` at or before each of ``at`` (-1: none)."""
    return np.searchsorted(np.asarray(times, dtype=np.int64), at, side='right') - 1


@dataclass
class EpisodeFrames:
    """One episode's rows and the image message each frame shows."""

    episode: Episode
    state: np.ndarray  # (n, 7)
    action: np.ndarray  # (n, 7)
    environment: np.ndarray  # (n, 4)
    images: np.ndarray  # (n,) index into Streams.image_times


def sample_episode(streams: Streams, episode: Episode, fps: int,
                   warn: Callable[[str], None]) -> EpisodeFrames | None:
    """Return the episode's frames at ``fps``; None (warned) when it has none."""
    first = max(episode.start, streams.arm_times[0], streams.image_times[0])
    if first > episode.end:
        warn(f'an episode of {(episode.end - episode.start) / 1e9:.2f} s before the first '
             'joint state and image: dropped')
        return None
    count = math.floor((episode.end - first) * fps / 1e9) + 1
    at = first + np.round(np.arange(count) * 1e9 / fps).astype(np.int64)
    arm = np.asarray(streams.arm)[_held(streams.arm_times, at)]
    if streams.gripper_times:
        held = _held(streams.gripper_times, at)
        opening = np.where(held >= 0, np.asarray(streams.opening)[np.maximum(held, 0)], np.nan)
    else:
        opening = np.full(count, np.nan)
    state = np.column_stack([arm, opening]).astype(np.float32)
    action = np.concatenate([state[1:], state[-1:]])
    environment = np.zeros((count, 4), dtype=np.float32)
    if streams.ball_times:
        held = _held(streams.ball_times, at)
        seen = held >= 0
        environment[seen, :3] = np.asarray(streams.ball)[held[seen]]
        ages = at[seen] - np.asarray(streams.ball_times, dtype=np.int64)[held[seen]]
        environment[seen, 3] = ages <= BALL_SEEN_S * 1e9
    return EpisodeFrames(episode, state, action, environment, _held(streams.image_times, at))


def image_rgb(message: Any, path: Path) -> np.ndarray:
    """Return a sensor_msgs/Image (rgb8, bgr8) as an (h, w, 3) uint8 array."""
    if message.encoding not in ('rgb8', 'bgr8'):
        raise ExportError(f'{path}: camera images are {message.encoding}, not rgb8 or bgr8')
    rows = np.frombuffer(bytes(message.data), dtype=np.uint8).reshape(message.height, -1)
    image = rows[:, :message.width * 3].reshape(message.height, message.width, 3)
    return image[..., ::-1] if message.encoding == 'bgr8' else image
