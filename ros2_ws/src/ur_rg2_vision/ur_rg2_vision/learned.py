"""The learned ball detector: a one-class network exported to ONNX, run with ONNX Runtime. No ROS.

A model directory (written by ``train_detector``, or the one shipped in this package) holds
``model.onnx`` and ``detector.json``: the input size ``[height, width]``, the class ``names``,
the ``ball_class`` index, the ``confidence`` and ``iou`` (non-maximum suppression) thresholds
and its ``inputs``: ``["rgb"]`` (the default), or ``["rgb", "depth_relief"]`` for a model that
also sees the depth's relief (:func:`ur_rg2_vision.learned_input.depth_relief`) as a fourth
channel. Output layout: 1 x
(4 + classes) x N rows, or their transpose; boxes are (cx, cy, w, h) in input pixels of the
letterboxed frame (scaled to fit, centred, grey around it), class scores 0-1. The shipped
model (:mod:`ur_rg2_detector.detector_net`, a CenterNet trained by this project, Apache-2.0)
gives that layout, as does an ultralytics YOLOv8 export: a user's own model of that layout
drops in with a ``detector.json`` beside it. ONNX Runtime (MIT; imported only when a model is
loaded) runs it on the CPU on one thread.

The network decides: each of its boxes over the threshold is a ball candidate, most confident
first, as a :class:`~ur_rg2_vision.detector.Detection` like the colour detector's: the sphere
whose outline has this box (off the optical axis an ellipse, see
:func:`ur_rg2_vision.sphere.sphere_box`) gives the image of its centre and its radius as seen
on the axis; its pixels are the disc inside the box, and :mod:`ur_rg2_vision.localize` fits
the sphere to their depth, which gives the 3D centre (and turns down a box on a flat disc or a
cube). No colour rule finds, refines or accepts a ball.
"""

from dataclasses import dataclass
import json
import math
import os
from pathlib import Path

import cv2
import numpy as np

from ur_rg2_vision.circle_fit import least_squares_step
from ur_rg2_vision.detector import BallDetector, Detection, HsvRange
from ur_rg2_vision.learned_input import (
    DEPTH_RELIEF,
    RGB,
    Letterbox,
    ModelInput,
    input_channels,
)
from ur_rg2_vision.sphere import sphere_box

MODEL_FILE = 'model.onnx'
SINGLE_PASS_FILE = 'model_single_pass.onnx'  # beside a flip-test model: the frame alone
SETTINGS_FILE = 'detector.json'
SHIPPED_MODEL = Path(__file__).resolve().parent / 'models' / 'ball'
_MAX_CANDIDATES = 100  # boxes over the threshold kept for non-maximum suppression
_MAX_BOXES = 6  # the most confident boxes after it: bounds the work per frame
_FIT_ITERATIONS = 6
_BORDER_PX = 1.0  # a box side this near the image border is cut off there, not the outline


class ModelError(ValueError):
    """A model directory that is missing, incomplete or unreadable, with the reason."""


def _run(session, blob: np.ndarray) -> np.ndarray:
    return session.run(None, {session.get_inputs()[0].name: blob})[0]


