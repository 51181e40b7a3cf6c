"""The ``dataset`` executable against a running sim: labels, appending, interruption, errors."""

from pathlib import Path
import signal
import subprocess
import sys
import time

from conftest import start_sim, wait_for
import cv2
import numpy as np
import pytest
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
from ur_rg2_vision.dataset import is_val

DATASET = str(Path(sys.executable).parent / 'dataset')
# The largest ball of the project's range: the renderer draws a sphere as a mesh whose outline
# lies about 3 % inside the true one, and rounds each side to a pixel; on the 15 px box of a far
# 3 cm ball those alone cost IoU 0.1, on the 40-80 px boxes of this ball less than 0.06.
RADIUS = 0.08
RUN_TIMEOUT = 240.0


def run_dataset(graph, *args, timeout: float = RUN_TIMEOUT) -> subprocess.CompletedProcess:
    return subprocess.run([DATASET, '--timeout', '30', *map(str, args)], env=graph.env,
                          capture_output=True, text=True, timeout=timeout)


def samples(root: Path) -> dict[str, tuple[Path, Path]]:
    """Return {name: (image, label)} of every image in the data set."""
    found = {}
    for image in sorted(root.glob('images/*/*.png')):
        found[image.stem] = (image, root / 'labels' / image.parent.name / f'{image.stem}.txt')
    return found


def red_box(image: Path) -> tuple[int, int, int, int] | None:
    """Return the box (x0, y0, x1, y1), YOLO pixel edges, of the red pixels of an image."""
    bgr = cv2.imread(str(image)).astype(int)
    b, g, r = bgr[..., 0], bgr[..., 1], bgr[..., 2]
    ys, xs = np.nonzero((r >= 60) & (r > 2.5 * g) & (r > 2.5 * b))
    if len(xs) == 0:
        return None
    return xs.min(), ys.min(), xs.max() + 1, ys.max() + 1


def iou(a, b) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
    return w * h / union


def check_labels(root: Path, width: int = 640, height: int = 480) -> tuple[int, int]:
    """Assert every label matches the ball's pixels; return (labelled, empty) counts."""
    labelled = empty = 0
    for name, (image, label) in samples(root).items():
        assert label.exists(), f'{image} has no label'
        lines = label.read_text().splitlines()
        pixels = red_box(image)
        if not lines:
            assert pixels is None, f'{name}: empty label but a ball at {pixels}'
            empty += 1
            continue
        assert len(lines) == 1
        cls, cx, cy, w, h = lines[0].split()
        assert cls == '0'
        cx, cy, w, h = (float(v) for v in (cx, cy, w, h))
        assert 0 <= cx - w / 2 and cx + w / 2 <= 1 + 1e-6 and 0 <= cy - h / 2
        assert cy + h / 2 <= 1 + 1e-6
        box = ((cx - w / 2) * width, (cy - h / 2) * height, (cx + w / 2) * width,
               (cy + h / 2) * height)
        assert pixels is not None, f'{name}: labelled {box} but no ball in the image'
        assert iou(box, pixels) >= 0.9, (name, box, pixels)
        labelled += 1
    return labelled, empty


def sim_parameters(graph, names):
    node = graph.node('parameter_reader')
    client = node.create_client(GetParameters, 'ur_rg2_sim/get_parameters')
    assert client.wait_for_service(timeout_sec=20)
    future = client.call_async(GetParameters.Request(names=names))
    wait_for(future.done, 20, 'the sim parameters')
    return [parameter_value_to_python(v) for v in future.result().values]


