"""to_lerobot: recordings to LeRobot v3.0 data sets, checked against LeRobot's layout.

The recordings are written with the recorder's own writer (ur_rg2_tools.bag, the schemas and
CDR bytes of ``record``) from the contract's messages: joint states at 100 Hz, colour images
at 30 Hz, vision's sightings, and the ``episode`` markers the nodes publish. LeRobot itself is
not installed here: its v3.0 layout is checked as LeRobot 0.4 writes and reads it.
"""

import json
import math

import av
from geometry_msgs.msg import PointStamped
import numpy as np
import pyarrow.parquet as pq
import pytest
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import String
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS
from ur_rg2_tools.bag import BagWriter, offered_qos_yaml
from ur_rg2_tools.msgdefs import full_text
from ur_rg2_tools.to_lerobot import main

T0 = 1_700_000_000 * 10 ** 9  # log time of the recording's first message, ns
WIDTH, HEIGHT = 128, 96
FPS = 10


def write_recording(path, seconds: float, markers=(), joints: bool = True,
                    ball=(0.1, 0.0, 0.8)) -> None:
    """Write ``seconds`` of the graph's topics; ``markers`` are (seconds, 'start'|...)."""
    bag = BagWriter(path)
    qos = offered_qos_yaml([QoSProfile(depth=10)])

    def topic(name, type_name):
        return bag.add_topic(name, type_name, full_text(type_name), qos)

    states = topic('/joint_states', 'sensor_msgs/msg/JointState')
    images = topic('/camera/color/image_raw', 'sensor_msgs/msg/Image')
    balls = topic('/ball/position', 'geometry_msgs/msg/PointStamped')
    episodes = topic('/episode', 'std_msgs/msg/String')
    events = []
    if joints:
        for i in range(int(seconds * 100)):
            t = i / 100
            events.append((t, states, JointState(
                name=[*ARM_JOINTS, *GRIPPER_JOINTS],
                position=[0.1 * t * (j + 1) for j in range(6)] + [0.02, 0.02])))
    for i in range(int(seconds * 30)):
        t = i / 30
        image = np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)
        image[:, :, 0] = i * 3 % 256  # each frame its own red
        image[HEIGHT // 4:HEIGHT // 2, (i * 2) % WIDTH:(i * 2) % WIDTH + 16, 1] = 255
        events.append((t, images, Image(height=HEIGHT, width=WIDTH, encoding='rgb8',
                                        step=WIDTH * 3, data=image.tobytes())))
        if ball is not None and t < seconds / 2:  # vision loses the ball halfway
            message = PointStamped()
            message.header.frame_id = 'camera_color_optical_frame'
            message.point.x, message.point.y, message.point.z = ball
            events.append((t + 0.005, balls, message))
    events += [(t, episodes, String(data=value)) for t, value in markers]
    for t, channel, message in sorted(events, key=lambda event: event[0]):
        time = T0 + round(t * 1e9)
        bag.write(channel, serialize_message(message), time, time)
    bag.finish()


def read_dataset(root):
    info = json.loads((root / 'meta/info.json').read_text())
    data = pq.read_table(root / 'data/chunk-000/file-000.parquet').to_pylist()
    episodes = pq.read_table(root / 'meta/episodes/chunk-000/file-000.parquet').to_pylist()
    return info, data, episodes


def decoded_frames(path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format='rgb24') for frame in container.decode(video=0)]


