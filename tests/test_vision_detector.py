"""Ball detection (2D) and localisation (3D) on synthetic frames with exact ground truth.

The 3D tests measure the ball's radius (the node's default) unless they say otherwise.
"""

import math

import numpy as np
import pytest
from test_vision_scenes import CX, CY, FX, FY, WIDTH, Box, K, Scene, Sphere, project, render
from ur_rg2_vision.detector import RED, BallDetector, HsvRange
from ur_rg2_vision.localize import locate_ball

GREY = (0.6, 0.6, 0.62)
BASE = Scene()


def expected_radius(centre, radius=0.03) -> float:
    distance = float(np.linalg.norm(centre))
    return FX * math.tan(math.asin(radius / distance))


def visible_ball(name):
    """Return (scene, ball centre) for a named scene in which the red ball can be seen."""
    ball = BASE.on_floor(0.1, 1.2, 0.03)
    if name == 'plain':
        return Scene(spheres=[Sphere(ball)]), ball
    if name == 'left_near':
        ball = BASE.on_floor(-0.3, 0.75, 0.03)
        return Scene(spheres=[Sphere(ball)]), ball
    if name == 'small_far':  # about 8 px radius
        ball = BASE.on_floor(0.2, 2.05, 0.03)
        return Scene(spheres=[Sphere(ball)]), ball
    if name == 'large_near':  # about 60 px radius, e.g. held up in front of the camera
        ball = (0.05, 0.04, 0.3)
        return Scene(spheres=[Sphere(ball)]), ball
    if name == 'finger_in_front':  # a thin post splits the ball in two
        post = Box(BASE.on_floor(0.1, 1.0, 0.1), (0.006, 0.006, 0.1), GREY)
        return Scene(spheres=[Sphere(ball)], boxes=[post]), ball
    if name == 'half_hidden':  # a wide link covers the ball's left half
        link = Box(BASE.on_floor(0.035, 1.0, 0.1), (0.05, 0.01, 0.1), GREY)
        return Scene(spheres=[Sphere(ball)], boxes=[link]), ball
    if name == 'image_border':  # centre 4 px inside the left edge: half the ball is cut off
        ball = ((4 - (WIDTH - 1) / 2) * 1.2 / FX, 0.1, 1.2)
        return Scene(spheres=[Sphere(ball)]), ball
    if name == 'dim':
        return Scene(spheres=[Sphere(ball)], exposure=0.35), ball
    if name == 'bright':
        return Scene(spheres=[Sphere(ball)], exposure=1.5, ambient=0.8), ball
    if name == 'side_light':  # dark shaded half
        return Scene(spheres=[Sphere(ball)], light=(1.0, 0.0, 0.0), ambient=0.25), ball
    if name.startswith('floor_'):
        colors = {'floor_green': (0.2, 0.55, 0.2), 'floor_blue': (0.15, 0.2, 0.6),
                  'floor_black': (0.05, 0.05, 0.05), 'floor_white': (0.95, 0.95, 0.95),
                  'floor_brown': (0.5, 0.33, 0.18), 'floor_orange': (0.85, 0.5, 0.15)}
        color = np.array(colors[name])
        return Scene(spheres=[Sphere(ball)], floor_colors=(color, 0.8 * color)), ball
    if name == 'clutter':  # a green and a blue ball and a red cube around the red ball
        others = [Sphere(BASE.on_floor(-0.05, 1.2, 0.03), color=(0.0, 0.7, 0.0)),
                  Sphere(BASE.on_floor(0.25, 1.3, 0.03), color=(0.1, 0.2, 0.8))]
        cube = Box(BASE.on_floor(0.2, 1.05, 0.03), (0.03, 0.03, 0.03), yaw=0.4)
        return Scene(spheres=[Sphere(ball), *others], boxes=[cube]), ball
    raise KeyError(name)


VISIBLE = ['plain', 'left_near', 'small_far', 'large_near', 'finger_in_front', 'half_hidden',
           'image_border', 'dim', 'bright', 'side_light', 'floor_green', 'floor_blue',
           'floor_black', 'floor_white', 'floor_brown', 'floor_orange', 'clutter']


@pytest.mark.parametrize('name', VISIBLE)
def test_finds_the_ball(name):
    scene, ball = visible_ball(name)
    rgb, depth = render(scene)
    detections = BallDetector().detect(rgb, K)
    assert len(detections) == 1, f'{len(detections)} balls found'
    found = detections[0]
    u, v = project(ball)
    assert math.hypot(found.u - u, found.v - v) < 0.5
    assert found.radius == pytest.approx(expected_radius(ball), rel=0.05)
    position = locate_ball(found, depth, K)
    assert position is not None
    error = np.linalg.norm(np.array([position.x, position.y, position.z]) - ball)
    assert error < 0.002, f'3D error {error * 1000:.1f} mm'
    assert position.radius == pytest.approx(0.03, abs=0.001)


