"""The ``dataset`` command's sampler and loop without ROS: a fake sim behind the driver's API.

The fake keeps the driver's record (:class:`ur_rg2_vision.dataset_run.SimRecord`: frames, true
poses, /tf_static and the looks at them) and answers ``set_parameters``, ``get_parameters`` and
``spin_until`` the way the sim does: after a change, the ball's true pose at the new place and
then frames whose depth shows the sphere there.
"""

import argparse

from builtin_interfaces.msg import Time
import cv2
from geometry_msgs.msg import PoseStamped, TransformStamped
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from ur_rg2_common.tf_buffer import quaternion_from_matrix
from ur_rg2_vision.dataset import yolo_label
from ur_rg2_vision.dataset_run import Sampler, SimError, SimRecord, parse_args, run
from ur_rg2_vision.placement import Camera
from ur_rg2_vision.ros_image import rgb_to_image
from ur_rg2_vision.sphere import sphere_box

WIDTH, HEIGHT = 160, 120
K = np.array([[147.3, 0.0, 80.0], [0.0, 147.3, 59.0], [0.0, 0.0, 1.0]])
POSITION, LOOK_AT = (1.3, -1.1, 0.95), (0.3, -0.1, 0.1)
RADIUS = 0.03


class FakeSim(SimRecord):
    """The sim as the driver sees it, one message of each kind per wait."""

    def __init__(self) -> None:
        super().__init__(timeout=1.0)
        self.params = {'robot_model': 'ur5', 'ball_radius': RADIUS,
                       'ball_position': [0.5, -0.3, RADIUS], 'ball_color': [1.0, 0.0, 0.0, 1.0],
                       'camera_position': list(POSITION), 'camera_look_at': list(LOOK_AT),
                       'scene_objects': '', 'floor_color': [0.7, 0.7, 0.7],
                       'light_direction': [0.4, -0.6, 1.0]}
        self.sets: list[dict] = []
        self.ticks = 0
        self._publish_static()

    def _stamp(self) -> Time:
        return Time(sec=self.ticks // 100, nanosec=self.ticks % 100 * 10_000_000)

    def _camera(self) -> Camera:
        return Camera(tuple(self.params['camera_position']),
                      tuple(self.params['camera_look_at']), K, WIDTH, HEIGHT)

    def _publish_static(self) -> None:
        camera = self._camera()
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = camera.rotation, camera.position
        t = TransformStamped()
        t.header = Header(frame_id='world', stamp=self._stamp())
        t.child_frame_id = 'camera_color_optical_frame'
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = (
            camera.position)
        q = t.transform.rotation
        q.x, q.y, q.z, q.w = quaternion_from_matrix(pose)
        self.add_static(t)

    def get_parameters(self, names):
        return {name: self.params.get(name) for name in names}  # None: not set, as a sim's

    def set_parameters(self, values: dict) -> None:
        self.sets.append(dict(values))
        self.params.update(values)
        if 'camera_position' in values:
            self.ticks += 1
            self._publish_static()

    def spin_until(self, predicate, what, timeout=None):
        for _ in range(40):
            if self.stop_signal is not None:
                raise SimError('stopped')
            value = predicate()
            if value:
                return value
            self._tick()
        raise SimError(f'timed out waiting for {what}')

    def _tick(self) -> None:
        """Publish the ball's true pose and a frame (colour, info, depth) of this moment."""
        self.ticks += 1
        stamp = self._stamp()
        ball = np.asarray(self.params['ball_position'], dtype=float)
        pose = PoseStamped(header=Header(frame_id='world', stamp=stamp))
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = ball
        self.poses.append(pose)
        header = Header(frame_id='camera_color_optical_frame', stamp=stamp)
        centre = self._camera().to_optical(ball)
        u, v = np.meshgrid(np.arange(WIDTH), np.arange(HEIGHT))
        rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1)
        a = np.einsum('...i,...i', rays, rays)
        b = rays @ centre
        disc = b * b - a * (centre @ centre - RADIUS ** 2)
        with np.errstate(invalid='ignore'):
            depth = np.where(disc > 0, (b - np.sqrt(disc)) / a, 3.0).astype(np.float32)
        self.colors.append(rgb_to_image(np.zeros((HEIGHT, WIDTH, 3), np.uint8), header))
        self.infos.append(CameraInfo(header=header, width=WIDTH, height=HEIGHT,
                                     k=K.ravel().tolist()))
        self.depths.append(Image(header=header, height=HEIGHT, width=WIDTH, encoding='32FC1',
                                 step=WIDTH * 4, data=depth.tobytes()))


