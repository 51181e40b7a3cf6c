"""Node ``ur_rg2_vision`` through its contract: topics, the save service, parameters."""

import functools
import os
from pathlib import Path
import re
import select
import signal
import subprocess
import sys
import time

from builtin_interfaces.msg import Time
from conftest import wait_for
import cv2
from geometry_msgs.msg import PointStamped
import numpy as np
import pytest
from rcl_interfaces.msg import Log
from rclpy.duration import Duration
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from test_vision_scenes import HEIGHT, WIDTH, K, Scene, Sphere, render
from ur_rg2_vision.frame_store import depth_to_mm
from ur_rg2_vision.ros_image import image_to_rgb
from ur_rg2_vision.vision_node import VisionNode

TIMEOUT = 15.0  # generous: a loaded 2-core machine
QUIET = 0.5  # how long "nothing more arrives" is watched
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
FRAME_ID = 'camera_color_optical_frame'
# A saved frame's name: the UTC time of the save, then the simulation stamp.
SAVED = r'frame_\d{8}T\d{6}\.\d{3}Z_sim%010d\.%09d(?:_\d+)?_(color|depth)\.png'


def saved_name(sec: int, nanosec: int = 250_000_000) -> re.Pattern:
    """Return the pattern of the names of the frame stamped ``sec``.``nanosec``."""
    return re.compile(SAVED % (sec, nanosec))


@functools.cache
def ball_frame():
    """Return (rgb, depth, ball centre) of a synthetic frame with the red ball."""
    centre = Scene().on_floor(0.1, 1.2, 0.03)
    rgb, depth = render(Scene(spheres=[Sphere(centre)]))
    return rgb, depth, np.array(centre)


@functools.cache
def empty_frame():
    """Return (rgb, depth) of the floor alone."""
    return render(Scene())


def header(sec: int) -> Header:
    return Header(stamp=Time(sec=sec, nanosec=250_000_000), frame_id=FRAME_ID)


def color_msg(sec: int, rgb: np.ndarray) -> Image:
    return Image(header=header(sec), height=rgb.shape[0], width=rgb.shape[1], encoding='rgb8',
                 step=rgb.shape[1] * 3, data=rgb.tobytes())


def depth_msg(sec: int, depth: np.ndarray) -> Image:
    return Image(header=header(sec), height=depth.shape[0], width=depth.shape[1],
                 encoding='32FC1', step=depth.shape[1] * 4, data=depth.tobytes())


def info_msg(sec: int, k=K, width=WIDTH, height=HEIGHT) -> CameraInfo:
    return CameraInfo(header=header(sec), width=width, height=height,
                      distortion_model='plumb_bob', d=[0.0] * 5, k=np.ravel(k).tolist())


