"""Ball detection in a colour image: HSV threshold, then a robust circle fit per blob.

Plain OpenCV and numpy, no ROS. Two stages keep a 640x480 frame within a few milliseconds:

1. Coarse: threshold a half-resolution copy in HSV and take its connected blobs as candidates.
2. Fine, per candidate, in a window around it at full resolution: threshold again, collect the
   outer contour points of every blob in the window and fit one circle to them with RANSAC.
   Contour points of an occluder's edge (the gripper or an arm link in front of the ball, or the
   image border) do not lie on the ball's outline, so RANSAC leaves them out, and a ball cut in
   two by a gripper finger still yields one circle from both halves.

A blob is a ball when enough of the fitted circle's circumference is seen (``coverage``) and
the contour does not bulge out of the circle: a cube's outline has corners outside any circle
that follows its edges. From far away, a cube's hexagonal outline is too small to tell from a
circle; the depth check in :mod:`ur_rg2_vision.localize` rejects those.

Only a sphere on the optical axis has a circular outline; off the axis it is an ellipse
stretched outwards, by up to ~20 % in the corners of a 57 degree image, more than a cube's
corners stick out. Given the camera matrix, the fit therefore works in a virtual view turned
to look straight at the blob, where the outline is a circle again (:class:`_BallView`).
"""

from dataclasses import dataclass
import math

import cv2
import numpy as np

from ur_rg2_vision.circle_fit import (
    TOL_FRACTION,
    TOL_PX,
    Arcs,
    bulge,
    distances,
    ransac_circle,
)

# OpenCV's 8-bit HSV: hue 0-179 (degrees / 2), saturation and value 0-255.
HUE_MAX = 179
SV_MAX = 255

_COARSE_SCALE = 2  # the coarse stage works on every second pixel of every second row
_MAX_CANDIDATES = 6  # largest coarse blobs refined per frame
_MIN_CONTOUR_POINTS = 8
_MAX_PIECES = 8  # outlines per window, longest first
_MAX_BULGE_RATIO = 0.08  # bulge points per on-circle point
_MIN_COVERAGE = 0.4  # fraction of the circumference seen
_COVERAGE_BINS = 36
_OUTLINE_ANGLES = np.linspace(0, 2 * math.pi, 64, endpoint=False)
_UNIT_CIRCLE = np.column_stack([np.cos(_OUTLINE_ANGLES), np.sin(_OUTLINE_ANGLES)])
_SUBPIXEL_BITS = 4  # the ball's outline is drawn to 1/16 pixel
_SUBPIXEL = 1 << _SUBPIXEL_BITS


