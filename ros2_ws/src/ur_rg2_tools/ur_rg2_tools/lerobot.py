"""Recordings of the graph (MCAP) to a LeRobot data set, codebase version v3.0.

The layout LeRobot 0.4 writes (``lerobot.datasets.utils``): ``meta/info.json`` (features,
counts, path templates), ``meta/episodes/chunk-000/file-000.parquet`` (one row per episode:
length, where its rows and video frames are, its stats), ``meta/tasks.parquet``,
``meta/stats.json``, the frames in ``data/chunk-000/file-000.parquet`` and the camera in
``videos/observation.images.camera/chunk-000/file-000.mp4``, every episode one after the other.

Every stream is sampled at ``fps`` on the recording's log time (when the recorder received
each message): a frame takes the latest message at or before its time. Per frame:

- ``observation.state``: the six arm joints (rad, ARM_JOINTS order) and the RG2's opening (m,
  the sum of its finger joints);
- ``action``: the next frame's ``observation.state``, the position the arm and gripper were
  driven to over the frame (the last frame's own state);
- ``observation.environment_state``: the ball as vision saw it (``ball/position``, metres in
  its header's frame, the camera's optical frame), held at its last sighting, 0 before the
  first, and whether it was seen in the last BALL_SEEN_S (ur_rg2_tools.recording_frames);
- ``observation.images.camera``: the colour image;
- ``next.done`` (last frame of its episode) and ``next.success`` (last frame of an episode
  that ended in success), beside LeRobot's indices and ``timestamp`` (s since the episode's
  first frame).

Episodes come from the markers on ``episode`` (ur_rg2_common.contract): ``start`` opens one,
``success`` or ``failure`` closes it. A recording without markers is one episode, neither a
success nor a failure. No ROS message packages or nodes: messages are decoded with the schemas
in the file.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import json
import os
from pathlib import Path
import shutil
import tempfile
from typing import Any, NamedTuple

import av
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from ur_rg2_common.contract import ARM_JOINTS, EPISODE_FAILURE, EPISODE_SUCCESS, GRIPPER_JOINTS

from ur_rg2_tools.bag import RecordingError
from ur_rg2_tools.recording_frames import (
    COLOR_IMAGE,
    EpisodeFrames,
    ExportError,
    Reader,
    image_rgb,
    read_streams,
    sample_episode,
    split_episodes,
)

CODEBASE_VERSION = 'v3.0'
CHUNK_FILE = 'chunk-{chunk_index:03d}/file-{file_index:03d}'
DATA_PATH = 'data/' + CHUNK_FILE + '.parquet'
VIDEO_PATH = 'videos/{video_key}/' + CHUNK_FILE + '.mp4'
EPISODES_PATH = 'meta/episodes/' + CHUNK_FILE + '.parquet'
TASKS_PATH = 'meta/tasks.parquet'
CAMERA_KEY = 'observation.images.camera'
STATE_NAMES = [*ARM_JOINTS, 'gripper_opening']
ENVIRONMENT_NAMES = ['ball_x', 'ball_y', 'ball_z', 'ball_seen']
DEFAULT_TASK = 'Pick up the ball.'
# The codecs a plain ``av`` wheel may encode, LeRobot's default first (AV1, as LeRobot writes
# with g=2, crf=30, preset 12: a key frame every other frame for random access).
CODECS = (('libsvtav1', {'g': '2', 'crf': '30', 'preset': '12'}),
          ('libx264', {'g': '2', 'crf': '23'}),
          ('libopenh264', {'g': '2'}))
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
IMAGE_SAMPLES = 100  # frames per episode the image stats are taken from (every 8th pixel)
# What LeRobot 0.4 puts in info.json beside the features.
CHUNKS_SIZE, DATA_FILES_MB, VIDEO_FILES_MB = 1000, 100, 200



def choose_codec() -> tuple[str, dict[str, str]]:
    """Return the first of CODECS this ``av`` can encode."""
    for name, options in CODECS:
        try:
            av.codec.Codec(name, 'w')
        except Exception:  # noqa: BLE001 - av raises UnknownCodecError or ValueError
            continue
        return name, options
    raise ExportError('this av (PyAV) can encode none of ' + ', '.join(n for n, _ in CODECS))


class VideoWriter:
    """The data set's camera video: frames at ``fps``, one after the other."""

    def __init__(self, path: Path, fps: int) -> None:
        self.path = path
        self.fps = fps
        self.codec, self._options = choose_codec()
        # SVT-AV1 prints its configuration to stderr unless told to say errors only.
        os.environ.setdefault('SVT_LOG', '1')
        path.parent.mkdir(parents=True)
        self._container = av.open(str(path), 'w')
        self._stream = None
        self.frames = 0
        self.shape: tuple[int, int, int] | None = None

    def add(self, image: np.ndarray, source: Path) -> None:
        """Append one frame; every frame must have the first one's size."""
        if self._stream is None:
            self.shape = image.shape
            self._stream = self._container.add_stream(self.codec, rate=self.fps,
                                                      options=self._options)
            self._stream.height, self._stream.width = image.shape[:2]
            self._stream.pix_fmt = 'yuv420p'
        elif image.shape != self.shape:
            raise ExportError(f'{source}: a camera image of {image.shape[1]}x{image.shape[0]} '
                              f'after ones of {self.shape[1]}x{self.shape[0]}')
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format='rgb24')
        frame.pts = self.frames
        self._container.mux(self._stream.encode(frame))
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file."""
        if self._stream is not None:
            self._container.mux(self._stream.encode())
        self._container.close()

    def info(self) -> dict[str, Any]:
        """Return the feature's ``info`` as LeRobot's get_video_info reads it."""
        with av.open(str(self.path)) as container:
            stream = container.streams.video[0]
            return {'video.height': stream.height, 'video.width': stream.width,
                    'video.codec': stream.codec_context.codec.canonical_name,
                    'video.pix_fmt': stream.pix_fmt, 'video.is_depth_map': False,
                    'video.fps': self.fps, 'video.channels': 3, 'has_audio': False}


def feature_stats(values: np.ndarray, axis: int | tuple[int, ...] = 0) -> dict[str, list]:
    """Return LeRobot's stats of ``values`` over ``axis``: min, max, mean, std, count, q*."""
    values = np.asarray(values, dtype=np.float64)
    stats = {'min': np.min(values, axis=axis), 'max': np.max(values, axis=axis),
             'mean': np.mean(values, axis=axis), 'std': np.std(values, axis=axis)}
    for q in QUANTILES:
        stats[f'q{round(q * 100):02d}'] = np.quantile(values, q, axis=axis)
    result = {key: np.atleast_1d(value).tolist() for key, value in stats.items()}
    result['count'] = [int(values.shape[0])]
    return result