class Rig:
    """A fake camera publishing to the vision node, and a listener of its outputs."""

    def __init__(self, graph, vision: VisionNode) -> None:
        self.vision = vision
        node = graph.node('vision_test_rig', namespace=vision.get_namespace())
        self.node = node
        self.color = node.create_publisher(Image, 'camera/color/image_raw', QOS)
        self.depth = node.create_publisher(Image, 'camera/depth/image_raw', QOS)
        self.info = node.create_publisher(CameraInfo, 'camera/color/camera_info', QOS)
        self.positions: list[PointStamped] = []
        self.images: list[Image] = []
        self._subscriptions = [
            node.create_subscription(PointStamped, 'ball/position', self.positions.append, QOS),
            node.create_subscription(Image, 'ball/image', self.images.append, QOS)]
        self.save = node.create_client(Trigger, 'vision/save_frame')
        wait_for(lambda: all(p.get_subscription_count() for p in (self.color, self.depth,
                                                                   self.info))
                 and all(s.get_publisher_count() for s in self._subscriptions),
                 TIMEOUT, 'the vision node and the test rig to match')

    def send(self, sec: int, rgb=None, depth=None, info=True, depth_first=False) -> None:
        """Publish one frame: colour (and its camera_info) and depth, either may be omitted."""
        messages = []
        if rgb is not None:
            messages.append((self.color, color_msg(sec, rgb)))
        if info:
            messages.append((self.info, info_msg(sec)))
        if depth is not None:
            depth_pair = (self.depth, depth_msg(sec, depth))
            messages.insert(0 if depth_first else len(messages), depth_pair)
        for publisher, msg in messages:
            publisher.publish(msg)

    def send_ball(self, sec: int, **kwargs) -> None:
        rgb, depth, _ = ball_frame()
        self.send(sec, rgb, depth, **kwargs)

    def wait_images(self, count: int) -> None:
        wait_for(lambda: len(self.images) >= count, TIMEOUT, f'{count} ball/image messages')

    def wait_positions(self, count: int) -> None:
        wait_for(lambda: len(self.positions) >= count, TIMEOUT,
                 f'{count} ball/position messages')

    def call_save(self) -> Trigger.Response:
        assert self.save.wait_for_service(timeout_sec=TIMEOUT)
        future = self.save.call_async(Trigger.Request())
        wait_for(future.done, TIMEOUT, 'the vision/save_frame response')
        return future.result()


def rosout(graph) -> list[Log]:
    """Return a list that collects what the nodes of ``graph`` log from now on."""
    logs: list[Log] = []
    graph.node('log_listener').create_subscription(Log, '/rosout', logs.append, 100)
    return logs


def vision_warnings(logs: list[Log]) -> list[str]:
    return [log.msg for log in logs if log.name == 'ur_rg2_vision' and log.level >= Log.WARN]


def start(graph, tmp_path, namespace: str = '', **parameters) -> Rig:
    parameters.setdefault('frames_dir', str(tmp_path / 'frames'))
    vision = graph.add(VisionNode(
        context=graph.context, namespace=namespace,
        parameter_overrides=[Parameter(name, value=value) for name, value in parameters.items()]))
    return Rig(graph, vision)