@pytest.mark.parametrize('name', ['plain', 'small_far', 'large_near', 'half_hidden', 'clutter'])
def test_a_given_radius_is_assumed(name):
    scene, ball = visible_ball(name)
    rgb, depth = render(scene)
    (found,) = BallDetector().detect(rgb, K)
    position = locate_ball(found, depth, K, 0.03)
    error = np.linalg.norm(np.array([position.x, position.y, position.z]) - ball)
    assert error < 0.002 and position.radius == 0.03


def ball_at(u: float, v: float, distance: float) -> tuple[float, float, float]:
    """Return the optical point ``distance`` m from the camera seen at pixel (u, v)."""
    ray = np.array([(u - CX) / FX, (v - CY) / FY, 1.0])
    return tuple(distance * ray / np.linalg.norm(ray))


@pytest.mark.parametrize('radius', [0.015, 0.022, 0.03, 0.05, 0.08])
@pytest.mark.parametrize('distance', [0.5, 1.0, 1.5, 2.0])
def test_balls_of_any_size_are_found_and_measured(radius, distance):
    for u, v in [(320, 250), (150, 120), (520, 380)]:  # on the axis, and off it
        ball = ball_at(u, v, distance)
        # Looking almost level: the floor is farther than 2.5 m wherever it is seen.
        rgb, depth = render(Scene(spheres=[Sphere(ball, radius)], pitch=np.radians(10.0)))
        (found,) = BallDetector().detect(rgb, K)
        position = locate_ball(found, depth, K)
        assert position is not None, (u, v)
        error = np.linalg.norm(np.array([position.x, position.y, position.z]) - ball)
        assert error < 0.001, f'3D error {error * 1000:.2f} mm at {(u, v)}'
        assert position.radius == pytest.approx(radius, abs=0.001), (u, v)


@pytest.mark.parametrize('name', ['plain', 'small_far', 'finger_in_front'])
def test_without_camera_matrix_a_ball_near_the_axis_is_found(name):
    scene, ball = visible_ball(name)
    rgb, _ = render(scene)
    (found,) = BallDetector().detect(rgb)
    u, v = project(ball)
    assert math.hypot(found.u - u, found.v - v) < 1.0


def test_sizes_span_small_far_to_large_near():
    assert 7 < expected_radius(visible_ball('small_far')[1]) < 9
    assert 55 < expected_radius(visible_ball('large_near')[1]) < 65


def test_occluded_ball_reports_partial_coverage():
    rgb, _ = render(visible_ball('half_hidden')[0])
    assert BallDetector().detect(rgb, K)[0].coverage < 0.8


def no_ball(name):
    """Return a scene without a ball of the configured colour."""
    near = BASE.on_floor(0.0, 0.9, 0.03)
    if name == 'empty':
        return Scene()
    if name.startswith('cube'):
        _, half, yaw = name.split('_')
        half = float(half) / 100
        return Scene(boxes=[Box(BASE.on_floor(0.0, 0.9, half), (half,) * 3, yaw=float(yaw))])
    if name == 'long_box':
        return Scene(boxes=[Box(BASE.on_floor(0.0, 0.9, 0.03), (0.1, 0.03, 0.03), yaw=0.3)])
    colors = {'green_ball': (0.0, 0.7, 0.0), 'blue_ball': (0.1, 0.2, 0.8),
              'yellow_ball': (0.9, 0.85, 0.0), 'orange_ball': (1.0, 0.5, 0.0),
              'magenta_ball': (0.9, 0.0, 0.9)}
    return Scene(spheres=[Sphere(near, color=colors[name])])


NO_BALL = ['empty', 'cube_3_0', 'cube_3_0.5', 'cube_3_0.8', 'cube_4_0.2', 'cube_5_0.7',
           'long_box', 'green_ball', 'blue_ball', 'yellow_ball', 'orange_ball', 'magenta_ball']


@pytest.mark.parametrize('name', NO_BALL)
def test_finds_nothing_without_a_red_ball(name):
    rgb, _ = render(no_ball(name))
    assert BallDetector().detect(rgb, K) == []


def test_other_colour_range_finds_the_green_ball():
    rgb, _ = render(visible_ball('clutter')[0])
    green = HsvRange((50, 100, 40), (70, 255, 255))
    (found,) = BallDetector(green).detect(rgb, K)
    u, v = project(BASE.on_floor(-0.05, 1.2, 0.03))
    assert math.hypot(found.u - u, found.v - v) < 1.0


def test_min_radius_drops_small_balls():
    rgb, _ = render(visible_ball('small_far')[0])
    assert BallDetector(min_radius_px=12.0).detect(rgb, K) == []


def test_red_hue_wraps_around_zero():
    hsv_red = np.array([[[255, 0, 0], [255, 0, 40], [255, 40, 0], [0, 255, 0]]], np.uint8)
    assert RED.mask(hsv_red).ravel().tolist() == [255, 255, 255, 0]


