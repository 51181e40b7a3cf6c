"""record and replay through the contract: the running sim to MCAP and back into vision.

The recorder and the player run as users run them (``ros2 run ur_rg2_tools ...``) on the
test's private domain; a subscriber beside the recorder counts what was published.
"""

from collections import Counter, defaultdict
import json
import re
import struct
import urllib.request

from conftest import RosGraph, start_sim, wait_for
from geometry_msgs.msg import PointStamped
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image, JointState
from test_ros2_cli import Launched
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_tools.view3d_node import View3dNode
from ur_rg2_vision.vision_node import VisionNode

COUNTED = {'/joint_states': JointState, '/camera/color/image_raw': Image,
           '/camera/depth/image_raw': Image}
FOR_VISION = ['/camera/color/image_raw', '/camera/depth/image_raw', '/camera/color/camera_info']
RECORDED = sorted({*COUNTED, *FOR_VISION, '/tf_static', '/robot_description'})
RECORD_S = 10.0  # of simulation time (the sim runs in real time)
START_TIMEOUT_S = 120.0


def stamp(cdr: bytes) -> tuple[int, int]:
    """Return header.stamp of a CDR message whose first field is a std_msgs/Header."""
    return struct.unpack_from('<iI', cdr, 4)  # after the 4-byte encapsulation header


class Witness:
    """Keeps every message of COUNTED the graph delivers to it, serialized, by header stamp."""

    def __init__(self, graph: RosGraph) -> None:
        self.seen: dict[str, list[tuple[tuple[int, int], bytes]]] = defaultdict(list)
        node = graph.node('counter')
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        for topic, message_type in COUNTED.items():
            node.create_subscription(message_type, topic,
                                     lambda data, topic=topic: self._on(topic, data), qos,
                                     raw=True)

    def _on(self, topic: str, data: bytes) -> None:
        self.seen[topic].append((stamp(data), data))

    def latest(self, topic: str) -> float:
        seen = self.seen[topic][-1:]
        return seen[0][0][0] + seen[0][0][1] / 1e9 if seen else 0.0