def test_marked_episodes_become_a_v3_dataset(tmp_path, capsys):
    recording = tmp_path / 'demo.mcap'
    # One failure, some time between, one success, and an end with nothing open.
    write_recording(recording, 6.0, [(0.5, 'start'), (2.0, 'failure'), (2.6, 'start'),
                                     (5.1, 'success'), (5.5, 'failure')])
    root = tmp_path / 'demos'
    assert main([str(recording), '-o', str(root), '--fps', str(FPS),
                 '--repo-id', 'someone/ur_rg2_demos']) == 0
    out = capsys.readouterr()
    assert 'wrote' in out.out and '2 episodes (1 success, 1 failure, 0 unmarked)' in out.out
    assert 'a failure at 5.50 s with no episode open: ignored' in out.err
    info, data, episodes = read_dataset(root)
    assert info['codebase_version'] == 'v3.0' and info['fps'] == FPS
    assert info['data_path'] == 'data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet'
    assert info['video_path'] == ('videos/{video_key}/chunk-{chunk_index:03d}/'
                                  'file-{file_index:03d}.mp4')
    # Rows per episode: its duration times fps, within one frame.
    for episode, seconds in zip(episodes, (1.5, 2.5)):
        assert abs(episode['length'] - seconds * FPS) <= 1
    assert [e['success'] for e in episodes] == [False, True]
    assert info['total_episodes'] == 2 and info['total_frames'] == len(data)
    assert info['splits'] == {'train': '0:2'}
    # LeRobot's per-frame columns, indices running on across episodes.
    assert [row['index'] for row in data] == list(range(len(data)))
    first = episodes[0]['length']
    assert [row['episode_index'] for row in data] == [0] * first + [1] * (len(data) - first)
    assert [row['frame_index'] for row in data[first:first + 3]] == [0, 1, 2]
    assert math.isclose(data[first + 3]['timestamp'], 3 / FPS, rel_tol=1e-6)
    assert [row['next.done'] for row in data].count(True) == 2
    assert [i for i, row in enumerate(data) if row['next.success']] == [len(data) - 1]
    # State: the joints at the frame's time (joint j at 0.1 (j+1) t rad), the opening 40 mm;
    # the action is the next frame's state.
    row = data[first + 5]
    t = 2.6 + 5 / FPS
    assert row['observation.state'][:6] == pytest.approx(
        [0.1 * (j + 1) * t for j in range(6)], abs=0.1 * 6 * 0.011)
    assert row['observation.state'][6] == pytest.approx(0.04)
    assert row['action'] == data[first + 6]['observation.state']
    # The ball as vision saw it until 3 s: seen, then held and no longer seen.
    assert data[0]['observation.environment_state'] == pytest.approx([0.1, 0.0, 0.8, 1.0])
    assert data[-1]['observation.environment_state'] == pytest.approx([0.1, 0.0, 0.8, 0.0])
    # Episode rows point at their frames and their stretch of the video.
    assert episodes[1]['dataset_from_index'] == first
    assert episodes[1]['dataset_to_index'] == len(data)
    key = 'videos/observation.images.camera'
    assert episodes[1][f'{key}/from_timestamp'] == pytest.approx(first / FPS)
    assert episodes[1]['tasks'] == ['Pick up the ball.']
    # The video decodes to as many frames as rows, each the recording's image of its time.
    frames = decoded_frames(root / 'videos/observation.images.camera/chunk-000/file-000.mp4')
    assert len(frames) == len(data)
    for index, at in ((0, 0.5), (first + 10, 3.6)):
        red = (math.floor(at * 30 + 1e-6) * 3) % 256
        assert abs(float(frames[index][:, :, 0].mean()) - red) < 6
    assert (root / 'README.md').read_text().count('someone/ur_rg2_demos') == 1
    assert not list(tmp_path.glob('.demos*'))  # no partial directory left