@dataclass(frozen=True)
class HsvRange:
    """An inclusive HSV range; when ``lower`` hue > ``upper`` hue it wraps around 0 (red)."""

    lower: tuple[int, int, int]
    upper: tuple[int, int, int]

    def __post_init__(self) -> None:
        for name, value in (('lower', self.lower), ('upper', self.upper)):
            if len(value) != 3:
                raise ValueError(f'HSV {name} must have 3 values (H, S, V), got {len(value)}')
            h, s, v = value
            if not (0 <= h <= HUE_MAX and 0 <= s <= SV_MAX and 0 <= v <= SV_MAX):
                raise ValueError(f'HSV {name} {list(value)} out of range: H 0-{HUE_MAX}, '
                                 f'S and V 0-{SV_MAX}')
        if self.lower[1] > self.upper[1] or self.lower[2] > self.upper[2]:
            raise ValueError(f'HSV lower {list(self.lower)} exceeds upper {list(self.upper)} '
                             'in saturation or value')

    def mask(self, rgb: np.ndarray) -> np.ndarray:
        """Return a uint8 mask (255 = in range) of an RGB uint8 image."""
        return self.hsv_mask(cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV))

    def hsv_mask(self, hsv: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Return the mask of an HSV image (OpenCV's 8-bit scale), into ``out`` if given."""
        (h_lo, s_lo, v_lo), (h_hi, s_hi, v_hi) = self.lower, self.upper
        if h_lo <= h_hi:
            return cv2.inRange(hsv, (h_lo, s_lo, v_lo), (h_hi, s_hi, v_hi), dst=out)
        out = cv2.inRange(hsv, (h_lo, s_lo, v_lo), (HUE_MAX, s_hi, v_hi), dst=out)
        return cv2.bitwise_or(out, cv2.inRange(hsv, (0, s_lo, v_lo), (h_hi, s_hi, v_hi)),
                              dst=out)


# The sim's default ball, RGBA (1, 0, 0, 1): pure red, darker on its shaded side.
RED = HsvRange((170, 100, 40), (10, 255, 255))
DEFAULT_MIN_RADIUS_PX = 4.0


@dataclass(frozen=True)
class Detection:
    """A ball found in the image, in full-resolution pixel coordinates."""

    u: float  # the ball centre's image, column
    v: float  # the ball centre's image, row
    radius: float  # pixels, as if the ball were on the optical axis (see the module docstring)
    coverage: float  # fraction of the circumference seen, 0-1
    mask: np.ndarray  # bool, ball-colour pixels inside the circle, within the window below
    x0: int  # window origin: mask[i, j] is pixel (x0 + j, y0 + i)
    y0: int

    def pixels(self, step: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Return the columns and rows of the ball-colour pixels inside the circle.

        ``step``: only those of every step-th row and column.
        """
        rows, cols = np.nonzero(self.mask[::step, ::step])
        return cols * step + self.x0, rows * step + self.y0


class BallDetector:
    """Finds round blobs of one colour; see the module docstring for the method.

    It reuses its working images from frame to frame: one detector per thread.
    """

    needs_depth = False  # colour alone finds the ball; the depth only locates it

    def __init__(self, color: HsvRange = RED,
                 min_radius_px: float = DEFAULT_MIN_RADIUS_PX) -> None:
        if not min_radius_px > 0:
            raise ValueError(f'min_radius_px must be positive, got {min_radius_px}')
        self.color = color
        self.min_radius_px = float(min_radius_px)
        # The coarse stage's images, reused: fresh ones of this size cost new pages per frame.
        self._small = self._hsv = self._coarse = None

    def _coarse_mask(self, rgb: np.ndarray) -> np.ndarray:
        """Return the colour mask of every second pixel of every second row."""
        height, width = rgb.shape[0] // _COARSE_SCALE, rgb.shape[1] // _COARSE_SCALE
        if self._small is None or self._small.shape[:2] != (height, width):
            self._small = np.empty((height, width, 3), np.uint8)
            self._hsv = np.empty_like(self._small)
            self._coarse = np.empty((height, width), np.uint8)
        cv2.resize(rgb, (width, height), dst=self._small, interpolation=cv2.INTER_NEAREST)
        cv2.cvtColor(self._small, cv2.COLOR_RGB2HSV, dst=self._hsv)
        return self.color.hsv_mask(self._hsv, self._coarse)

    def detect(self, rgb: np.ndarray, k: np.ndarray | None = None,
               depth: np.ndarray | None = None) -> list[Detection]:
        """Return the balls in an RGB uint8 image, the most completely seen first.

        ``k``: the 3x3 camera matrix. Without it, outlines are taken as seen on the axis.
        ``depth``: not used (the learned detector's ``detect`` may need it).
        """
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f'expected an RGB uint8 image, got {rgb.dtype} {rgb.shape}')
        height, width = rgb.shape[:2]
        coarse = self._coarse_mask(rgb)
        outlines, _ = cv2.findContours(coarse, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        # Blobs by bounding box, largest first; specks far below the smallest ball are noise.
        min_area = max(3.0, 0.25 * math.pi * (self.min_radius_px / _COARSE_SCALE) ** 2)
        blobs = sorted((cv2.boundingRect(outline) for outline in outlines),
                       key=lambda box: -box[2] * box[3])
        blobs = [box for box in blobs if box[2] * box[3] >= min_area]
        found: list[tuple[int, Detection]] = []
        for x, y, w, h in blobs[:_MAX_CANDIDATES]:
            # Already explained by a ball found from a larger blob (its other half)?
            cu, cv_ = (x + w / 2) * _COARSE_SCALE, (y + h / 2) * _COARSE_SCALE
            if any(math.hypot(cu - d.u, cv_ - d.v) < d.radius for _, d in found):
                continue
            # Window: the blob, grown by its size to take in the rest of a ball cut in two by
            # an occluder (a gripper finger in front of its middle), then shrunk to the blobs
            # in it, with a margin of a coarse pixel to their full-resolution edges.
            grow = max(w, h) + 2
            left, top = max(0, x - grow), max(0, y - grow)
            near = coarse[top:y + h + grow, left:x + w + grow]
            bx, by, bw, bh = cv2.boundingRect(near)
            x0 = max(0, (left + bx - 1) * _COARSE_SCALE)
            y0 = max(0, (top + by - 1) * _COARSE_SCALE)
            x1 = min(width, (left + bx + bw + 1) * _COARSE_SCALE)
            y1 = min(height, (top + by + bh + 1) * _COARSE_SCALE)
            result = self._refine(rgb, k, x0, y0, x1, y1)
            if result is not None and not any(
                    math.hypot(result[1].u - d.u, result[1].v - d.v) < d.radius
                    for _, d in found):
                found.append(result)
        found.sort(key=lambda item: -item[0])
        return [detection for _, detection in found]

    def find_in(self, rgb: np.ndarray, k: np.ndarray | None,
                window: tuple[int, int, int, int]) -> Detection | None:
        """Return the ball of this colour in ``window`` (x0, y0, x1, y1) of the image, if any."""
        height, width = rgb.shape[:2]
        x0, y0 = max(0, window[0]), max(0, window[1])
        x1, y1 = min(width, window[2]), min(height, window[3])
        result = self._refine(rgb, k, x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None
        return None if result is None else result[1]

    def _refine(self, rgb: np.ndarray, k: np.ndarray | None, x0: int, y0: int, x1: int,
                y1: int) -> tuple[int, Detection] | None:
        """Fit a circle to the blobs in one window; return (on-circle points, detection)."""
        height, width = rgb.shape[:2]
        mask = self.color.mask(rgb[y0:y1, x0:x1])
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE,
                                       offset=(x0, y0))
        # The longest outlines only: a ball is in at most a few pieces; this bounds the work
        # on cluttered frames.
        contours = sorted((c for c in contours if len(c) >= _MIN_CONTOUR_POINTS),
                          key=len, reverse=True)[:_MAX_PIECES]
        if not contours:
            return None
        lengths = np.array([len(c) for c in contours])
        pixels = np.concatenate(contours).reshape(-1, 2)
        view = _BallView(k, *pixels.mean(axis=0))
        # Coordinates as rows (2, N): the fits' arithmetic runs on contiguous arrays.
        points = view.from_image(pixels)
        # The image border cuts a ball like an occluder does: its edge is not the ball's.
        border = _on_border(pixels, width, height, (x0, y0, x1, y1))
        arcs = Arcs(points, lengths, border)
        if arcs.points.shape[1] < _MIN_CONTOUR_POINTS:
            return None
        max_radius = max(width, height) / 2
        circle = ransac_circle(arcs, self.min_radius_px, max_radius)
        if circle is None:
            return None
        cu, cv_, radius = circle
        tol = max(TOL_PX, TOL_FRACTION * radius)
        distance = distances(arcs.points, cu, cv_)
        on_circle = np.abs(distance - radius) <= tol
        n_on = int(np.count_nonzero(on_circle))
        on_x, on_y = arcs.points.compress(on_circle, axis=1)
        angles = np.arctan2(on_y - cv_, on_x - cu)
        bins = ((angles + math.pi) * (_COVERAGE_BINS / (2 * math.pi))).astype(int)
        coverage = np.count_nonzero(np.bincount(bins % _COVERAGE_BINS)) / _COVERAGE_BINS
        if coverage < _MIN_COVERAGE:
            return None
        if bulge(distances(points, cu, cv_), lengths, border, radius, tol) > (
                _MAX_BULGE_RATIO * n_on):
            return None
        # Contour points are the blob's outermost pixel centres, half a pixel inside its edge.
        radius += 0.5
        if not self.min_radius_px <= radius <= max_radius:
            return None
        u, v = view.to_image(np.array([[cu, cv_]]))[0]
        # Ball-colour pixels inside the outline (an ellipse off the axis): the outline drawn
        # in a window around it.
        outline = view.to_image(radius * _UNIT_CIRCLE + (cu, cv_))
        bx0, by0 = np.maximum(np.floor(outline.min(axis=0)).astype(int), (x0, y0))
        bx1, by1 = np.minimum(np.ceil(outline.max(axis=0)).astype(int) + 1, (x1, y1))
        if bx0 >= bx1 or by0 >= by1:
            return None
        inside = np.zeros((by1 - by0, bx1 - bx0), np.uint8)
        vertices = np.round((outline - (bx0, by0)) * _SUBPIXEL).astype(np.int32)
        cv2.fillPoly(inside, [vertices], 1, cv2.LINE_8, _SUBPIXEL_BITS)
        ball_mask = (mask[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] & inside).view(bool)
        return n_on, Detection(u=float(u), v=float(v), radius=float(radius),
                               coverage=coverage, mask=ball_mask, x0=int(bx0), y0=int(by0))


class _BallView:
    """Pixel coordinates of a virtual camera turned to look straight at one image point.

    Same focal length as the real camera, its principal point at (0, 0); only the rotation
    differs, so the image of a sphere centred on the new axis is a circle. Between the two
    images is a homography. Without a camera matrix: the image itself.
    """

    def __init__(self, k: np.ndarray | None, u: float, v: float) -> None:
        self._to_view = self._to_image = None
        if k is None:
            return
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        x, y = (u - cx) / fx, (v - cy) / fy
        # Rodrigues: the rotation taking the ray (x, y, 1) onto the optical axis, about
        # the axis (y, -x, 0) / sin.
        norm = math.sqrt(x * x + y * y + 1.0)
        sin, cos = math.hypot(x, y) / norm, 1.0 / norm
        if sin > 1e-12:
            ax, ay = y / (norm * sin), -x / (norm * sin)
            c1 = 1.0 - cos
            rotation = np.array([
                [cos + c1 * ax * ax, c1 * ax * ay, sin * ay],
                [c1 * ax * ay, cos + c1 * ay * ay, -sin * ax],
                [-sin * ay, sin * ax, cos]])
        else:
            rotation = np.eye(3)
        f = (fx + fy) / 2
        to_ray = np.array([[1 / fx, 0.0, -cx / fx], [0.0, 1 / fy, -cy / fy], [0.0, 0.0, 1.0]])
        from_ray = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        self._to_view = np.diag([f, f, 1.0]) @ rotation @ to_ray
        self._to_image = from_ray @ rotation.T @ np.diag([1 / f, 1 / f, 1.0])

    def from_image(self, points: np.ndarray) -> np.ndarray:
        """Return (N, 2) image points in the virtual view's pixels, as rows (2, N) float64."""
        return np.ascontiguousarray(_transform(points, self._to_view).T)

    def to_image(self, points: np.ndarray) -> np.ndarray:
        """Return (N, 2) points of the virtual view as (N, 2) image pixels."""
        return _transform(points, self._to_image)


def _transform(points: np.ndarray, homography: np.ndarray | None) -> np.ndarray:
    points = points.astype(np.float64)
    if homography is None:
        return points
    return cv2.perspectiveTransform(points.reshape(-1, 1, 2), homography).reshape(-1, 2)


def _on_border(pixels: np.ndarray, width: int, height: int, window: tuple[int, int, int, int]
               ) -> np.ndarray:
    """Return which contour pixels (N, 2) lie on the image border.

    Only the sides that the window (x0, y0, x1, y1) the contours come from touches are checked.
    """
    x0, y0, x1, y1 = window
    border = np.zeros(len(pixels), dtype=bool)
    for touches, axis, edge in ((x0 == 0, 0, 0), (y0 == 0, 1, 0), (x1 == width, 0, width - 1),
                                (y1 == height, 1, height - 1)):
        if touches:
            border |= pixels[:, axis] == edge
    return border


_DRAW_COLOR = (0, 255, 0)


def draw_detections(rgb: np.ndarray, detections: list[Detection]) -> np.ndarray:
    """Return a copy of ``rgb`` with each detected ball's circle and centre drawn."""
    image = rgb.copy()
    for detection in detections:
        centre = (round(detection.u), round(detection.v))
        cv2.circle(image, centre, max(1, round(detection.radius)), _DRAW_COLOR, 2,
                   cv2.LINE_AA)
        cv2.drawMarker(image, centre, _DRAW_COLOR, cv2.MARKER_CROSS, 8, 1)
    return image