def read_back(path) -> dict[str, list]:
    """Return the file's messages by topic: (stamp, bytes, decoded message) in file order."""
    messages = defaultdict(list)
    with open(path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == 'cdr' and schema.encoding == 'ros2msg'
            key = stamp(message.data) if channel.topic in COUNTED else None
            messages[channel.topic].append((key, message.data, decoded))
    return messages


def info_counts(env: dict[str, str], path, log) -> tuple[str, dict[str, int]]:
    """Run ``ros2 run ur_rg2_tools info`` on ``path``; return its output and count per topic."""
    info = Launched(['ros2', 'run', 'ur_rg2_tools', 'info', str(path)], env, log)
    assert info.wait(60) == 0, info.output
    counts = {topic: int(count) for topic, count in re.findall(
        r'Topic: (\S+) \| Type: \S+ \| Count: (\d+) \| Serialization Format: cdr',
        info.output)}
    return info.output, counts


def test_round_trip_record_the_sim_read_back_replay_into_vision(ros_graph, tmp_path):
    start_sim(ros_graph, camera_width=320, camera_height=240)
    counter = Witness(ros_graph)
    wait_for(lambda: len(counter.seen['/camera/depth/image_raw']) >= 3, START_TIMEOUT_S,
             'the sim to publish camera frames')
    path = tmp_path / 'run.mcap'
    recorder = Launched(['ros2', 'run', 'ur_rg2_tools', 'record', '-o', str(path), *RECORDED],
                        ros_graph.env, tmp_path / 'record.log')
    try:
        wait_for(lambda: recorder.output.count('recording /') == len(RECORDED) + 1 or
                 recorder.process.poll() is not None, START_TIMEOUT_S,
                 'the recorder to subscribe to every topic')
        assert recorder.process.poll() is None, recorder.output
        started = counter.latest('/joint_states')
        wait_for(lambda: counter.latest('/joint_states') - started > RECORD_S,
                 RECORD_S * 6, f'{RECORD_S} s of simulation time')
        recorder.ctrl_c()
        assert recorder.wait(30) == 0, recorder.output
    finally:
        recorder.kill()
    assert 'Traceback' not in recorder.output and f'wrote {path}' in recorder.output

    recorded = read_back(path)
    assert sorted(recorded) == RECORDED
    # info, as ros2 bag info: the counts of the file's summary.
    output, counts = info_counts(ros_graph.env, path, tmp_path / 'info.log')
    assert counts == {topic: len(messages) for topic, messages in recorded.items()}
    assert f'Messages:          {sum(counts.values())}' in output
    assert 'Storage id:        mcap' in output and 'Compression:       zstd' in output
    # /tf_static was published before the recorder started: latched, it is in the file.
    assert recorded['/tf_static'][0][2].transforms
    assert isinstance(deserialize_message(recorded['/tf_static'][0][1], TFMessage), TFMessage)
    for topic in COUNTED:
        stamps = [key for key, _, _ in recorded[topic]]
        first, last = min(stamps), max(stamps)
        assert (last[0] + last[1] / 1e9) - (first[0] + first[1] / 1e9) > RECORD_S * 0.95, topic
        # Everything the subscriber beside it got while the recorder was recording, and the
        # same messages byte for byte (the sim may publish two joint states with one stamp).
        published = Counter(data for key, data in list(counter.seen[topic])
                            if first <= key <= last)
        in_file = Counter(data for _, data, _ in recorded[topic])
        kept = sum((published & in_file).values())
        assert kept >= 0.99 * published.total(), (
            f'{topic}: recorded {kept} of {published.total()} messages')
        seen = dict(counter.seen[topic])
        assert not [key for key, data, _ in recorded[topic]
                    if key in seen and data not in published], f'{topic}: messages changed'
        # The reader's decoding is the message.
        key, data, decoded = recorded[topic][len(recorded[topic]) // 2]
        original = deserialize_message(data, COUNTED[topic])
        assert (decoded.header.stamp.sec, decoded.header.stamp.nanosec) == key
        if topic == '/joint_states':
            assert list(decoded.name) == list(original.name)
            assert list(decoded.position) == list(original.position)
        else:
            assert (decoded.width, decoded.encoding) == (original.width, original.encoding)
            assert bytes(decoded.data) == bytes(original.data)

    # Replay into vision and the 3D view on a graph with no sim: vision finds the ball in the
    # recorded frames, the 3D view has the robot at the recorded joint states.
    frames = {key for key, _, _ in recorded['/camera/color/image_raw']}
    graph = RosGraph()
    try:
        graph.add(VisionNode(context=graph.context))
        view = graph.add(View3dNode(context=graph.context, parameter_overrides=[
            Parameter('port', value=0)]))
        found = []
        graph.node('ball_watcher').create_subscription(
            PointStamped, 'ball/position', found.append, 100)
        player = Launched(['ros2', 'run', 'ur_rg2_tools', 'replay', str(path)],
                          graph.env, tmp_path / 'replay.log')

        def replayed() -> bool:
            # As a page asks for it: the 3D view reads its topics when the scene is asked for.
            with urllib.request.urlopen(view.url + 'scene', timeout=10) as response:
                scene = json.loads(response.read())
            return (len(found) >= 3 and set(ARM_JOINTS) <= set(scene.get('joints', ()))
                    and view.scene.description() is not None and 'camera' in scene)

        try:
            wait_for(lambda: replayed() or player.process.poll() is not None,
                     START_TIMEOUT_S, 'ball/position and the 3D scene from the replay')
            assert replayed(), player.output
            for ball in found:
                assert (ball.header.stamp.sec, ball.header.stamp.nanosec) in frames
                assert ball.header.frame_id == 'camera_color_optical_frame'
                assert 0.5 < ball.point.z < 3.0  # in front of the camera, on the floor
            player.ctrl_c()
            assert player.wait(30) == 0, player.output
        finally:
            player.kill()
        assert 'Traceback' not in player.output
    finally:
        graph.shutdown()


def test_a_killed_recorder_leaves_its_chunks_readable(ros_graph, tmp_path):
    start_sim(ros_graph, camera_width=320, camera_height=240, real_time_factor=0.0)
    path = tmp_path / 'killed.mcap'
    recorder = Launched(['ros2', 'run', 'ur_rg2_tools', 'record', '-o', str(path),
                         'camera/depth/image_raw'], ros_graph.env, tmp_path / 'record.log')
    try:
        # Depth images of 300 kB: a 1 MB chunk is written every 4 of them.
        wait_for(lambda: path.exists() and path.stat().st_size > 3_000_000, START_TIMEOUT_S,
                 'the recorder to write a few chunks')
    finally:
        recorder.kill()  # SIGKILL: no chance to finish the file
    replay = Launched(['ros2', 'run', 'ur_rg2_tools', 'replay', str(path)], ros_graph.env,
                      tmp_path / 'replay.log')
    assert replay.wait(60) == 1
    assert 'not a complete MCAP file' in replay.output and 'recover' in replay.output
    assert 'Traceback' not in replay.output
    fixed = tmp_path / 'fixed.mcap'
    recover = Launched(['ros2', 'run', 'ur_rg2_tools', 'recover', str(path), '-o', str(fixed)],
                       ros_graph.env, tmp_path / 'recover.log')
    assert recover.wait(60) == 0, recover.output
    recorded = read_back(fixed)['/camera/depth/image_raw']
    assert len(recorded) >= 4
    # info reads the file without a summary through: the messages recover kept.
    output, counts = info_counts(ros_graph.env, path, tmp_path / 'info.log')
    assert counts == {'/camera/depth/image_raw': len(recorded)}
    assert 'Cut short:' in output and 'recover' in output
    assert all(decoded.encoding == '32FC1' for _, _, decoded in recorded)


def test_bad_input_is_one_clear_error_and_nothing_lost(ros_graph, tmp_path):
    # A topic nobody publishes: exit 1 naming it; what was recorded is a complete file.
    ros_graph.node('talker').create_publisher(JointState, 'joint_states', 10)
    path = tmp_path / 'partial.mcap'
    recorder = Launched(['ros2', 'run', 'ur_rg2_tools', 'record', '--wait', '5', '-o',
                         str(path), 'joint_states', 'no_such_topic'], ros_graph.env,
                        tmp_path / 'record.log')
    try:
        assert recorder.wait(60) == 1
    finally:
        recorder.kill()
    # (On a loaded machine /joint_states may not be discovered within --wait either.)
    assert re.search(r'unknown topic (/joint_states, )?/no_such_topic: no publisher',
                     recorder.output), recorder.output
    assert 'Traceback' not in recorder.output and f'wrote {path}' in recorder.output
    assert read_back(path) == {}  # complete, readable, and empty: nothing was published
    # An existing file is never overwritten.
    again = Launched(['ros2', 'run', 'ur_rg2_tools', 'record', '-o', str(path), '--all'],
                     ros_graph.env, tmp_path / 'again.log')
    assert again.wait(60) == 1 and 'File exists' in again.output
    assert 'Traceback' not in again.output
    no_cache = Launched(['ros2', 'run', 'ur_rg2_tools', 'record', '--max-cache-size', '0',
                         '--all'], ros_graph.env, tmp_path / 'no_cache.log')
    assert no_cache.wait(60) == 2
    assert '--max-cache-size must be positive, not 0' in no_cache.output
    # replay and info: a missing file and a file that is no recording (no advice to recover).
    (tmp_path / 'text.mcap').write_text('hello')
    for command in ('replay', 'info'):
        for name, reason in (('missing.mcap', 'No such file'),
                             ('text.mcap', 'not an MCAP file')):
            player = Launched(['ros2', 'run', 'ur_rg2_tools', command, str(tmp_path / name)],
                              ros_graph.env, tmp_path / f'{command}-{name}.log')
            assert player.wait(60) == 1
            assert reason in player.output and 'Traceback' not in player.output
            assert 'recover' not in player.output