def test_schema_of_the_dataset(tmp_path):
    recording = tmp_path / 'plain.mcap'
    write_recording(recording, 2.0, ball=None)
    root = tmp_path / 'plain'
    assert main([str(recording), '-o', str(root), '--fps', '15']) == 0
    info, data, episodes = read_dataset(root)
    features = info['features']
    assert features['observation.state'] == {
        'dtype': 'float32', 'shape': [7], 'names': [*ARM_JOINTS, 'gripper_opening']}
    assert features['action']['names'] == features['observation.state']['names']
    assert features['observation.environment_state']['names'] == [
        'ball_x', 'ball_y', 'ball_z', 'ball_seen']
    camera = features['observation.images.camera']
    assert (camera['dtype'], camera['shape']) == ('video', [HEIGHT, WIDTH, 3])
    assert camera['names'] == ['height', 'width', 'channels']
    assert camera['info']['video.codec'] in ('av1', 'h264')
    assert camera['info']['video.fps'] == 15 and camera['info']['video.pix_fmt'] == 'yuv420p'
    for name in ('timestamp', 'frame_index', 'episode_index', 'index', 'task_index',
                 'next.done', 'next.success'):
        assert features[name]['shape'] == [1]
    for key in ('total_tasks', 'chunks_size', 'data_files_size_in_mb', 'video_files_size_in_mb',
                'robot_type'):
        assert key in info
    # Each non-video feature is a Parquet column of its dtype and shape.
    schema = pq.read_schema(root / 'data/chunk-000/file-000.parquet')
    for name, feature in features.items():
        if feature['dtype'] == 'video':
            assert name not in schema.names
            continue
        column = schema.field(name).type
        if feature['shape'] == [1]:
            assert str(column) == {'float32': 'float', 'int64': 'int64',
                                   'bool': 'bool'}[feature['dtype']]
        else:
            assert column.list_size == feature['shape'][0]
            assert str(column.value_type) == 'float'
    # No markers: one episode, the whole recording, unmarked; no ball seen: zeros, not seen.
    assert len(episodes) == 1 and episodes[0]['outcome'] == 'unmarked'
    assert abs(len(data) - 2.0 * 15) <= 1
    assert all(row['observation.environment_state'] == [0, 0, 0, 0] for row in data)
    # The tasks table as pandas writes LeRobot's (the task as its index).
    tasks = pq.read_table(root / 'meta/tasks.parquet')
    assert tasks.to_pylist() == [{'task_index': 0, '__index_level_0__': 'Pick up the ball.'}]
    assert json.loads(tasks.schema.metadata[b'pandas'])['index_columns'] == [
        '__index_level_0__']
    # Stats as LeRobot's: per feature min, max, mean, std, count, quantiles; images per channel.
    stats = json.loads((root / 'meta/stats.json').read_text())
    assert set(stats) == set(features)
    assert set(stats['action']) == {'min', 'max', 'mean', 'std', 'count', 'q01', 'q10', 'q50',
                                    'q90', 'q99'}
    assert len(stats['action']['mean']) == 7 and stats['action']['count'] == [len(data)]
    assert np.array(stats['observation.images.camera']['mean']).shape == (3, 1, 1)
    assert 0 <= stats['observation.images.camera']['max'][1][0][0] <= 1
    assert episodes[0]['stats/action/count'] == [len(data)]
    assert len(decoded_frames(
        root / 'videos/observation.images.camera/chunk-000/file-000.mp4')) == len(data)


def test_bad_input_is_one_clear_error_and_nothing_written(tmp_path, capsys):
    def refused(*args) -> str:
        assert main([*map(str, args), '-o', str(tmp_path / 'out')]) == 1
        assert not (tmp_path / 'out').exists() and not list(tmp_path.glob('.out*'))
        error = capsys.readouterr().err
        assert error.count('\n') == 1, error
        return error

    assert 'cannot open' in refused(tmp_path / 'missing.mcap')
    (tmp_path / 'text.mcap').write_text('not a recording')
    assert 'not an MCAP file' in refused(tmp_path / 'text.mcap')
    whole = tmp_path / 'whole.mcap'
    write_recording(whole, 1.0)
    data = whole.read_bytes()
    (tmp_path / 'cut.mcap').write_bytes(data[:len(data) // 2])
    assert 'ur_rg2_tools recover' in refused(tmp_path / 'cut.mcap')
    write_recording(tmp_path / 'images.mcap', 1.0, joints=False)
    assert 'no /joint_states message with the six arm joints' in refused(
        tmp_path / 'images.mcap')
    # A good recording after a bad one: still nothing written.
    assert 'no /joint_states' in refused(whole, tmp_path / 'images.mcap')
    (tmp_path / 'out').mkdir()
    (tmp_path / 'out' / 'kept').write_text('precious')
    assert main([str(whole), '-o', str(tmp_path / 'out')]) == 1
    assert 'exists' in capsys.readouterr().err
    assert (tmp_path / 'out' / 'kept').read_text() == 'precious'
