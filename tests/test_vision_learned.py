"""The learned ball detector: train_detector -> evaluate_detector -> vision detector:=learned.

A short training run on a tiny data set (rendered detector scenes, written by
``scripts/detector-data``'s scene_dataset) exports a model that evaluate_detector reads back
and the vision node serves; the model
shipped with the package finds a blue ball in the sim's scene and calls neither a red cube nor
a flat red disc a ball; a missing or corrupt model directory stops the node at start-up with
one clear line. The hard-set numbers are the benchmark's (``python -m bench detector``).
"""

import json
import os
from pathlib import Path
import re
import subprocess
import sys

from conftest import start_sim, wait_for
from geometry_msgs.msg import PointStamped, PoseStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from test_vision_scenes import Box, K, Scene, Sphere, project, render
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import IMAGE_QOS
from ur_rg2_detector import scene_dataset
from ur_rg2_detector.labelled_scenes import detector_scenes, plain_to_the_eye
from ur_rg2_detector.scenes import hard_scenes
from ur_rg2_vision.dataset import yolo_label
from ur_rg2_vision.learned import (
    MODEL_FILE,
    SETTINGS_FILE,
    SHIPPED_MODEL,
    SINGLE_PASS_FILE,
    BallModel,
    ModelError,
    box_detection,
)
from ur_rg2_vision.learned_input import depth_relief
from ur_rg2_vision.localize import locate_ball
from ur_rg2_vision.placement import COLOR_GROUPS
from ur_rg2_vision.ros_image import rgb_to_image
from ur_rg2_vision.sphere import sphere_box
from ur_rg2_vision.vision_node import VisionNode

BIN = Path(sys.executable).parent
BASE = Scene()
TIMEOUT = 30.0  # the sim and the vision in one process on a loaded 2-core machine


def _listen(graph) -> tuple[list[PointStamped], list[Image]]:
    node = graph.node('ball_listener')
    positions, images = [], []
    node.create_subscription(PointStamped, 'ball/position', positions.append, 100)
    node.create_subscription(Image, 'ball/image', images.append, IMAGE_QOS)
    return positions, images


def _exact_box(centre, radius: float, k: np.ndarray) -> tuple[float, ...]:
    """Return the box (u0, v0, u1, v1, score) a perfect network gives a ball, amodal."""
    cx, cy, w, h = yolo_label(sphere_box(centre, radius, k), 640, 480)
    return (cx - w / 2) * 640, (cy - h / 2) * 480, (cx + w / 2) * 640, (cy + h / 2) * 480, 0.9


def test_a_box_around_a_ball_gives_its_centre_through_the_depth():
    """The geometry without the model: the exact box of each ball, off the axis too."""
    errors = []
    for shot in hard_scenes(16, seed=21, ball_share=1.0):
        if shot.centre is None or shot.visible < 0.9:
            continue
        box = _exact_box(shot.centre, shot.radius, shot.k)
        position = locate_ball(box_detection(box, 640, 480, shot.k), shot.depth, shot.k)
        assert position is not None, shot.name
        errors.append(np.linalg.norm([position.x, position.y, position.z] - shot.centre))
    assert len(errors) >= 8 and np.median(errors) < 0.003, errors


@pytest.mark.parametrize('edge', [0.06, 0.08, 0.085, 0.0875])
def test_a_ball_hidden_in_part_by_a_thing_in_front_gives_its_centre(edge):
    """A link in front of 0, 37, 48 and 54 % of the ball's disc: its depth is an occluder's."""
    ball = BASE.on_floor(0.1, 1.2, 0.03)
    link = Box(BASE.on_floor(edge - 0.05, 1.0, 0.1), (0.05, 0.01, 0.1), (0.6, 0.6, 0.62))
    _, depth = render(Scene(spheres=[Sphere(ball)], boxes=[link]))
    detection = box_detection(_exact_box(ball, 0.03, K), 640, 480, K)
    position = locate_ball(detection, depth, K)
    assert position is not None
    assert np.linalg.norm([position.x, position.y, position.z] - np.array(ball)) < 0.003