def image_stats(samples: list[np.ndarray]) -> dict[str, list]:
    """Return per-channel stats of (h, w, 3) uint8 images in [0, 1], each (3, 1, 1)."""
    pixels = np.stack(samples).astype(np.float64) / 255.0  # (n, h, w, 3)
    stats = feature_stats(pixels.reshape(-1, 3))
    result = {key: [[[v]] for v in value] for key, value in stats.items()}
    result['count'] = [len(samples)]
    return result


def features(shape: tuple[int, int, int], video_info: dict[str, Any]) -> dict[str, Any]:
    """Return info.json's features."""
    def vector(names):
        return {'dtype': 'float32', 'shape': [len(names)], 'names': list(names)}

    def scalar(dtype):
        return {'dtype': dtype, 'shape': [1], 'names': None}

    return {
        'observation.state': vector(STATE_NAMES),
        'action': vector(STATE_NAMES),
        'observation.environment_state': vector(ENVIRONMENT_NAMES),
        CAMERA_KEY: {'dtype': 'video', 'shape': list(shape),
                     'names': ['height', 'width', 'channels'], 'info': video_info},
        'next.done': scalar('bool'),
        'next.success': scalar('bool'),
        'timestamp': scalar('float32'),
        'frame_index': scalar('int64'),
        'episode_index': scalar('int64'),
        'index': scalar('int64'),
        'task_index': scalar('int64'),
    }


def _vectors(values: np.ndarray) -> pa.Array:
    width = values.shape[1]
    return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1), pa.float32()), width)


def episode_columns(frames: EpisodeFrames, fps: int, episode_index: int,
                    first_index: int) -> dict[str, np.ndarray]:
    """Return an episode's rows as columns (vectors as (n, k) arrays)."""
    count = len(frames.state)
    done = np.zeros(count, dtype=bool)
    done[-1] = True
    return {
        'observation.state': frames.state,
        'action': frames.action,
        'observation.environment_state': frames.environment,
        'next.done': done,
        'next.success': done & (frames.episode.outcome == EPISODE_SUCCESS),
        'timestamp': (np.arange(count) / fps).astype(np.float32),
        'frame_index': np.arange(count, dtype=np.int64),
        'episode_index': np.full(count, episode_index, dtype=np.int64),
        'index': np.arange(first_index, first_index + count, dtype=np.int64),
        'task_index': np.zeros(count, dtype=np.int64),
    }