class BallModel:
    """An ONNX detector and its settings, loaded from a model directory."""

    def __init__(self, model_dir: str | os.PathLike | None = None) -> None:
        directory = Path(model_dir) if model_dir else SHIPPED_MODEL
        self.directory = directory
        settings_path = directory / SETTINGS_FILE
        if not directory.is_dir():
            raise ModelError(f'model_dir {str(directory)!r} is not a directory')
        try:
            settings = json.loads(settings_path.read_text())
            height, width = (int(n) for n in settings['input_size'])
            self.names = [str(name) for name in settings['names']]
            self.ball_class = int(settings.get('ball_class', 0))
            self.confidence = float(settings['confidence'])
            self.iou = float(settings['iou'])
            self.inputs = [str(name) for name in settings.get('inputs', [RGB])]
        except (OSError, ValueError, KeyError, TypeError) as error:
            raise ModelError(f'model_dir {str(directory)!r}: cannot read {SETTINGS_FILE} '
                             f'({type(error).__name__}: {error})') from None
        if not (0 <= self.ball_class < len(self.names) and 0 < self.confidence < 1
                and 0 < self.iou <= 1 and height > 0 and width > 0
                and self.inputs in ([RGB], [RGB, DEPTH_RELIEF])):
            raise ModelError(f'model_dir {str(directory)!r}: {SETTINGS_FILE} has an invalid '
                             'input_size, ball_class, confidence, iou or inputs')
        self.input_size = height, width
        try:
            import onnxruntime
        except ImportError as error:
            raise ModelError(f'model_dir {str(directory)!r}: the learned detector needs '
                             f'onnxruntime (requirements.txt): {error}') from None
        zeros = np.zeros((1, input_channels(self.inputs), height, width), np.float32)
        self._session, output = self._load(onnxruntime, MODEL_FILE, zeros)
        channels = 4 + len(self.names)
        if output.ndim != 3 or output.shape[0] != 1 or channels not in output.shape[1:]:
            raise ModelError(f'model_dir {str(directory)!r}: {MODEL_FILE} gives output '
                             f'{list(output.shape)}, expected 1 x {channels} x N (YOLOv8 '
                             f'layout, {len(self.names)} classes) or its transpose')
        self._transposed = output.shape[1] != channels
        # A model with the flip test may have the network on the frame alone beside it: run
        # first, it decides every frame the mirror image could not change (see _rows()).
        self._single_pass = None
        if settings.get('flip_test') and (directory / SINGLE_PASS_FILE).is_file():
            self._single_pass, single = self._load(onnxruntime, SINGLE_PASS_FILE, zeros)
            if single.shape != output.shape:
                raise ModelError(f'model_dir {str(directory)!r}: {SINGLE_PASS_FILE} gives '
                                 f'output {list(single.shape)}, {MODEL_FILE} '
                                 f'{list(output.shape)}')
        self._work: ModelInput | None = None  # for frames of the last size

    def _load(self, onnxruntime, name: str, zeros: np.ndarray) -> tuple[object, np.ndarray]:
        """Return an ONNX Runtime session of the file ``name`` and its output for ``zeros``."""
        options = onnxruntime.SessionOptions()
        # One thread: the node works on one frame at a time, and the machine has few cores.
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only: its warnings are not the user's
        try:
            session = onnxruntime.InferenceSession(
                str(self.directory / name), options, providers=['CPUExecutionProvider'])
            return session, _run(session, zeros)
        # A missing, corrupt or mismatched file: onnxruntime's own exception classes, which
        # derive from Exception alone.
        except Exception as error:
            reason = str(error).strip().splitlines()[-1] if str(error).strip() else ''
            raise ModelError(f'model_dir {str(self.directory)!r}: cannot run {name} '
                             f'({type(error).__name__}: {reason})') from None

    def _rows(self, blob: np.ndarray) -> np.ndarray:
        """Return the network's N x (4 + classes) rows for ``blob``.

        With a single-pass model beside a flip-test one, that runs first. Its rows are the
        answer when the flip test could not change which boxes pass: none scores
        ``confidence / 2`` or more (a mirror image would have to see a ball the frame itself
        hardly shows), or every such box scores ``2 * confidence`` or more (the average with
        the mirror image's score, 0 at least, passes). Other frames run the flip-test model.
        """
        if self._single_pass is not None:
            rows = self._oriented(_run(self._single_pass, blob))
            scores = rows[:, 4 + self.ball_class]
            seen = scores[scores >= self.confidence / 2]
            if not seen.size or seen.min() >= 2 * self.confidence:
                return rows
        return self._oriented(_run(self._session, blob))

    def _oriented(self, output: np.ndarray) -> np.ndarray:
        return output[0] if self._transposed else output[0].T

    @property
    def needs_depth(self) -> bool:
        """Tell whether the model sees the depth image too (its relief)."""
        return DEPTH_RELIEF in self.inputs

    def boxes(self, rgb: np.ndarray, depth: np.ndarray | None = None
              ) -> list[tuple[float, float, float, float, float]]:
        """Return the balls' boxes (u0, v0, u1, v1, score) in image pixels, best first.

        ``depth``: the frame's depth image (metres), for a model that needs it; ValueError
        when such a model has none or one of another size. The network's input is built in
        arrays kept for the next frame of that size: one call at a time.
        """
        if self.needs_depth and (depth is None or depth.shape[:2] != rgb.shape[:2]):
            raise ValueError(f'{self.directory}: the model needs the depth image of the '
                             f'{rgb.shape[1]}x{rgb.shape[0]} frame, got '
                             f'{"none" if depth is None else depth.shape}')
        rows, cols = rgb.shape[:2]
        if self._work is None or self._work.letterbox.shape != (rows, cols):
            self._work = ModelInput(Letterbox((rows, cols), self.input_size),
                                    input_channels(self.inputs), self.input_size)
        blob = self._work.fill(rgb, depth)
        box = self._work.letterbox
        scale, left, top = box.scale, box.left, box.top
        output = self._rows(blob)
        scores = output[:, 4 + self.ball_class]
        if len(self.names) > 1:  # a box is the ball's when the ball is its best class
            scores = np.where(output[:, 4:].argmax(axis=1) == self.ball_class, scores, 0.0)
        keep = np.flatnonzero(scores >= self.confidence)
        keep = keep[np.argsort(-scores[keep])[:_MAX_CANDIDATES]]
        if not len(keep):
            return []
        cx, cy, w, h = output[keep, :4].T
        u0 = (cx - w / 2 - left) / scale
        v0 = (cy - h / 2 - top) / scale
        found = cv2.dnn.NMSBoxes(
            [[float(a), float(b), float(c), float(d)] for a, b, c, d in
             zip(u0, v0, w / scale, h / scale)], scores[keep].tolist(), self.confidence,
            self.iou)
        result = []
        for i in np.asarray(found, dtype=int).reshape(-1)[:_MAX_BOXES]:
            x0, y0 = float(np.clip(u0[i], 0, cols)), float(np.clip(v0[i], 0, rows))
            x1 = float(np.clip(u0[i] + w[i] / scale, 0, cols))
            y1 = float(np.clip(v0[i] + h[i] / scale, 0, rows))
            if x1 > x0 and y1 > y0:
                result.append((x0, y0, x1, y1, float(scores[keep[i]])))
        return result