@pytest.mark.parametrize('lower, upper', [
    ((0, 0), (10, 255, 255)), ((180, 0, 0), (10, 255, 255)), ((0, 300, 0), (10, 255, 255)),
    ((0, 200, 0), (10, 100, 255)), ((0, 0, 200), (10, 255, 100)),
])
def test_invalid_hsv_range_is_refused(lower, upper):
    with pytest.raises(ValueError):
        HsvRange(lower, upper)


def test_invalid_min_radius_is_refused():
    with pytest.raises(ValueError):
        BallDetector(min_radius_px=0.0)


@pytest.mark.parametrize('image', [
    np.zeros((48, 64), np.uint8), np.zeros((48, 64, 4), np.uint8), np.zeros((48, 64, 3))])
def test_wrong_image_type_is_refused(image):
    with pytest.raises(ValueError):
        BallDetector().detect(image)


def test_noise_image_gives_no_false_ball():
    rgb = np.random.default_rng(7).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    assert BallDetector().detect(rgb, K) == []


# -- 3D ------------------------------------------------------------------------------------

def test_depth_of_an_occluder_in_front_is_ignored():
    scene, ball = visible_ball('plain')
    rgb, depth = render(scene)
    (found,) = BallDetector().detect(rgb, K)
    # Occluder pixels in front that still look like the ball (e.g. misregistered depth).
    cols, rows = found.pixels()
    bad = np.random.default_rng(3).random(len(cols)) < 0.3
    depth[rows[bad], cols[bad]] = depth[rows[bad], cols[bad]] - 0.2
    position = locate_ball(found, depth, K)
    error = np.linalg.norm(np.array([position.x, position.y, position.z]) - ball)
    assert error < 0.002


def test_missing_depth_pixels_are_skipped():
    scene, ball = visible_ball('plain')
    rgb, depth = render(scene)
    (found,) = BallDetector().detect(rgb, K)
    cols, rows = found.pixels()
    holes = np.random.default_rng(4).random(len(cols)) < 0.5
    depth[rows[holes], cols[holes]] = np.where(np.arange(holes.sum()) % 2, np.nan, np.inf)
    position = locate_ball(found, depth, K)
    assert np.linalg.norm(np.array([position.x, position.y, position.z]) - ball) < 0.002


def test_no_depth_gives_no_position():
    rgb, depth = render(visible_ball('plain')[0])
    (found,) = BallDetector().detect(rgb, K)
    for radius in (0.0, 0.03):
        assert locate_ball(found, np.full_like(depth, np.nan), K, radius) is None
        assert locate_ball(found, np.zeros_like(depth), K, radius) is None


def test_wrong_ball_radius_gives_no_position():
    rgb, depth = render(visible_ball('plain')[0])
    (found,) = BallDetector().detect(rgb, K)
    assert locate_ball(found, depth, K, 0.06) is None
    assert locate_ball(found, depth, K, 0.015) is None


@pytest.mark.parametrize('ball_radius', [0.0, 0.03])
@pytest.mark.parametrize('half, distance', [(0.025, 1.6), (0.025, 2.2), (0.025, 2.8),
                                            (0.015, 1.5), (0.04, 2.8), (0.06, 3.5)])
def test_far_cube_that_looks_round_is_not_a_ball(half, distance, ball_radius):
    scene = Scene(boxes=[Box(BASE.on_floor(0.0, distance, half), (half,) * 3, yaw=0.7)])
    rgb, depth = render(scene)
    for detection in BallDetector().detect(rgb, K):  # 2D may take a far cube for a ball ...
        assert locate_ball(detection, depth, K, ball_radius) is None  # ... depth must not


@pytest.mark.parametrize('radius, distance', [(0.015, 1.0), (0.03, 0.6), (0.03, 1.5),
                                              (0.05, 2.0), (0.08, 1.0)])
def test_picture_of_a_ball_on_the_floor_is_not_a_ball(radius, distance):
    # A flat red patch with exactly a ball's outline and shading: only the depth tells.
    ball = BASE.on_floor(0.0, distance, radius)
    rgb, _ = render(Scene(spheres=[Sphere(ball, radius)]))
    _, flat = render(Scene())
    (detection,) = BallDetector().detect(rgb, K)
    assert locate_ball(detection, flat, K) is None
    assert locate_ball(detection, flat, K, radius) is None


@pytest.mark.parametrize('ball_radius', [0.0, 0.03])
def test_depth_that_shows_no_sphere_gives_no_position(ball_radius):
    rgb, depth = render(visible_ball('plain')[0])
    (found,) = BallDetector().detect(rgb, K)
    rng = np.random.default_rng(5)
    for bad in (np.full_like(depth, 1.2), rng.uniform(0.3, 3.0, depth.shape),
                np.full_like(depth, 1e-6), np.full_like(depth, 1e6)):
        assert locate_ball(found, bad.astype(np.float32), K, ball_radius) is None