def _table(columns: dict[str, np.ndarray]) -> pa.Table:
    return pa.table({key: _vectors(value) if value.ndim == 2 else pa.array(value)
                     for key, value in columns.items()})


def _tasks_table(tasks: list[str]) -> pa.Table:
    """Return meta/tasks.parquet as pandas writes LeRobot's DataFrame (tasks as its index)."""
    pandas = {'index_columns': ['__index_level_0__'],
              'column_indexes': [{'name': None, 'field_name': None, 'pandas_type': 'unicode',
                                  'numpy_type': 'object', 'metadata': {'encoding': 'UTF-8'}}],
              'columns': [{'name': 'task_index', 'field_name': 'task_index',
                           'pandas_type': 'int64', 'numpy_type': 'int64', 'metadata': None},
                          {'name': None, 'field_name': '__index_level_0__',
                           'pandas_type': 'unicode', 'numpy_type': 'object', 'metadata': None}],
              'creator': {'library': 'pyarrow', 'version': pa.__version__},
              'pandas_version': '2.3.3'}
    table = pa.table({'task_index': pa.array(range(len(tasks)), pa.int64()),
                      '__index_level_0__': pa.array(tasks, pa.string())})
    return table.replace_schema_metadata({b'pandas': json.dumps(pandas).encode()})


def _card(repo_id: str, info: dict[str, Any]) -> str:
    return (
        '---\nlicense: apache-2.0\ntask_categories:\n- robotics\ntags:\n- LeRobot\n'
        'configs:\n- config_name: default\n  data_files: data/*/*.parquet\n---\n\n'
        f'# {repo_id}\n\nDemonstrations recorded in the UR5 + RG2 simulation graph (ROS 2 '
        'Jazzy) and exported by `ros2 run ur_rg2_tools to_lerobot`: '
        f"{info['total_episodes']} episodes, {info['total_frames']} frames at {info['fps']} fps."
        '\n\n```json\n' + json.dumps(info, indent=4) + '\n```\n')


class Summary(NamedTuple):
    """What :func:`export` wrote."""

    episodes: int
    frames: int
    successes: int
    failures: int
    codec: str


def export(recordings: Sequence[str | os.PathLike], output: str | os.PathLike, fps: int = 10,
           repo_id: str = '', task: str = DEFAULT_TASK, namespace: str = '',
           warn: Callable[[str], None] = print) -> Summary:
    """Write the data set of ``recordings`` to ``output``, which must not exist.

    It appears whole or not at all: written beside it under a temporary name, then renamed.
    Raises ExportError (or RecordingError) with the reason.
    """
    output = Path(output)
    if fps <= 0:
        raise ExportError(f'--fps must be positive, not {fps}')
    if os.path.lexists(output):
        raise ExportError(f'{output} exists: give a new directory (nothing is overwritten)')
    if not output.parent.is_dir():
        raise ExportError(f'{output.parent} is not a directory')
    partial = Path(tempfile.mkdtemp(prefix=f'.{output.name}.', suffix='.partial',
                                    dir=output.parent))
    try:
        summary = _write(recordings, partial, fps, repo_id or f'local/{output.name}', task,
                         namespace, warn)
        if os.path.lexists(output):
            raise ExportError(f'{output} appeared while the data set was written')
        partial.rename(output)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return summary