class LearnedBallDetector:
    """Finds balls with a :class:`BallModel`; the same ``detect`` as the colour detector."""

    def __init__(self, model: BallModel, min_radius_px: float) -> None:
        if not min_radius_px > 0:
            raise ValueError(f'min_radius_px must be positive, got {min_radius_px}')
        self.model = model
        self.min_radius_px = float(min_radius_px)

    @property
    def needs_depth(self) -> bool:
        """Tell whether ``detect`` needs the frame's depth image (the model sees it)."""
        return self.model.needs_depth

    def detect(self, rgb: np.ndarray, k: np.ndarray | None = None,
               depth: np.ndarray | None = None) -> list[Detection]:
        """Return the balls in an RGB uint8 image, the most confident first.

        ``k``: the 3x3 camera matrix; without it, outlines are taken as seen on the axis.
        ``depth``: the frame's depth image (metres), needed when :attr:`needs_depth`.
        """
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f'expected an RGB uint8 image, got {rgb.dtype} {rgb.shape}')
        shapes = (box_detection(box, rgb.shape[1], rgb.shape[0], k)
                  for box in self.model.boxes(rgb, depth))
        return [detection for detection in shapes if detection.radius >= self.min_radius_px]


@dataclass(frozen=True)
class DetectionConfig:
    """The vision node's detector and the ball radius it assumes (0: measured)."""

    detector: BallDetector | LearnedBallDetector
    ball_radius: float


