"""The learned detector's input: a frame letterboxed to the model's size, and the depth's relief.

Plain NumPy and OpenCV, no ROS. :func:`depth_relief` is what the trainer feeds a model that
sees the depth; :class:`ModelInput` builds the same input for :class:`~ur_rg2_vision.learned.
BallModel`, frame after frame, in arrays it keeps (bit for bit what a fresh build gives).
"""

import cv2
import numpy as np

PAD_GREY = 114  # ultralytics' letterbox fill

RGB, DEPTH_RELIEF = 'rgb', 'depth_relief'  # a model's inputs (detector.json's "inputs")
_RELIEF_SIGMA_PX = 8.0  # the smooth surface the relief is measured from, input pixels
_RELIEF_GAIN = 20.0  # relief channel per metre (clipped to +-1: 5 cm and more)
_RELIEF_STEP = 2  # the smooth surface is blurred at half the input's resolution
_RELIEF_PAD_PX = round(4 * _RELIEF_SIGMA_PX)  # border reflected around the input before that


def input_channels(inputs: list[str]) -> int:
    """Return the channels of a model's input: RGB's three, and one for the depth's relief."""
    return 3 + (DEPTH_RELIEF in inputs)


def depth_relief(depth: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Return a depth image's relief at a model's input ``size`` (height, width), float32.

    ``depth`` in metres, 0, inf or NaN where there is none; letterboxed as
    :meth:`ur_rg2_vision.learned.BallModel.boxes` letterboxes the colour frame (0 around
    it). The relief is the depth less its Gaussian blur (what stands out of the surface
    around it: a ball, a cube's edge; a flat disc hardly), times 20 per metre, clipped to
    +-1; 0 where there is no depth.
    """
    letterbox = Letterbox(depth.shape[:2], size)
    canvas = np.zeros(size, np.float32)
    _Relief(letterbox).compute(depth, canvas[letterbox.inner])
    return canvas


class Letterbox:
    """Where a frame of one size lies in a model's input: scaled to fit, centred."""

    def __init__(self, shape: tuple[int, int], size: tuple[int, int]) -> None:
        (rows, cols), (height, width) = shape, size
        self.shape = rows, cols
        self.scale = min(height / rows, width / cols)
        self.inner_w, self.inner_h = round(cols * self.scale), round(rows * self.scale)
        self.left, self.top = (width - self.inner_w) // 2, (height - self.inner_h) // 2
        self.inner = (slice(self.top, self.top + self.inner_h),
                      slice(self.left, self.left + self.inner_w))


class _Relief:
    """:func:`depth_relief` of the depth images of one size, in work arrays kept between frames.

    Allocated once: in a process whose allocator hands freed blocks back to the kernel (all
    but the nodes, see ur_rg2_common.spin.keep_freed_memory), fresh arrays per frame would
    cost page faults on every frame. One frame at a time.
    """

    def __init__(self, letterbox: Letterbox) -> None:
        self.letterbox = letterbox
        shape, inner = letterbox.shape, (letterbox.inner_h, letterbox.inner_w)
        self._valid = np.empty(shape, bool)
        self._other = np.empty(shape, bool)
        self._known = np.empty(shape, np.float32)
        self._share = np.empty(shape, np.float32)
        self._pair = np.empty(shape + (2,), np.float32)  # the known depth and the share known
        self._scaled = np.empty(inner + (2,), np.float32)
        pad, step = _RELIEF_PAD_PX, _RELIEF_STEP
        padded = inner[0] + 2 * pad, inner[1] + 2 * pad
        self._padded = np.empty(padded + (2,), np.float32)
        small = padded[0] // step, padded[1] // step
        self._small = np.empty(small + (2,), np.float32)
        self._blurred = np.empty(small + (2,), np.float32)
        self._ratio = np.empty(small, np.float32)
        self._smooth = np.empty(padded, np.float32)
        # The scaled channels apart: numpy is several times faster on contiguous planes.
        self._planes = [np.empty(inner, np.float32) for _ in range(2)]
        self._relief = np.empty(inner, np.float32)
        self._unknown = np.empty(inner, bool)

    def compute(self, depth: np.ndarray, out: np.ndarray) -> None:
        """Write the relief of ``depth`` into ``out``, the letterbox's inner part of the input."""
        valid, other = self._valid, self._other
        # Finite and positive: NaN fails both comparisons, +inf the second.
        np.greater(depth, 0, out=valid)
        np.less(depth, np.inf, out=other)
        np.logical_and(valid, other, out=valid)
        np.copyto(self._known, depth)
        np.logical_not(valid, out=other)
        np.copyto(self._known, 0, where=other)
        np.copyto(self._share, valid)
        cv2.merge([self._known, self._share], dst=self._pair)
        box = self.letterbox
        cv2.resize(self._pair, (box.inner_w, box.inner_h), dst=self._scaled,
                   interpolation=cv2.INTER_AREA)
        known, share = cv2.split(self._scaled, self._planes)
        relief = self._relief
        np.maximum(share, np.float32(1e-6), out=relief)
        np.divide(known, relief, out=relief)
        np.subtract(relief, self._smooth_depth(), out=relief)
        np.multiply(relief, np.float32(_RELIEF_GAIN), out=relief)
        np.less_equal(share, np.float32(0.5), out=self._unknown)
        np.copyto(relief, 0, where=self._unknown)
        np.clip(relief, -1, 1, out=out)

    def _smooth_depth(self) -> np.ndarray:
        """Return the Gaussian blur of the known depth, normalised by how much of it is known.

        Of the scaled known depth (0 elsewhere) and share known. Normalised, no hole pulls the
        surface towards 0. Blurred at half the resolution, for speed, on the image with its
        border reflected wide enough (4 sigma) to be blurred as at full resolution.
        """
        pad = _RELIEF_PAD_PX
        cv2.copyMakeBorder(self._scaled, pad, pad, pad, pad, cv2.BORDER_REFLECT_101,
                           dst=self._padded)
        rows, cols = self._padded.shape[:2]
        small, blurred, ratio = self._small, self._blurred, self._ratio
        cv2.resize(self._padded, small.shape[1::-1], dst=small, interpolation=cv2.INTER_AREA)
        cv2.GaussianBlur(small, (0, 0), _RELIEF_SIGMA_PX / _RELIEF_STEP, dst=blurred)
        np.maximum(blurred[..., 1], np.float32(1e-6), out=ratio)
        np.divide(blurred[..., 0], ratio, out=ratio)
        cv2.resize(ratio, (cols, rows), dst=self._smooth, interpolation=cv2.INTER_LINEAR)
        return self._smooth[pad:rows - pad, pad:cols - pad]


class ModelInput:
    """A model's input array and the work arrays that fill it, for frames of one size.

    The grey letterbox around the frame (and 0 relief there) is written once; each frame
    fills the inner part.
    """

    def __init__(self, letterbox: Letterbox, channels: int, size: tuple[int, int]) -> None:
        self.letterbox = letterbox
        self.blob = np.empty((1, channels) + size, np.float32)
        np.multiply(np.full(size, PAD_GREY, np.uint8), np.float32(1 / 255), out=self.blob[0, 0])
        self.blob[0, 1:3] = self.blob[0, 0]
        self.blob[0, 3:] = 0
        self._resized = np.empty((letterbox.inner_h, letterbox.inner_w, 3), np.uint8)
        self._planes = [np.empty((letterbox.inner_h, letterbox.inner_w), np.uint8)
                        for _ in range(3)]
        self._relief = _Relief(letterbox) if channels > 3 else None

    def fill(self, rgb: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """Return the input of a frame (and its depth, for a model that sees it)."""
        box = self.letterbox
        cv2.resize(rgb, (box.inner_w, box.inner_h), dst=self._resized,
                   interpolation=cv2.INTER_AREA)  # as the trainer scales
        # RGB 0-1 planes, as ultralytics feeds them, then the relief.
        cv2.split(self._resized, self._planes)
        for channel, plane in enumerate(self._planes):
            np.multiply(plane, np.float32(1 / 255), out=self.blob[0, channel][box.inner],
                        casting='unsafe')
        if self._relief is not None:
            self._relief.compute(depth, self.blob[0, 3][box.inner])
        return self.blob
