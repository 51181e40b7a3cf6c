"""The learned detector's input, built in work arrays kept from frame to frame, bit for bit.

:class:`ur_rg2_vision.learned.BallModel` letterboxes each frame into arrays it keeps (the
network's input, the relief's steps) instead of allocating them per frame. The model was
trained on the input of the plain per-frame code below (``train_detector`` builds it with
:func:`~ur_rg2_vision.learned_input.depth_relief`): the kept arrays must give exactly that,
whatever frame came before, in whatever size.
"""

import cv2
import numpy as np
import pytest
from ur_rg2_vision.learned import BallModel
from ur_rg2_vision.learned_input import depth_relief

SIGMA, GAIN, STEP, PAD, GREY = 8.0, 20.0, 2, 32, 114  # learned.py's constants


def plain_relief(depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Return the relief as the model's training input was built: fresh arrays, one pass."""
    height, width = size
    rows, cols = depth.shape[:2]
    scale = min(height / rows, width / cols)
    inner_w, inner_h = round(cols * scale), round(rows * scale)
    left, top = (width - inner_w) // 2, (height - inner_h) // 2
    valid = np.isfinite(depth) & (depth > 0)
    known = np.where(valid, depth, np.float32(0)).astype(np.float32, copy=False)
    scaled = cv2.resize(cv2.merge([known, valid.astype(np.float32)]), (inner_w, inner_h),
                        interpolation=cv2.INTER_AREA)
    known, valid = scaled[..., 0], scaled[..., 1]
    padded = cv2.copyMakeBorder(scaled, PAD, PAD, PAD, PAD, cv2.BORDER_REFLECT_101)
    prows, pcols = padded.shape[:2]
    small = cv2.resize(padded, (pcols // STEP, prows // STEP), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), SIGMA / STEP)
    smooth = small[..., 0] / np.maximum(small[..., 1], np.float32(1e-6))
    smooth = cv2.resize(smooth, (pcols, prows), interpolation=cv2.INTER_LINEAR)
    smooth = smooth[PAD:prows - PAD, PAD:pcols - PAD]
    relief = (known / np.maximum(valid, np.float32(1e-6)) - smooth) * np.float32(GAIN)
    relief[valid <= 0.5] = 0
    canvas = np.zeros((height, width), np.float32)
    np.clip(relief, -1, 1, out=canvas[top:top + inner_h, left:left + inner_w])
    return canvas


def plain_input(rgb: np.ndarray, depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Return the network's input (1, 4, height, width) built afresh for one frame."""
    height, width = size
    rows, cols = rgb.shape[:2]
    scale = min(height / rows, width / cols)
    inner_w, inner_h = round(cols * scale), round(rows * scale)
    left, top = (width - inner_w) // 2, (height - inner_h) // 2
    canvas = np.full((height, width, 3), GREY, np.uint8)
    canvas[top:top + inner_h, left:left + inner_w] = cv2.resize(
        rgb, (inner_w, inner_h), interpolation=cv2.INTER_AREA)
    blob = np.empty((1, 4, height, width), np.float32)
    np.multiply(canvas.transpose(2, 0, 1), np.float32(1 / 255), out=blob[0, :3],
                casting='unsafe')
    blob[0, 3] = plain_relief(depth, size)
    return blob


def frame(seed: int, rows: int = 480, cols: int = 640) -> tuple[np.ndarray, np.ndarray]:
    """Return a random (rgb, depth): a tilted floor, bumps, holes of every kind of no-return."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (rows, cols, 3), dtype=np.uint8)
    v, u = np.mgrid[0:rows, 0:cols].astype(np.float32)
    depth = 1.5 + 0.002 * v - 0.0005 * u + rng.normal(0, 0.002, (rows, cols)).astype(np.float32)
    for _ in range(5):
        cu, cv, radius = rng.uniform(0, cols), rng.uniform(0, rows), rng.uniform(5, 40)
        depth[(u - cu) ** 2 + (v - cv) ** 2 <= radius ** 2] -= 0.05
    for value in (0.0, -1.0, np.inf, -np.inf, np.nan):
        depth[rng.random((rows, cols)) < 0.02] = value
    depth[: rows // 8, : cols // 8] = np.nan  # a large hole
    return np.ascontiguousarray(rgb), depth.astype(np.float32)


def bits(array: np.ndarray) -> np.ndarray:
    """Return float32 values as their bits: equal means the same float, -0.0 and NaN too."""
    return np.ascontiguousarray(array, np.float32).view(np.uint32)


@pytest.mark.parametrize('shape, size', [
    ((480, 640), (384, 512)), ((360, 640), (384, 512)), ((480, 640), (96, 128)),
    ((123, 457), (240, 320))])
def test_depth_relief_is_the_plain_computation_bit_for_bit(shape, size):
    _, depth = frame(1, *shape)
    for metres in (depth, depth.astype(np.float64)):  # as read from a file, too
        np.testing.assert_array_equal(bits(depth_relief(metres, size)),
                                      bits(plain_relief(metres, size)))


def test_model_input_is_the_plain_one_frame_after_frame_and_size_after_size():
    model = BallModel()
    assert model.needs_depth  # the shipped model: RGB and the depth's relief
    inputs = []
    rows = model._rows
    model._rows = lambda blob: inputs.append(blob.copy()) or rows(blob)
    frames = [frame(2), frame(3), frame(4, 360, 640), frame(5, 240, 320), frame(2)]
    for rgb, depth in frames:
        boxes = model.boxes(rgb, depth)
        np.testing.assert_array_equal(bits(inputs[-1]),
                                      bits(plain_input(rgb, depth, model.input_size)))
        assert boxes == model.boxes(rgb.copy(), depth.copy())  # again: the same answer
