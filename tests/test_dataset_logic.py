"""The data set's logic without ROS: sphere boxes, placements, split, files, progress."""

import io
import math

import numpy as np
import pytest
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_vision.dataset import (
    DatasetWriter,
    Progress,
    hidden_fraction,
    is_val,
    label_text,
    yolo_label,
)
from ur_rg2_vision.placement import REACH, Camera, PlacementError, plan_placement
from ur_rg2_vision.sphere import sphere_box

K = np.array([[589.0, 0.0, 320.0], [0.0, 589.0, 239.0], [0.0, 0.0, 1.0]])
DEFAULT_CAMERA = Camera((1.3, -1.1, 0.95), (0.3, -0.1, 0.1), K, 640, 480)


def brute_force_box(center, radius, k, points=400_000, seed=0):
    """Return the box of the projections of many points on the sphere's surface."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(points, 3))
    surface = np.asarray(center) + radius * directions / np.linalg.norm(directions, axis=1,
                                                                          keepdims=True)
    u = k[0, 0] * surface[:, 0] / surface[:, 2] + k[0, 2]
    v = k[1, 1] * surface[:, 1] / surface[:, 2] + k[1, 2]
    return u.min(), v.min(), u.max(), v.max()


@pytest.mark.parametrize('center, radius', [
    ((0.0, 0.0, 1.0), 0.03),  # on the axis: a circle
    ((0.4, -0.3, 0.8), 0.05),  # off the axis: an ellipse, wider than the centre's circle
    ((-0.9, 0.7, 0.6), 0.08),  # far off, near: strongly elongated
    ((0.05, 0.6, 2.0), 0.015),
])
def test_sphere_box_is_the_box_of_the_projected_surface(center, radius):
    box = sphere_box(center, radius, K)
    expected = brute_force_box(center, radius, K)
    # Random surface points reach the outline from inside: within a small fraction of a pixel.
    assert np.all(np.abs(np.subtract(box, expected)) < 0.05), (box, expected)


def test_off_axis_box_is_not_the_projected_circle():
    center, radius = np.array([-0.9, 0.7, 0.6]), 0.08
    naive_half_width = K[0, 0] * radius / np.linalg.norm(center)
    u0, _, u1, _ = sphere_box(center, radius, K)
    assert (u1 - u0) / 2 > 1.2 * naive_half_width


def test_sphere_box_none_when_the_sphere_reaches_behind_the_camera():
    assert sphere_box((0.0, 0.0, 0.02), 0.03, K) is None
    assert sphere_box((0.0, 0.0, -1.0), 0.03, K) is None


def test_yolo_label_normalises_and_clips_to_the_image():
    # Pixel i covers [i, i + 1] in YOLO's coordinates: a box from pixel 9.5 to 29.5 (ROS).
    cx, cy, w, h = yolo_label((9.5, 19.5, 29.5, 59.5), 640, 480)
    assert (cx * 640, cy * 480, w * 640, h * 480) == pytest.approx((20.0, 40.0, 20.0, 40.0))
    cx, cy, w, h = yolo_label((-20.5, 470.5, 9.5, 500.0), 640, 480)
    assert (cx * 640 - w * 320, cy * 480 + h * 240) == pytest.approx((0.0, 480.0))
    assert w * 640 == pytest.approx(10.0)
    assert yolo_label((-30.0, 10.0, -0.6, 20.0), 640, 480) is None
    assert yolo_label((650.0, 10.0, 700.0, 20.0), 640, 480) is None
    assert yolo_label(None, 640, 480) is None
    assert label_text(None) == ''
    assert label_text((0.5, 0.25, 0.1, 0.2)) == '0 0.500000 0.250000 0.100000 0.200000\n'


def test_hidden_fraction_from_depth():
    center, radius = np.array([0.0, 0.0, 1.0]), 0.05
    height, width = 480, 640
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1)
    a, b = np.einsum('...i,...i', rays, rays), rays @ center
    disc = b * b - a * (center @ center - radius ** 2)
    ball = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
    depth = np.minimum(ball, 3.0).astype(np.float32)  # a wall 3 m away behind the ball
    assert hidden_fraction(center, radius, K, depth) == (0.0, 0.0)
    covered = depth.copy()
    covered[:, :320] = 0.5  # something 0.5 m away hides the ball's left half
    hidden, missing = hidden_fraction(center, radius, K, covered)
    assert hidden == pytest.approx(0.5, abs=0.05) and missing == 0.0
    hidden, missing = hidden_fraction(center, radius, K, np.full_like(depth, np.inf))
    assert hidden == 0.0 and missing == 1.0


def test_split_is_even_and_continues_across_runs():
    flags = [is_val(i, 0.2) for i in range(1000)]
    assert sum(flags) == 200
    assert sum(flags[:10]) == 2 and sum(flags[10:20]) == 2
    assert not any(is_val(i, 0.0) for i in range(100))
    assert all(is_val(i, 1.0) for i in range(100))


def plan(index, attempt=0, seed=7, **options):
    settings = dict(camera=DEFAULT_CAMERA, radius=0.03, reach=REACH['ur5'],
                    out_of_view_fraction=0.2, jitter_camera=False, jitter_color=False)
    settings.update(options)
    return plan_placement(seed, index, attempt, **settings)


def test_placements_are_seeded_in_reach_and_in_or_out_of_view():
    placements = [plan(i) for i in range(200)]
    assert placements == [plan(i) for i in range(200)]
    assert placements != [plan(i, seed=8) for i in range(200)]
    assert plan(3) != plan(3, attempt=1)
    out = [p for p in placements if not p.in_view]
    assert 20 <= len(out) <= 60
    for p in placements:
        x, y, z = p.ball
        assert z == 0.03
        assert 0.3 <= math.hypot(x, y) <= 0.9 or not p.in_view
        center = DEFAULT_CAMERA.to_optical(p.ball)
        label = yolo_label(sphere_box(center, 0.03, K), 640, 480) if center[2] > 0.03 else None
        assert (label is not None) == p.in_view
        assert p.camera is None and p.color is None


def test_jitter_moves_the_camera_and_paints_the_ball():
    placements = [plan(i, jitter_camera=True, jitter_color=True) for i in range(50)]
    for p in placements:
        position, look_at = p.camera
        assert np.all(np.abs(np.subtract(position, DEFAULT_CAMERA.position)) <= 0.15 + 1e-9)
        assert position[2] >= 0.3 and look_at[2] == DEFAULT_CAMERA.look_at[2]
        assert all(0 <= c <= 1 for c in p.color) and p.color[3] == 1.0
        if p.in_view:
            moved = Camera(position, look_at, K, 640, 480)
            rotation = optical_rotation(position, look_at)
            center = rotation.T @ (np.asarray(p.ball) - position)
            assert np.allclose(center, moved.to_optical(p.ball))
            assert yolo_label(sphere_box(center, 0.03, K), 640, 480) is not None
    assert len({p.color for p in placements}) == 50


def test_any_camera_looks_at_the_reach_from_any_side():
    placements = [plan(i, any_camera=True) for i in range(100)]
    assert placements == [plan(i, any_camera=True) for i in range(100)]
    bearings = []
    for p in placements:
        position, look_at = p.camera
        assert math.hypot(*position[:2]) >= 0.7  # clear of the arm
        assert look_at[2] == 0.0 and 0.3 <= math.hypot(*look_at[:2]) <= 0.9
        offset = np.subtract(position, look_at)
        assert 0.6 - 1e-9 <= np.linalg.norm(offset) <= 2.2 + 1e-9
        down = math.degrees(math.asin(offset[2] / np.linalg.norm(offset)))
        assert 25 - 1e-6 <= down <= 65 + 1e-6
        bearings.append(math.atan2(offset[1], offset[0]))
        center = Camera(position, look_at, K, 640, 480).to_optical(p.ball)
        label = yolo_label(sphere_box(center, 0.03, K), 640, 480) if center[2] > 0.03 else None
        assert (label is not None) == p.in_view
    # From every side: each quadrant of bearings holds some poses.
    assert len({int((b + math.pi) // (math.pi / 2)) for b in bearings}) == 4


def test_out_of_view_behind_the_camera_when_it_sees_all_the_reach():
    above = Camera((0.0, -3.0, 4.0), (0.0, 0.0, 0.0), K, 640, 480)
    p = plan(0, camera=above, out_of_view_fraction=1.0, tries=50)
    center = above.to_optical(p.ball)
    assert not p.in_view and (center[2] <= 0.03 or yolo_label(
        sphere_box(center, 0.03, K), 640, 480) is None)


def test_a_camera_that_sees_no_floor_in_reach_is_an_error():
    sky = Camera((0.0, 0.0, 1.0), (0.0, 0.5, 3.0), K, 640, 480)
    with pytest.raises(PlacementError, match='is the camera looking at the workspace'):
        plan(0, camera=sky, out_of_view_fraction=0.0, tries=200)


def test_writer_appends_with_new_names_and_continues_the_split(tmp_path):
    rgb = np.zeros((4, 6, 3), np.uint8)
    writer = DatasetWriter(tmp_path, 0.5)
    paths = [writer.write(rgb, (0.5, 0.5, 0.1, 0.1)) for _ in range(3)]
    assert [p.relative_to(tmp_path).as_posix() for p in paths] == [
        'images/train/000000.png', 'images/val/000001.png', 'images/train/000002.png']
    assert (tmp_path / 'labels/val/000001.txt').read_text().startswith('0 0.5')
    # Left by a run killed between a label and its image: removed, its name not reused.
    (tmp_path / 'labels/val/000003.txt').write_text('0 0.1 0.1 0.1 0.1\n')
    again = DatasetWriter(tmp_path, 0.5)
    assert again.removed_orphans == 1 and again.count() == 3
    assert again.write(rgb, None).name == '000003.png'
    assert (tmp_path / 'labels/val/000003.txt').read_text() == ''
    assert (tmp_path / 'data.yaml').read_text() == (
        f'path: {tmp_path}\ntrain: images/train\nval: images/val\nnames: {{0: ball}}\n')
    assert not [p for p in tmp_path.rglob('.*')]


def test_writer_refuses_a_data_set_of_other_classes(tmp_path):
    (tmp_path / 'data.yaml').write_text('path: x\ntrain: a\nval: b\nnames: {0: cat, 1: dog}\n')
    with pytest.raises(ValueError, match='not a data set of the class 0: ball'):
        DatasetWriter(tmp_path, 0.2)


def test_progress_lines_without_a_terminal():
    now = [0.0]
    stream = io.StringIO()
    progress = Progress(5, stream, every=2, tty=False, clock=lambda: now[0])
    for _ in range(5):
        now[0] += 0.5
        progress.advance()
    assert stream.getvalue().splitlines() == [
        '2/5  40% 2.00 samples/s ETA 0:00:02', '4/5  80% 2.00 samples/s ETA 0:00:00',
        '5/5 100% 2.00 samples/s ETA 0:00:00']


def test_progress_bar_on_a_terminal():
    stream = io.StringIO()
    progress = Progress(4, stream, tty=True, clock=lambda: 1.0)
    progress.advance()
    assert stream.getvalue().startswith('\r[########----------------------] 1/4  25%')
    progress.close()
    assert stream.getvalue().endswith('\n')


def test_distractors_stand_in_view_clear_of_the_ball_and_parse_for_the_sim():
    from ur_rg2_common.scene_objects import SceneObject

    kinds, in_ball_colour = set(), 0
    for index in range(30):
        placement = plan_placement(7, index, 0, DEFAULT_CAMERA, 0.03, REACH['ur5'], 0.0,
                                   False, False, distractors=4, jitter_scene=True)
        objects = SceneObject.parse(placement.objects)
        assert len(objects) <= 4
        for item in objects:
            kinds.add(item.shape if item.shape == 'disc' or item.size[2] == item.size[0]
                      else 'flat box')
            in_ball_colour += item.color == (1.0, 0.0, 0.0)
            assert math.hypot(item.x - placement.ball[0], item.y - placement.ball[1]) > 0.03
            u, v, _ = K @ DEFAULT_CAMERA.to_optical((item.x, item.y, 0.0))
            assert 0 <= u / _ <= 640 and 0 <= v / _ <= 480
        assert len(placement.floor) == 3 and math.isclose(np.linalg.norm(placement.light), 1)
        assert placement.light[2] > 0
    assert kinds == {'box', 'flat box', 'disc'} and in_ball_colour > 0
    # Without the options the placements are the ones they always were.
    plain = plan_placement(7, 3, 0, DEFAULT_CAMERA, 0.03, REACH['ur5'], 0.0, False, False)
    assert plain.objects is None and plain.floor is None
    assert plain.ball == plan_placement(7, 3, 0, DEFAULT_CAMERA, 0.03, REACH['ur5'], 0.0, False,
                                        False, distractors=4).ball


def test_scene_objects_text_round_trips_and_bad_text_is_refused():
    from ur_rg2_common.scene_objects import SceneObject

    objects = SceneObject.parse('box 0.5 -0.5 0.3 0.03 0.02 0.01 1 0 0; disc 1 1 0 0.05 0.05 '
                                '0.002 0 0 1;')
    assert [o.shape for o in objects] == ['box', 'disc']
    assert SceneObject.parse('; '.join(o.text() for o in objects)) == objects
    assert SceneObject.parse('') == []
    for bad in ('ball 0 0 0 0.1 0.1 0.1 1 0 0', 'box 0 0 0 0.1 0.1', 'box 0 0 0 2 1 1 1 0 0',
                'box 0 0 nan 0.1 0.1 0.1 1 0 0'):
        with pytest.raises(ValueError, match=r'scene_objects\[0\]'):
            SceneObject.parse(bad)