def test_a_box_whose_depth_shows_the_floor_through_half_the_ball_is_no_ball():
    """Half a ball's depth, the floor behind the rest: no occluder explains the rest."""
    ball = BASE.on_floor(0.1, 1.2, 0.03)
    _, depth = render(Scene(spheres=[Sphere(ball)]))
    _, floor = render(Scene())
    u = project(ball)[0]
    depth[:, :round(u) + 2] = floor[:, :round(u) + 2]  # a little more than the left half
    detection = box_detection(_exact_box(ball, 0.03, K), 640, 480, K)
    assert locate_ball(detection, depth, K) is None


def test_the_depth_relief_shows_a_ball_and_not_a_tilted_floor_or_holes():
    rows, cols = np.mgrid[0:480, 0:640].astype(np.float32)
    floor = 1.5 + 0.002 * rows - 0.0005 * cols  # a tilted plane, m
    ball = floor.copy()
    inside = (cols - 320) ** 2 + (rows - 240) ** 2 <= 16 ** 2  # a ball-sized bump
    ball[inside] -= 0.05  # 5 cm nearer than the floor around it
    holey = np.full((480, 640), 1.5, np.float32)
    holey[100:140, 100:140] = 0.0  # no return
    holey[300:310, 500:520] = np.inf
    holey[50:60, 400:410] = np.nan
    size = (240, 320)
    core = (slice(40, 200), slice(40, 280))  # 5 sigmas from the border
    assert np.abs(depth_relief(floor, size)[core]).max() < 0.01
    assert depth_relief(ball, size)[120, 160] < -0.5
    relief = depth_relief(holey, size)
    assert relief.dtype == np.float32 and np.isfinite(relief).all()
    assert np.abs(relief).max() < 0.01  # 0 in the holes, the floor around them flat
    wide = depth_relief(np.ones((360, 640), np.float32), size)  # letterboxed as the colour
    assert (wide[:30] == 0).all() and (wide[-30:] == 0).all()