def _args(tmp_path, *extra) -> argparse.Namespace:
    return parse_args(['--count', '4', '--out', str(tmp_path / 'set'), '--seed', '5',
                       '--out-of-view', '0.25', *extra])


def test_each_sample_is_labelled_with_the_box_of_the_ball_where_it_was_put(tmp_path):
    sim = FakeSim()
    sampler = Sampler(sim, _args(tmp_path))
    for index in range(6):
        rgb, depth, label = sampler.sample(index)
        assert rgb.shape == (HEIGHT, WIDTH, 3) and depth.shape == (HEIGHT, WIDTH)
        ball = sim.params['ball_position']
        assert sim.sets[-1]['ball_position'] == ball
        expected = yolo_label(sphere_box(sampler.camera.to_optical(ball), RADIUS, K), WIDTH,
                              HEIGHT)
        assert (label is None) == (expected is None)
        if label is not None:
            assert np.allclose(label, expected, atol=1e-9)


def test_random_cameras_and_colours_are_set_and_labelled_in_the_moved_camera(tmp_path):
    sim = FakeSim()
    sampler = Sampler(sim, _args(tmp_path, '--any-camera', '--jitter-color'))
    for index in range(4):
        *_, label = sampler.sample(index)
        moved = Camera(tuple(sim.params['camera_position']),
                       tuple(sim.params['camera_look_at']), K, WIDTH, HEIGHT)
        assert 'camera_position' in sim.sets[-1] and 'ball_color' in sim.sets[-1]
        expected = yolo_label(sphere_box(moved.to_optical(sim.params['ball_position']), RADIUS,
                                         K), WIDTH, HEIGHT)
        assert (label is None) == (expected is None)
        if label is not None:
            assert np.allclose(label, expected, atol=1e-6)
    sampler.restore()
    assert sim.params['camera_position'] == list(POSITION)


def test_run_writes_the_samples_and_puts_the_sim_back(tmp_path, capsys):
    sim = FakeSim()
    assert run(_args(tmp_path, '--distractors', '2'), sim) == 0
    images = sorted((tmp_path / 'set' / 'images').rglob('*.png'))
    labels = sorted((tmp_path / 'set' / 'labels').rglob('*.txt'))
    depths = sorted((tmp_path / 'set' / 'depth').rglob('*.png'))  # 16-bit mm, as scene_dataset
    assert len(images) == len(labels) == len(depths) == 4
    assert [p.relative_to(tmp_path / 'set' / 'depth') for p in depths] == [
        p.relative_to(tmp_path / 'set' / 'images') for p in images]
    millimetres = cv2.imread(str(depths[0]), cv2.IMREAD_UNCHANGED)
    assert millimetres.dtype == np.uint16 and millimetres.shape == (HEIGHT, WIDTH)
    assert 2900 <= np.median(millimetres) <= 3000  # the fake sim's wall, 3 m away
    assert sim.params['ball_position'] == [0.5, -0.3, RADIUS]
    assert sim.params['scene_objects'] == ''
    assert 'wrote 4 samples' in capsys.readouterr().err


def test_a_sim_that_never_shows_the_ball_is_a_clear_error(tmp_path, capsys):
    sim = FakeSim()
    sim.colors = type(sim.colors)(maxlen=0)  # frames never arrive
    assert run(_args(tmp_path), sim) == 1
    assert 'a camera frame' in capsys.readouterr().err


@pytest.mark.parametrize('option', ['--count=0', '--val-fraction=1.5', '--distractors=-1'])
def test_bad_options_are_refused(option):
    with pytest.raises(SystemExit):
        parse_args([option])