def detection_config(color: HsvRange, min_radius_px: float, ball_radius: float,
                     model: BallModel | None) -> DetectionConfig:
    """Return the detector of the vision node's settings and the ball radius it assumes.

    ``color`` is the colour detector's range; ``model``: the learned detector's model, None
    for the colour detector.
    """
    detector = (BallDetector(color, min_radius_px) if model is None
                else LearnedBallDetector(model, min_radius_px))
    return DetectionConfig(detector, ball_radius)


def box_detection(box: tuple[float, float, float, float, float], width: int, height: int,
                  k: np.ndarray | None) -> Detection:
    """Return the detection of a ball whose outline has this box (u0, v0, u1, v1, score).

    The box in YOLO's pixel coordinates (pixel i covers [i, i + 1]), as :meth:`BallModel.boxes`
    gives it; the detection in ROS's (pixel i's centre at i), as the camera matrix has it.
    """
    u0, v0, u1, v1 = (c - 0.5 for c in box[:4])
    score = box[4]
    u, v, radius = (u0 + u1) / 2, (v0 + v1) / 2, max(u1 - u0, v1 - v0) / 2
    if k is not None:
        u, v, radius = _outline_sphere((u0, v0, u1, v1), width, height, k, (u, v, radius))
    # Pixels: the disc inside the box (localize fits the core of it, and trims the rest).
    x0, y0 = max(0, int(math.floor(u0))), max(0, int(math.floor(v0)))
    x1, y1 = min(width, int(math.ceil(u1)) + 1), min(height, int(math.ceil(v1)) + 1)
    rows, cols = np.mgrid[y0:y1, x0:x1]
    mask = (cols - u) ** 2 + (rows - v) ** 2 <= radius ** 2
    return Detection(u=float(u), v=float(v), radius=float(radius), coverage=score, mask=mask,
                     x0=x0, y0=y0)


def _outline_sphere(box: tuple[float, float, float, float], width: int, height: int,
                    k: np.ndarray, start: tuple[float, float, float]
                    ) -> tuple[float, float, float]:
    """Return (u, v, on-axis radius) of the sphere whose projected box is ``box``.

    Least squares over the box sides not cut off by the image border; the sphere at distance
    1 along the ray through (u, v), of the radius whose on-axis image is ``radius`` pixels.
    """
    sides = np.array([box[0] > _BORDER_PX - 0.5, box[1] > _BORDER_PX - 0.5,
                      box[2] < width - 0.5 - _BORDER_PX, box[3] < height - 0.5 - _BORDER_PX])
    if np.count_nonzero(sides) < 3:
        return start
    target = np.asarray(box)[sides]
    focal = (k[0, 0] + k[1, 1]) / 2
    inverse = np.linalg.inv(k)

    def predict(params: np.ndarray) -> np.ndarray | None:
        u, v, radius = params
        ray = inverse @ (u, v, 1.0)
        ray /= np.linalg.norm(ray)
        projected = sphere_box(ray, math.sin(math.atan(radius / focal)), k)
        return None if projected is None else np.asarray(projected)[sides]

    params = np.asarray(start, dtype=float)
    for _ in range(_FIT_ITERATIONS):
        predicted = predict(params)
        if predicted is None:
            return start
        jacobian = np.empty((len(target), 3))
        for j in range(3):
            nudged = params.copy()
            nudged[j] += 0.1
            moved = predict(nudged)
            if moved is None:
                return start
            jacobian[:, j] = (moved - predicted) / 0.1
        step = least_squares_step(jacobian, predicted - target)
        params += step
        if params[2] <= 0:
            return start
        if np.abs(step).max() < 0.01:
            break
    return float(params[0]), float(params[1]), float(params[2])