def test_ball_position_and_annotated_image(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    rig.send_ball(7)
    rig.wait_positions(1)
    rig.wait_images(1)
    position, annotated = rig.positions[0], rig.images[0]
    assert position.header == header(7) == annotated.header
    point = np.array([position.point.x, position.point.y, position.point.z])
    assert np.linalg.norm(point - ball_frame()[2]) < 0.003
    rgb = ball_frame()[0]
    assert (annotated.encoding, annotated.width, annotated.height) == ('rgb8', WIDTH, HEIGHT)
    drawn = image_to_rgb(annotated)
    changed = np.any(drawn != rgb, axis=2)
    assert 100 < changed.sum() < 5000  # the circle around the ball, nothing else
    assert (drawn[changed][:, 1] > drawn[changed][:, 0]).mean() > 0.5  # drawn in green


def test_depth_may_come_before_colour(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    rig.send_ball(3, depth_first=True)
    rig.wait_positions(1)
    assert rig.positions[0].header.stamp == header(3).stamp


def test_a_node_that_fell_behind_goes_on_with_the_newest_frame(ros_graph, tmp_path):
    """Frames that came while the node was busy are dropped, not worked through in turn."""
    vision = VisionNode(context=ros_graph.context, parameter_overrides=[
        Parameter('frames_dir', value=str(tmp_path / 'frames'))])
    rig = Rig(ros_graph, vision)  # matched, but not spun yet: as busy with a long frame
    for sec in range(1, 5):
        rig.send_ball(sec)
        for publisher in (rig.color, rig.depth):  # in the node's reader
            assert publisher.wait_for_all_acked(Duration(seconds=TIMEOUT))
    ros_graph.add(vision)
    rig.wait_positions(1)
    rig.wait_images(1)
    assert [p.header.stamp.sec for p in rig.positions] == [4]
    assert [i.header.stamp.sec for i in rig.images] == [4]
    rig.send_ball(5)  # and on at the camera's pace
    rig.wait_positions(2)
    assert [p.header.stamp.sec for p in rig.positions] == [4, 5]


def test_colour_without_depth_gives_image_but_no_position(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    rgb, depth, _ = ball_frame()
    rig.send(1, rgb)
    rig.wait_images(1)
    rig.send(2, rgb, depth)  # a complete frame after it: only that one has a position
    rig.wait_positions(1)
    rig.wait_images(2)
    assert [p.header.stamp.sec for p in rig.positions] == [2]


def test_frame_without_ball_gives_image_but_no_position(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    rgb, depth = empty_frame()
    rig.send(1, rgb, depth)
    rig.wait_images(1)
    rig.send_ball(2)
    rig.wait_positions(1)
    assert [p.header.stamp.sec for p in rig.positions] == [2]


def test_camera_info_coming_late_gives_no_warning(ros_graph, tmp_path):
    """At start-up camera_info may reach vision a few frames after the images."""
    logs = rosout(ros_graph)
    rig = start(ros_graph, tmp_path)
    for sec in range(1, 6):
        rig.send_ball(sec, info=False)
        rig.wait_images(sec)
    rig.send_ball(6)
    wait_for(lambda: 6 in [p.header.stamp.sec for p in rig.positions], TIMEOUT,
             'a position once camera_info came')
    # A warning about something else: once it is in, a camera_info warning would be too.
    rig.color.publish(Image(header=header(7), height=2, width=2, encoding='mono16', step=4,
                            data=bytes(8)))
    wait_for(lambda: vision_warnings(logs), TIMEOUT, 'the warning about the bad image')
    assert [msg for msg in vision_warnings(logs) if 'colour image ignored' in msg] == \
        vision_warnings(logs)


def test_camera_info_missing_for_good_is_warned_about(ros_graph, tmp_path):
    logs = rosout(ros_graph)
    rig = start(ros_graph, tmp_path)
    sec = 0

    def warned() -> bool:
        nonlocal sec
        sec += 1
        rig.send_ball(sec, info=False)
        time.sleep(0.1)  # a camera's pace, not a flood
        return any('no camera/color/camera_info for the' in msg
                   for msg in vision_warnings(logs))

    wait_for(warned, TIMEOUT, 'the warning that camera_info is missing')
    assert sec >= 10  # not at the first frames: those may just be early
    assert not rig.positions


def test_save_frame_before_any_frame_fails_with_reason(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    response = rig.call_save()
    assert not response.success
    assert 'no camera frame' in response.message


def test_save_frame_writes_colour_and_depth_png(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    rig.send_ball(5)
    rig.wait_positions(1)
    response = rig.call_save()
    assert response.success, response.message
    color_path, depth_path = response.message.split()
    assert color_path.endswith('_color.png') and depth_path.endswith('_depth.png')
    assert saved_name(5).fullmatch(os.path.basename(color_path))
    assert os.path.basename(depth_path) == os.path.basename(color_path)[:-9] + 'depth.png'
    rgb, depth, _ = ball_frame()
    saved = cv2.cvtColor(cv2.imread(color_path), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(saved, rgb)
    np.testing.assert_array_equal(cv2.imread(depth_path, cv2.IMREAD_UNCHANGED),
                                  depth_to_mm(depth))
    assert sorted(os.listdir(tmp_path / 'frames')) == sorted(
        os.path.basename(p) for p in (color_path, depth_path))


def test_a_saved_frame_is_reported_once_by_the_answer_not_in_the_log(ros_graph, tmp_path):
    """The caller (keys) prints the answer; an info log line would say it a second time."""
    logs = rosout(ros_graph)
    rig = start(ros_graph, tmp_path)
    rig.send_ball(5)
    rig.wait_positions(1)
    response = rig.call_save()
    assert response.success, response.message
    # A failing save warns: once that warning is in, an info line about the save would be too.
    blocker = tmp_path / 'not_a_dir'
    blocker.write_text('')
    rig.vision.set_parameters([Parameter('frames_dir', value=str(blocker / 'frames'))])
    assert not rig.call_save().success
    wait_for(lambda: any('not_a_dir' in log.msg for log in logs), TIMEOUT, 'the warning')
    shown = [log.msg for log in logs if log.name == 'ur_rg2_vision' and log.level >= Log.INFO]
    assert not [msg for msg in shown if response.message.split()[0] in msg], shown


def test_save_frame_colour_only_says_depth_is_missing(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    rig.send(1, ball_frame()[0])
    rig.wait_images(1)
    response = rig.call_save()
    assert response.success
    assert response.message.endswith('_color.png (no depth image for this frame)')


def test_unwritable_frames_dir_fails_and_node_keeps_running(ros_graph, tmp_path):
    blocker = tmp_path / 'not_a_dir'
    blocker.write_text('')
    rig = start(ros_graph, tmp_path, frames_dir=str(blocker / 'frames'))
    rig.send_ball(1)
    rig.wait_positions(1)
    response = rig.call_save()
    assert not response.success
    assert 'cannot save' in response.message and 'not_a_dir' in response.message
    rig.send_ball(2)
    rig.wait_positions(2)


def test_save_every_n_saves_every_nth_frame(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path, save_every_n=2)
    for sec in range(1, 6):
        rig.send_ball(sec)
        rig.wait_positions(sec)
    frames = tmp_path / 'frames'
    expected = [(sec, kind) for sec in (2, 4) for kind in ('color', 'depth')]

    def saved_frames():
        names = os.listdir(frames) if frames.is_dir() else []
        return sorted((sec, match.group(1)) for name in names for sec in range(1, 6)
                      if (match := saved_name(sec).fullmatch(name)))

    wait_for(lambda: saved_frames() == expected, TIMEOUT, f'frames {expected} in {frames}')
    assert len(os.listdir(frames)) == 4  # nothing else


def test_save_every_n_without_depth_saves_the_colour_alone(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path, save_every_n=1)
    rgb = ball_frame()[0]
    for sec in range(1, 8):  # a few frames wait for their depth, then give up on it
        rig.send(sec, rgb)
        rig.wait_images(sec)
    frames = tmp_path / 'frames'
    wait_for(lambda: frames.is_dir() and any(saved_name(1).fullmatch(name)
                                             for name in os.listdir(frames)),
             TIMEOUT, 'the first colour frame saved alone')
    assert not [name for name in os.listdir(frames) if 'depth' in name]


def test_a_second_run_keeps_the_first_runs_frames(ros_graph, tmp_path):
    """Simulation time restarts at 0: a second graph saving to the same directory adds files."""
    frames = tmp_path / 'frames'

    def saved_files() -> list[str]:  # not the hidden temporary files of a save in progress
        names = os.listdir(frames) if frames.is_dir() else []
        return sorted(name for name in names if not name.startswith('.'))

    first = start(ros_graph, tmp_path, save_every_n=1)
    first.send_ball(1)
    wait_for(lambda: len(saved_files()) == 2, TIMEOUT, "the first run's frame")
    before = {name: (frames / name).read_bytes() for name in saved_files()}
    second = start(ros_graph, tmp_path, namespace='second_run', save_every_n=1)
    second.send_ball(1)
    wait_for(lambda: len(saved_files()) == 4, TIMEOUT, "the second run's frame")
    assert {name: (frames / name).read_bytes() for name in before} == before
    assert second.call_save().success
    assert len(saved_files()) == 6


def test_start_up_log_names_the_absolute_frames_dir(ros_graph, tmp_path):
    """frames_dir is relative to where the node was started: the log says where that is."""
    vision = subprocess.Popen([str(Path(sys.executable).with_name('vision'))], cwd=tmp_path,
                              env=ros_graph.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        output = b''
        deadline = time.monotonic() + 30.0
        while not re.search(rb'frames are saved to .*\n', output):
            assert time.monotonic() < deadline, f'no start-up line: {output!r}'
            if select.select([vision.stdout], [], [], 0.2)[0]:
                chunk = os.read(vision.stdout.fileno(), 4096)
                assert chunk, f'vision exited: {output!r}'
                output += chunk
    finally:
        vision.send_signal(signal.SIGINT)
        rest, _ = vision.communicate(timeout=15)
    line = re.search(r'frames are saved to (\S+)', output.decode()).group(1)
    assert re.sub(r'\x1b\[[0-9;]*m', '', line) == str(tmp_path / 'frames')
    assert vision.returncode == 0, (output + rest).decode()


@pytest.mark.parametrize('bad', [
    'colour_encoding', 'colour_truncated', 'depth_encoding', 'depth_size', 'info_k',
    'info_size'])
def test_bad_input_is_dropped_and_node_keeps_running(ros_graph, tmp_path, bad):
    rig = start(ros_graph, tmp_path)
    rgb, depth, _ = ball_frame()
    if bad == 'colour_encoding':
        rig.color.publish(Image(header=header(1), height=2, width=2, encoding='mono16',
                                step=4, data=bytes(8)))
    elif bad == 'colour_truncated':
        rig.color.publish(Image(header=header(1), height=HEIGHT, width=WIDTH, encoding='rgb8',
                                step=WIDTH * 3, data=bytes(100)))
    elif bad == 'depth_encoding':
        rig.send(1, rgb, info=True)
        rig.depth.publish(Image(header=header(1), height=HEIGHT, width=WIDTH, encoding='8UC1',
                                step=WIDTH, data=bytes(WIDTH * HEIGHT)))
    elif bad == 'depth_size':
        rig.send(1, rgb, depth[:240, :320].copy())
    elif bad == 'info_k':
        rig.info.publish(info_msg(1, k=np.zeros(9)))
        rig.send(1, rgb, depth, info=False)
    elif bad == 'info_size':
        rig.info.publish(info_msg(1, width=320, height=240))
        rig.send(1, rgb, depth, info=False)
    rig.send_ball(2)
    wait_for(lambda: 2 in [p.header.stamp.sec for p in rig.positions], TIMEOUT,
             'the position of the good frame')
    if not bad.startswith('info'):  # a frame with bad intrinsics may use the next good ones
        assert [p.header.stamp.sec for p in rig.positions] == [2]


def test_parameters_are_validated_and_applied(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path)
    vision = rig.vision
    for name, value in [('hsv_lower', [1, 2]), ('hsv_upper', [10, 255, 300]),
                        ('save_every_n', -1), ('min_radius_px', 0.0), ('ball_radius', -0.1)]:
        (result,) = vision.set_parameters([Parameter(name, value=value)])
        assert not result.successful, name
        assert result.reason
    assert list(vision.get_parameter('hsv_lower').value) == [170, 100, 40]
    # Look for green balls instead: the red one is no longer a ball.
    results = vision.set_parameters([Parameter('hsv_lower', value=[50, 100, 40]),
                                     Parameter('hsv_upper', value=[70, 255, 255])])
    assert all(r.successful for r in results)
    rig.send_ball(1)
    rig.wait_images(1)
    vision.set_parameters([Parameter('hsv_lower', value=[170, 100, 40]),
                           Parameter('hsv_upper', value=[10, 255, 255])])
    rig.send_ball(2)
    rig.wait_positions(1)
    assert [p.header.stamp.sec for p in rig.positions] == [2]


def test_works_in_a_namespace(ros_graph, tmp_path):
    rig = start(ros_graph, tmp_path, namespace='robot1')
    assert rig.color.topic_name == '/robot1/camera/color/image_raw'
    rig.send_ball(1)
    rig.wait_positions(1)
    assert rig.call_save().success