def _write(recordings: Sequence[str | os.PathLike], root: Path, fps: int, repo_id: str,
           task: str, namespace: str, warn: Callable[[str], None]) -> Summary:
    location = {'chunk_index': 0, 'file_index': 0}
    video = VideoWriter(root / VIDEO_PATH.format(video_key=CAMERA_KEY, **location), fps)
    tables: list[pa.Table] = []
    episodes: list[dict[str, Any]] = []
    all_columns: list[dict[str, np.ndarray]] = []
    image_samples: list[np.ndarray] = []
    try:
        for path in map(Path, recordings):
            try:
                reader = Reader(path, namespace)
            except RecordingError as error:
                raise ExportError(str(error)) from None
            try:
                streams = read_streams(reader)
                if not streams.gripper_times:
                    warn(f"{path}: no joint state of the RG2's fingers "
                         f'({", ".join(GRIPPER_JOINTS)}): the gripper opening is NaN')
                cut = split_episodes(streams.markers, streams.start, streams.end,
                                     lambda text, p=path: warn(f'{p}: {text}'))
                sampled = [frames for episode in cut
                           if (frames := sample_episode(streams, episode, fps,
                                                        lambda t, p=path: warn(f'{p}: {t}')))]
                samples = _encode(reader, sampled, video)
            finally:
                reader.close()
            for frames, images in zip(sampled, samples):
                first = sum(len(table) for table in tables)
                columns = episode_columns(frames, fps, len(episodes), first)
                tables.append(_table(columns))
                all_columns.append(columns)
                image_samples.extend(images)
                episodes.append(_episode_row(frames, columns, images, len(episodes), first,
                                             fps, task))
    finally:
        video.close()
    if not episodes:
        raise ExportError('no episode with frames in ' + ', '.join(map(str, recordings)))
    data = root / DATA_PATH.format(**location)
    data.parent.mkdir(parents=True)
    pq.write_table(pa.concat_tables(tables), data, compression='snappy')
    meta = root / 'meta'
    (meta / 'episodes' / 'chunk-000').mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(episodes), root / EPISODES_PATH.format(**location))
    pq.write_table(_tasks_table([task]), root / TASKS_PATH)
    merged = {key: np.concatenate([columns[key] for columns in all_columns])
              for key in all_columns[0]}
    stats = {key: feature_stats(value) for key, value in merged.items()}
    stats[CAMERA_KEY] = image_stats(image_samples)
    (meta / 'stats.json').write_text(json.dumps(stats, indent=4))
    frames = sum(len(table) for table in tables)
    info = {
        'codebase_version': CODEBASE_VERSION, 'robot_type': 'ur_rg2',
        'total_episodes': len(episodes), 'total_frames': frames, 'total_tasks': 1,
        'chunks_size': CHUNKS_SIZE, 'data_files_size_in_mb': DATA_FILES_MB,
        'video_files_size_in_mb': VIDEO_FILES_MB, 'fps': fps,
        'splits': {'train': f'0:{len(episodes)}'},
        'data_path': DATA_PATH, 'video_path': VIDEO_PATH,
        'features': features(video.shape, video.info()),
    }
    (meta / 'info.json').write_text(json.dumps(info, indent=4))
    (root / 'README.md').write_text(_card(repo_id, info))
    outcomes = [episode['outcome'] for episode in episodes]
    return Summary(len(episodes), frames, outcomes.count(EPISODE_SUCCESS),
                   outcomes.count(EPISODE_FAILURE), video.codec)


def _encode(reader: Reader, sampled: list[EpisodeFrames],
            video: VideoWriter) -> list[list[np.ndarray]]:
    """Encode every frame's image in order; return each episode's image samples for stats."""
    wanted = [(index, frame) for index, frames in enumerate(sampled)
              for frame in range(len(frames.images))]
    shown = np.concatenate([frames.images for frames in sampled]) if sampled else []
    samples: list[list[np.ndarray]] = [[] for _ in sampled]
    picks = [set(np.linspace(0, len(frames.images) - 1,
                             min(IMAGE_SAMPLES, len(frames.images))).round().astype(int))
             for frames in sampled]
    position = 0
    messages = (decode for _, _, decode in reader.messages({COLOR_IMAGE}))
    for number, decode in enumerate(messages):
        if position == len(shown):
            break
        if shown[position] != number:
            continue
        image = image_rgb(decode(), reader.path)
        while position < len(shown) and shown[position] == number:
            episode, frame = wanted[position]
            video.add(image, reader.path)
            if frame in picks[episode]:
                samples[episode].append(image[::8, ::8])
            position += 1
    if position != len(shown):
        raise ExportError(f'{reader.path}: its camera images changed while it was read')
    return samples


def _episode_row(frames: EpisodeFrames, columns: dict[str, np.ndarray],
                 images: list[np.ndarray], index: int, first: int, fps: int,
                 task: str) -> dict[str, Any]:
    """Return the episode's row of meta/episodes (LeRobot's columns, its outcome, its stats)."""
    count = len(frames.state)
    outcome = frames.episode.outcome
    row: dict[str, Any] = {
        'episode_index': index, 'tasks': [task], 'length': count,
        'data/chunk_index': 0, 'data/file_index': 0,
        'dataset_from_index': first, 'dataset_to_index': first + count,
        f'videos/{CAMERA_KEY}/chunk_index': 0, f'videos/{CAMERA_KEY}/file_index': 0,
        f'videos/{CAMERA_KEY}/from_timestamp': first / fps,
        f'videos/{CAMERA_KEY}/to_timestamp': (first + count) / fps,
        'meta/episodes/chunk_index': 0, 'meta/episodes/file_index': 0,
        'success': outcome == EPISODE_SUCCESS, 'outcome': outcome or 'unmarked',
    }
    stats = {key: feature_stats(value) for key, value in columns.items()}
    stats[CAMERA_KEY] = image_stats(images)
    for key, values in stats.items():
        for name, value in values.items():
            row[f'stats/{key}/{name}'] = value
    return row