def test_writes_labelled_samples_and_appends(ros_graph, tmp_path):
    start_sim(ros_graph, real_time_factor=0.0, ball_radius=RADIUS)
    out = tmp_path / 'set'
    done = run_dataset(ros_graph, '--count', 10, '--out', out, '--seed', 3, '--out-of-view',
                       0.3, '--val-fraction', 0.3)
    assert done.returncode == 0, done.stderr
    assert 'wrote 10 samples' in done.stderr
    assert '10/10 100%' in done.stderr and 'samples/s' in done.stderr
    first = samples(out)
    assert sorted(first) == [f'{i:06d}' for i in range(10)]
    for name, (image, _) in first.items():
        assert image.parent.name == ('val' if is_val(int(name), 0.3) else 'train')
    labelled, empty = check_labels(out)
    assert labelled >= 5 and empty >= 1
    assert (out / 'data.yaml').read_text() == (
        f'path: {out}\ntrain: images/train\nval: images/val\nnames: {{0: ball}}\n'
        'renderer: "the sim\'s renderer parameter: auto"\n')
    contents = {name: (i.read_bytes(), lb.read_bytes()) for name, (i, lb) in first.items()}

    # One seed, the same placements: the same labels in another directory.
    same = run_dataset(ros_graph, '--count', 4, '--out', tmp_path / 'same', '--seed', 3,
                       '--out-of-view', 0.3, '--val-fraction', 0.3)
    assert same.returncode == 0, same.stderr
    for name, (_, label) in samples(tmp_path / 'same').items():
        assert label.read_bytes() == contents[name][1]

    # Run again: appends under new names, the split continues, nothing written is touched;
    # colours jitter, and the sim gets its own colour back afterwards.
    again = run_dataset(ros_graph, '--count', 5, '--out', out, '--val-fraction', 0.3,
                        '--jitter-color')
    assert again.returncode == 0, again.stderr
    assert 'wrote 5 samples' in again.stderr and '15 in the data set' in again.stderr
    both = samples(out)
    assert sorted(both) == [f'{i:06d}' for i in range(15)]
    for name, (image, label) in both.items():
        assert image.parent.name == ('val' if is_val(int(name), 0.3) else 'train')
        if name in contents:
            assert (image.read_bytes(), label.read_bytes()) == contents[name]
    assert sim_parameters(ros_graph, ['ball_color']) == [[1.0, 0.0, 0.0, 1.0]]


def test_camera_jitter_labels_match_the_moved_camera(ros_graph, tmp_path):
    start_sim(ros_graph, real_time_factor=0.0, ball_radius=RADIUS)
    before = sim_parameters(ros_graph, ['camera_position', 'camera_look_at', 'ball_position'])
    done = run_dataset(ros_graph, '--count', 6, '--out', tmp_path, '--seed', 11,
                       '--jitter-camera', '--out-of-view', 0)
    assert done.returncode == 0, done.stderr
    labelled, empty = check_labels(tmp_path)
    assert (labelled, empty) == (6, 0)
    images = [cv2.imread(str(i)) for i, _ in samples(tmp_path).values()]
    # The camera moved: the pedestal and arm are elsewhere in every picture.
    assert all(np.mean(images[0] != image) > 0.2 for image in images[1:])
    assert sim_parameters(ros_graph, ['camera_position', 'camera_look_at',
                                      'ball_position']) == before


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_interrupted_run_leaves_a_consistent_set(ros_graph, tmp_path, signum):
    start_sim(ros_graph, real_time_factor=0.0, ball_radius=RADIUS)
    process = subprocess.Popen([DATASET, '--count', '1000', '--out', str(tmp_path)],
                               env=ros_graph.env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: len(samples(tmp_path)) >= 3, 120, 'three samples written',
                 interval=0.05)
        process.send_signal(signum)
        _, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 128 + signum, stderr
    written = len(samples(tmp_path))
    assert f'interrupted by {signal.Signals(signum).name}: wrote {written} of 1000' in stderr
    for image, label in samples(tmp_path).values():
        assert label.exists() and cv2.imread(str(image)) is not None
    assert sorted(p.stem for p in tmp_path.glob('labels/*/*.txt')) == sorted(samples(tmp_path))
    assert not list(tmp_path.rglob('.*'))  # no temporary file left
    check_labels(tmp_path)


def test_no_sim_is_a_clear_error(ros_graph, tmp_path):
    started = time.monotonic()
    out = tmp_path / 'set'
    done = subprocess.run([DATASET, '--count', '2', '--out', str(out), '--timeout', '2'],
                          env=ros_graph.env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert 'is the sim running' in done.stderr and 'Traceback' not in done.stderr
    assert not out.exists()  # nothing is created without a sim
    assert time.monotonic() - started < 30


def test_unwritable_out_is_a_clear_error(ros_graph, tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('not a directory')
    done = subprocess.run([DATASET, '--out', str(blocker / 'set'), '--timeout', '2'],
                          env=ros_graph.env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert f'cannot write the data set to {blocker / "set"}' in done.stderr
    assert 'Traceback' not in done.stderr


def test_bad_option_is_a_usage_error():
    done = subprocess.run([DATASET, '--val-fraction', '1.5'], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2 and 'must be between 0 and 1' in done.stderr