@pytest.mark.parametrize('depth', [False, True], ids=['rgb', 'rgb+depth'])
def test_short_training_exports_a_model_evaluate_reads_and_vision_serves(tmp_path, ros_graph,
                                                                          depth):
    data, model = tmp_path / 'data', tmp_path / 'model'
    scene_dataset.main(['--count', '12', '--out', str(data), '--seed', '3',
                        '--val-fraction', '0.25'])
    depth_flag = ['--depth'] if depth else []
    trained = subprocess.run(
        [str(BIN / 'train_detector'), '--data', str(data), '--out', str(model), '--epochs', '2',
         '--imgsz', '160', '--crop', '96', '--batch', '4', *depth_flag],
        capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr[-3000:]
    assert re.search(r'train_detector: 2 epochs in [\d.]+ min \(load', trained.stdout)
    assert {MODEL_FILE, SETTINGS_FILE, 'training_curve.png', 'results.csv'} <= {
        p.name for p in model.iterdir()}
    loaded = BallModel(model)
    assert loaded.input_size == (120, 160)  # 4:3 frames
    settings = json.loads((model / SETTINGS_FILE).read_text())
    assert 'Apache-2.0' in settings['licence'] and 'ultralytics' not in json.dumps(settings)
    assert settings['inputs'] == (['rgb', 'depth_relief'] if depth else ['rgb'])
    # Hard negatives mined from a quarter of the training on: at the second of two epochs.
    assert [m['epoch'] for m in settings['training']['hard_negatives']['mined']] == [2]
    assert loaded.needs_depth == depth
    further = subprocess.run(  # --init: on from the model, which it records
        [str(BIN / 'train_detector'), '--data', str(data), '--out', str(tmp_path / 'further'),
         '--epochs', '1', '--imgsz', '160', '--crop', '96', '--batch', '4', *depth_flag,
         '--init', str(model)], capture_output=True, text=True, timeout=300)
    assert further.returncode == 0, further.stderr[-3000:]
    record = json.loads((tmp_path / 'further' / SETTINGS_FILE).read_text())['training']
    assert record['init']['training'] == settings['training'] and record['epochs'] == 1
    if depth:  # --epochs 0: the model exported again, here with the flip test
        again = subprocess.run(
            [str(BIN / 'train_detector'), '--data', str(data), '--out', str(tmp_path / 'again'),
             '--epochs', '0', '--imgsz', '160', '--crop', '96', '--depth', '--flip-test', '--init',
             str(model)],
            capture_output=True, text=True, timeout=300)
        assert again.returncode == 0, again.stderr[-3000:]
        exported = json.loads((tmp_path / 'again' / SETTINGS_FILE).read_text())
        assert exported['flip_test'] and exported['training']['epochs'] == 0
        assert exported['training']['frames'] == settings['training']['frames']
        assert exported['training']['init']['training'] == settings['training']
        assert exported['licence'] == settings['licence']  # no training of its own
        assert (tmp_path / 'again' / 'training_curve.png').read_bytes() == (
            model / 'training_curve.png').read_bytes()
        assert BallModel(tmp_path / 'again').needs_depth
        assert (tmp_path / 'again' / SINGLE_PASS_FILE).is_file()  # run first by the node
        assert not (model / SINGLE_PASS_FILE).exists()  # no flip test: one network
    evaluated = subprocess.run(
        [str(BIN / 'evaluate_detector'), '--model', str(model), '--data', str(data)],
        capture_output=True, text=True, timeout=120)
    assert evaluated.returncode == 0, evaluated.stderr
    line = r'recall [\d.]+ precision [\d.]+ mAP50 [\d.]+ over 3 images'
    lines = evaluated.stdout.splitlines()
    assert lines[0].startswith('network alone') and re.fullmatch(f'  all: {line}', lines[1])
    pipeline = lines.index(next(x for x in lines if x.startswith('node pipeline')))
    assert re.fullmatch(f'  all: {line}, \\d+ false balls, 3D error median .*',
                        lines[pipeline + 1]), lines
    assert re.fullmatch(f'  every labelled ball: {line}', lines[pipeline - 1]), lines
    groups = [x.split(':')[0].strip() for x in lines[2:pipeline - 1]]
    assert groups and set(groups) <= set(COLOR_GROUPS), lines
    swept = subprocess.run(
        [str(BIN / 'evaluate_detector'), '--model', str(model), '--data', str(data),
         '--thresholds', '0.2,0.4'], capture_output=True, text=True, timeout=120)
    assert swept.returncode == 0, swept.stderr
    assert [re.fullmatch(f'  0\\.[24]: {line} \\| {line}, \\d+ false balls, .*', x) is not None
            for x in swept.stdout.splitlines()[1:]] == [True, True], swept.stdout
    # The node runs it: every frame fed comes back annotated on ball/image.
    ros_graph.add(VisionNode(context=ros_graph.context, parameter_overrides=[
        Parameter('detector', value='learned'), Parameter('model_dir', value=str(model)),
        Parameter('frames_dir', value=str(tmp_path / 'frames'))]))
    _, images = _listen(ros_graph)
    feeder = ros_graph.node('feeder')
    publishers = [feeder.create_publisher(kind, topic, IMAGE_QOS) for kind, topic in (
        (CameraInfo, 'camera/color/camera_info'), (Image, 'camera/color/image_raw'),
        (Image, 'camera/depth/image_raw'))]
    shot = next(detector_scenes(1, seed=3)).shot
    header = Header(frame_id='camera_color_optical_frame')
    info = CameraInfo(header=header, width=640, height=480, k=shot.k.ravel().tolist())
    depth = Image(header=header, height=480, width=640, encoding='32FC1', step=640 * 4,
                  data=shot.depth.astype(np.float32).tobytes())

    # Every third frame with a depth image of another size, which the model cannot take (the
    # node says so and goes on), every third without one: it still comes back, once given up.
    small = Image(header=header, height=120, width=160, encoding='32FC1', step=160 * 4,
                  data=shot.depth[::4, ::4].astype(np.float32).tobytes())

    def fed_and_served() -> bool:
        header.stamp.sec += 1
        kind = header.stamp.sec % 3  # 0: its depth, 1: a bad one, 2: none
        fed = (info, rgb_to_image(shot.rgb, header), (depth, small)[kind] if kind < 2 else None)
        for publisher, msg in zip(publishers, fed):
            if msg is not None:
                msg.header = header
                publisher.publish(msg)
        kinds = [image.header.stamp.sec % 3 for image in images]  # each image has its stamp
        return 2 in kinds and 1 in kinds and 0 in kinds[kinds.index(1):]

    wait_for(fed_and_served, TIMEOUT, 'ball/image of a frame without depth, and of one after '
             'one with a bad depth image', interval=0.1)


def test_seeds_train_as_ray_tasks_and_write_their_validation_side_by_side(tmp_path):
    data, out = tmp_path / 'data', tmp_path / 'seeds'
    scene_dataset.main(['--count', '8', '--out', str(data), '--seed', '5',
                        '--val-fraction', '0.25'])
    trained = subprocess.run(
        [str(BIN / 'train_detector'), '--data', str(data), '--out', str(out), '--epochs', '1',
         '--imgsz', '128', '--crop', '64', '--batch', '4', '--seeds', '3', '4',
         '--num-cpus', '2'], capture_output=True, text=True, timeout=400)
    assert trained.returncode == 0, trained.stderr[-3000:]
    table = (out / 'seeds.md').read_text()
    assert table in trained.stdout
    assert f'train_detector: seed 4: written to {out / "seed_4"}' in trained.stdout
    rows = table.splitlines()
    assert rows[0].startswith('| seed | epochs (best) | minutes | threshold | validation')
    assert [row.split('|')[1].strip() for row in rows[2:]] == ['3', '4']
    weights = set()
    for seed in (3, 4):
        settings = json.loads((out / f'seed_{seed}' / SETTINGS_FILE).read_text())
        assert settings['training']['seed'] == seed and settings['training']['epochs'] == 1
        assert BallModel(out / f'seed_{seed}').input_size == (96, 128)
        weights.add((out / f'seed_{seed}' / MODEL_FILE).read_bytes())
    assert len(weights) == 2  # each seed trained its own network


def test_shipped_model_finds_a_blue_ball_and_no_red_cube_or_flat_disc(ros_graph, tmp_path):
    camera, look_at = [1.3, -1.1, 0.95], [0.3, -0.1, 0.1]
    ball = [0.55, -0.5, 0.03]
    sim = start_sim(ros_graph, ball_position=ball, ball_color=[0.0, 0.2, 1.0, 1.0],
              camera_position=camera, camera_look_at=look_at,
              scene_objects='box 0.75 -0.35 0.5 0.03 0.03 0.03 1 0 0; '
                            'disc 0.35 -0.75 0 0.04 0.04 0.003 1 0 0')
    ros_graph.add(VisionNode(context=ros_graph.context, parameter_overrides=[
        Parameter('detector', value='learned'),
        Parameter('frames_dir', value=str(tmp_path))]))
    positions, images = _listen(ros_graph)
    expected = optical_rotation(camera, look_at).T @ (np.array(ball) - camera)

    def error(msg: PointStamped) -> float:
        return float(np.linalg.norm([msg.point.x, msg.point.y, msg.point.z] - expected))

    wait_for(lambda: len([p for p in positions if error(p) < 0.01]) >= 3, TIMEOUT,
             'the blue ball at its place')
    assert all(error(p) < 0.01 for p in positions), [round(error(p), 3) for p in positions]
    # The ball out of view: the red cube and the red disc stay, and are no balls. Judged on
    # the frames taken after ball/true_pose shows the ball gone: under load the vision node
    # may still be working through frames from before.
    true_poses: list[PoseStamped] = []
    ros_graph.node('truth').create_subscription(PoseStamped, 'ball/true_pose',
                                                true_poses.append, 100)
    assert sim.set_parameters([Parameter('ball_position', value=[2.5, -3.0, 0.03])])[0].successful
    moved = wait_for(lambda: next((pose for pose in list(true_poses)
                                   if pose.pose.position.x > 2.0), None), TIMEOUT,
                     'ball/true_pose with the ball out of view')
    gone = (moved.header.stamp.sec, moved.header.stamp.nanosec)

    def after_the_move(msg) -> bool:
        return (msg.header.stamp.sec, msg.header.stamp.nanosec) >= gone

    wait_for(lambda: len([i for i in images if after_the_move(i)]) >= 30, TIMEOUT,
             '30 frames of ball/image without the ball')
    later = [p for p in positions if after_the_move(p)]
    assert not later, f'balls found without a ball in view: {[error(p) for p in later]}'


@pytest.mark.parametrize('breakage', ['missing', 'no settings', 'corrupt model'])
def test_a_missing_or_corrupt_model_dir_is_refused_at_start_up(tmp_path, breakage):
    model = tmp_path / 'model'
    if breakage != 'missing':
        model.mkdir()
        shipped = BallModel().directory
        (model / MODEL_FILE).write_bytes(b'not an onnx model' if breakage == 'corrupt model'
                                         else (shipped / MODEL_FILE).read_bytes())
        if breakage == 'corrupt model':
            (model / SETTINGS_FILE).write_text((shipped / SETTINGS_FILE).read_text())
    with pytest.raises(ModelError):
        BallModel(model)
    result = subprocess.run(
        [str(BIN / 'vision'), '--ros-args', '-p', 'detector:=learned', '-p',
         f'model_dir:={model}'], capture_output=True, text=True, timeout=60,
        env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST'))
    assert result.returncode == 1
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and 'cannot start' in lines[0] and str(model) in lines[0], lines


def test_the_exported_decoding_gives_back_the_box_of_the_training_targets():
    """targets() and Exported's decoding agree: a network that outputs its targets."""
    torch = pytest.importorskip('torch')
    from ur_rg2_detector.detector_net import STRIDE, Exported, targets
    boxes = [(40.0, 30.0, 72.0, 54.0), None]
    heat, regress, index = targets(boxes, 120, 160)

    class Targets(torch.nn.Module):
        def forward(self, images):
            out = torch.zeros(len(boxes), 5, 120 // STRIDE, 160 // STRIDE)
            out[:, 0] = torch.logit(torch.from_numpy(heat).clamp(1e-4, 1 - 1e-4))
            for i, cell in enumerate(index):
                if cell >= 0:
                    out[i, 1:5].view(4, -1)[:, cell] = torch.from_numpy(regress[i])
            return out

    rows = Exported(Targets())(torch.zeros(2, 3, 120, 160)).numpy()
    best = rows[0, :, rows[0, 4].argmax()]
    assert np.allclose(best[:4], (56.0, 42.0, 32.0, 24.0), atol=1e-3) and best[4] > 0.99
    assert rows[1, 4].max() < 0.01  # no ball: no peak over any threshold


def test_the_flip_test_sees_a_mirrored_frame_as_its_mirror_image():
    """Exported(flip=True): a mirrored frame's boxes are the frame's boxes mirrored, scores equal.

    Only when the mirrored maps are put back right (offsets from the cell's other side); a
    network alone, untrained, is not symmetric.
    """
    torch = pytest.importorskip('torch')
    from ur_rg2_detector.detector_net import BallNet, Exported
    torch.manual_seed(1)
    net = BallNet(in_channels=4).eval()
    with torch.no_grad():
        net.head[-1].weight.mul_(20)  # distinct peaks
        frame = torch.rand(1, 4, 96, 128)
        mirrored = torch.flip(frame, [3])
        rows, rows_mirrored = (Exported(net, flip=True)(x)[0].numpy() for x in (frame, mirrored))
        alone = Exported(net)(frame)[0].numpy(), Exported(net)(mirrored)[0].numpy()
    cells = rows[4].reshape(12, 16)
    assert (cells > 0).sum() >= 3  # peaks to compare
    assert np.allclose(rows_mirrored[4].reshape(12, 16)[:, ::-1], cells, atol=1e-6)
    peaks = cells.ravel() > 0
    cx = rows[0].reshape(12, 16)
    cx_mirrored = rows_mirrored[0].reshape(12, 16)[:, ::-1]
    assert np.allclose(128 - cx_mirrored.ravel()[peaks], cx.ravel()[peaks], atol=1e-3)
    assert np.allclose(rows_mirrored[2:4].reshape(2, 12, 16)[:, :, ::-1].reshape(2, -1)[:, peaks],
                       rows[2:4][:, peaks], atol=1e-4)
    assert not np.allclose(alone[1][4].reshape(12, 16)[:, ::-1], alone[0][4].reshape(12, 16),
                           atol=1e-3)


class _Network:
    """A stand-in for an ONNX Runtime session: gives set scores (one row each), counts runs."""

    def __init__(self, scores: list[float]) -> None:
        self.scores, self.runs = scores, 0

    def get_inputs(self):
        return [type('Input', (), {'name': 'images'})]

    def run(self, _outputs, _feeds):
        self.runs += 1
        rows = np.zeros((1, 5, 3072), np.float32)
        for i, score in enumerate(self.scores):
            rows[0, :, i] = (100 + 40 * i, 100, 30, 30, score)
        return [rows]


@pytest.mark.parametrize('single_pass, runs_flip_test', [
    ([0.9], False),  # sure of its one box: the mirror image's score cannot take it under 0.35
    ([0.9, 0.75], False),
    ([0.1], False),  # nothing the frame shows: no box the average could lift over 0.35
    ([], False),
    ([0.5], True),  # between: the flip test decides
    ([0.9, 0.3], True),
    ([0.2], True),
])
def test_the_shipped_model_runs_its_flip_test_only_where_it_can_change_the_answer(
        single_pass, runs_flip_test):
    """The frame alone first; its boxes stand when every one is sure, else the flip test's."""
    model = BallModel()  # the shipped model: the flip test, at 0.35, with its single pass
    assert model.confidence == 0.35 and json.loads(
        (SHIPPED_MODEL / SETTINGS_FILE).read_text())['flip_test']
    model._single_pass, model._session = _Network(single_pass), _Network([0.6])
    rgb = np.zeros((480, 640, 3), np.uint8)
    boxes = model.boxes(rgb, np.ones((480, 640), np.float32))
    assert model._single_pass.runs == 1 and model._session.runs == runs_flip_test
    expected = [0.6] if runs_flip_test else [s for s in single_pass if s >= 0.35]
    assert sorted(box[4] for box in boxes) == pytest.approx(sorted(expected))


def test_an_exported_model_loads_back_to_train_further(tmp_path):
    """train_detector --init: the network loaded from model.onnx computes what the file does."""
    torch = pytest.importorskip('torch')
    ort = pytest.importorskip('onnxruntime')
    from ur_rg2_detector.detector_net import BallNet, Exported, load_exported
    torch.manual_seed(0)
    trained = BallNet()
    with torch.no_grad():  # batch norms with statistics and scales of their own
        for norm in (m for m in trained.modules() if isinstance(m, torch.nn.BatchNorm2d)):
            norm.running_mean.uniform_(-0.5, 0.5)
            norm.running_var.uniform_(0.5, 2.0)
            norm.weight.uniform_(0.5, 1.5)
            norm.bias.uniform_(-0.2, 0.2)
        trained.head[-1].weight.mul_(20)  # distinct peaks: no ties for the max pool to flip
    trained.eval()
    path = tmp_path / MODEL_FILE
    torch.onnx.export(Exported(trained), (torch.zeros(1, 3, 96, 128),), str(path), dynamo=False,
                      opset_version=13, input_names=['images'], output_names=['output'])
    images = torch.rand(8, 3, 96, 128)
    loaded = BallNet()
    load_exported(loaded, str(path), images)
    loaded.eval()
    with torch.no_grad():
        ours = Exported(loaded)(images[:1]).numpy()
    theirs = ort.InferenceSession(str(path)).run(None, {'images': images[:1].numpy()})[0]
    assert np.allclose(ours, theirs, rtol=1e-4, atol=1e-4)
    assert (theirs[0, 4] > 0.01).sum() >= 3  # peaks to compare
    torch.onnx.export(torch.nn.Conv2d(3, 5, 3), (torch.zeros(1, 3, 96, 128),), str(path),
                      dynamo=False, opset_version=13)
    with pytest.raises(ValueError):  # not an export of this network
        load_exported(BallNet(), str(path), images)


def test_training_can_drop_the_balls_that_do_not_stand_out(tmp_path):
    """train_detector --min-contrast: a ball within V of its surroundings' value goes."""
    import cv2
    from ur_rg2_detector.crops import ball_contrast, plain_pairs
    pairs = []
    for name, value in (('faint', 0.53), ('plain', 0.8), ('none', None)):
        bgr = np.full((120, 160, 3), 0.5 * 255, np.uint8)
        label = tmp_path / f'{name}.txt'
        label.write_text('')
        if value is not None:
            cv2.circle(bgr, (80, 60), 15, (round(value * 255),) * 3, -1)
            label.write_text(f'0 0.5 0.5 {30 / 160} {30 / 120}\n')
            assert ball_contrast(bgr, (65, 45, 95, 75)) == pytest.approx(value - 0.5, abs=0.01)
        cv2.imwrite(str(tmp_path / f'{name}.png'), bgr)
        pairs.append((tmp_path / f'{name}.png', label))
    assert [image.stem for image, _ in plain_pairs(pairs, 0.05)] == ['plain', 'none']
    assert len(plain_pairs(pairs, 0.01)) == 3


def test_hard_negatives_are_the_peaks_off_the_ball_and_crops_centre_on_them():
    """train_detector --hard-negatives: the network's own false peaks are what it trains on."""
    torch = pytest.importorskip('torch')
    from ur_rg2_detector.crops import augment, hard_negatives
    from ur_rg2_detector.detector_net import STRIDE, BallNet
    net = BallNet()
    with torch.no_grad():  # the same score everywhere: every cell is a peak, at cx = col * 8
        net.head[-1].weight.zero_()
        net.head[-1].bias.copy_(torch.tensor([2.0, 0.0, 0.0, 1.0, 1.0]))
    images = np.zeros((2, 96, 128, 3), np.uint8)
    ball = (0.0, 0.0, 60.0, 40.0)
    found = hard_negatives(torch, net, images, None, [None, ball])
    cells = (96 // STRIDE) * (128 // STRIDE)
    assert len(found[0]) == cells  # no ball: every peak is false
    inside = (60 // STRIDE + 1) * (40 // STRIDE + 1)
    assert len(found[1]) == cells - inside
    assert not ((found[1][:, 0] <= 60) & (found[1][:, 1] <= 40)).any()
    assert net.training  # handed back to training
    rng = np.random.default_rng(0)
    hard = np.array([[100.0, 70.0]], np.float32)
    frame = np.zeros((96, 128, 3), np.uint8)
    frame[70, 100] = 255  # the hard negative's pixel
    for _ in range(20):
        crop, box = augment(rng, frame, ball, (32, 32), hard=hard, hard_share=1.0)
        assert crop.shape == (32, 32, 3) and box is None  # centred on it, not on the ball
        assert crop.max() > crop.min()  # its pixel is in the crop (however bright)


def test_a_ball_mostly_hidden_is_neither_missed_nor_falsely_found(tmp_path):
    """evaluate_detector: a ball under 40 % visible is difficult, as PASCAL VOC's."""
    import cv2
    from ur_rg2_detector.evaluate_detector import Scores, evaluate
    for kind in ('images', 'labels', 'meta'):
        (tmp_path / kind / 'val').mkdir(parents=True)
    pairs, boxes = [], {}
    for name, visible, found in (('seen', 1.0, True), ('hidden', 0.2, True),
                                 ('missed', 0.2, False)):
        image = tmp_path / 'images' / 'val' / f'{name}.png'
        cv2.imwrite(str(image), np.zeros((48, 64, 3), np.uint8))
        label = tmp_path / 'labels' / 'val' / f'{name}.txt'
        label.write_text('0 0.5 0.5 0.25 0.25\n')  # (24, 18, 40, 30) in pixels
        (tmp_path / 'meta' / 'val' / f'{name}.json').write_text(json.dumps(
            {'group': 'grey', 'visible': visible}))
        pairs.append((image, label))
        boxes[image.stem] = [(24.0, 18.0, 40.0, 30.0, 0.9), (0.0, 0.0, 8.0, 8.0, 0.5)][
            0 if found else 1:]
    frames = iter(pairs)
    every = Scores(ranked=[])
    scores = evaluate(lambda rgb, depth: boxes[next(frames)[0].stem], pairs, every_label=every)
    assert (scores.balls, scores.found, scores.false) == (1, 1, 3)  # the 8-px boxes are false
    assert (every.balls, every.found, every.false) == (3, 2, 3)


def test_a_ball_is_plain_to_the_eye_only_off_both_floor_colours():
    assert plain_to_the_eye([0.2], [0.5, 0.9])
    assert not plain_to_the_eye([0.2], [0.5, 0.3])  # one floor colour within 0.15 of it
    assert plain_to_the_eye([0.4, 0.95], [0.5, 0.45])  # a pattern: one of its colours is
    assert not plain_to_the_eye([0.4, 0.55], [0.5, 0.45])


def test_detector_scenes_label_balls_of_every_colour_group():
    shots = list(detector_scenes(12, seed=7))
    assert [s.group for s in shots] == list(COLOR_GROUPS) * 2
    labelled = [s for s in shots if s.box is not None]
    assert len(labelled) >= 6
    for sample in labelled:
        u0, v0, u1, v1 = sample.box
        assert 0 <= u0 < u1 <= 640 and 0 <= v0 < v1 <= 480, sample.box
        assert sample.shot.centre is not None and sample.shot.visible > 0
    for sample in shots:
        if sample.box is None:
            assert sample.shot.centre is None
