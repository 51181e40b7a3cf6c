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
"""

from dataclasses import dataclass
import math

import cv2
import numpy as np

# OpenCV's 8-bit HSV: hue 0-179 (degrees / 2), saturation and value 0-255.
HUE_MAX = 179
SV_MAX = 255

_COARSE_SCALE = 2  # the coarse stage works on every second pixel of every second row
_MAX_CANDIDATES = 6  # largest coarse blobs refined per frame
_RANSAC_HYPOTHESES = 96
_RANSAC_MAX_POINTS = 240  # contour points used to score hypotheses
_MIN_CONTOUR_POINTS = 8
# A contour point lies on the circle within max(_TOL_PX, _TOL_FRACTION * radius) pixels.
_TOL_PX = 1.0
_TOL_FRACTION = 0.04
# Contour points between the circle and _BULGE_LIMIT * radius are "bulge": a polygon's corners.
_BULGE_LIMIT = 1.3
_MAX_BULGE_RATIO = 0.08  # bulge points per on-circle point
_MIN_COVERAGE = 0.4  # fraction of the circumference seen
_COVERAGE_BINS = 36


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
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        (h_lo, s_lo, v_lo), (h_hi, s_hi, v_hi) = self.lower, self.upper
        if h_lo <= h_hi:
            return cv2.inRange(hsv, (h_lo, s_lo, v_lo), (h_hi, s_hi, v_hi))
        return cv2.bitwise_or(cv2.inRange(hsv, (h_lo, s_lo, v_lo), (HUE_MAX, s_hi, v_hi)),
                              cv2.inRange(hsv, (0, s_lo, v_lo), (h_hi, s_hi, v_hi)))


# The sim's default ball, RGBA (1, 0, 0, 1): pure red, darker on its shaded side.
RED = HsvRange((170, 100, 40), (10, 255, 255))
DEFAULT_MIN_RADIUS_PX = 4.0


@dataclass(frozen=True)
class Detection:
    """A ball found in the image, in full-resolution pixel coordinates."""

    u: float  # circle centre, column
    v: float  # circle centre, row
    radius: float  # pixels
    coverage: float  # fraction of the circumference seen, 0-1
    mask: np.ndarray  # bool, ball-colour pixels inside the circle, within the window below
    x0: int  # window origin: mask[i, j] is pixel (x0 + j, y0 + i)
    y0: int

    def pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the columns and rows of the ball-colour pixels inside the circle."""
        rows, cols = np.nonzero(self.mask)
        return cols + self.x0, rows + self.y0


class BallDetector:
    """Finds round blobs of one colour; see the module docstring for the method."""

    def __init__(self, color: HsvRange = RED,
                 min_radius_px: float = DEFAULT_MIN_RADIUS_PX) -> None:
        if not min_radius_px > 0:
            raise ValueError(f'min_radius_px must be positive, got {min_radius_px}')
        self.color = color
        self.min_radius_px = float(min_radius_px)

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """Return the balls in an RGB uint8 image, the most completely seen first."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f'expected an RGB uint8 image, got {rgb.dtype} {rgb.shape}')
        height, width = rgb.shape[:2]
        coarse = self.color.mask(np.ascontiguousarray(rgb[::_COARSE_SCALE, ::_COARSE_SCALE]))
        count, _, stats, _ = cv2.connectedComponentsWithStats(coarse, connectivity=8)
        min_area = max(3.0, 0.25 * math.pi * (self.min_radius_px / _COARSE_SCALE) ** 2)
        blobs = [stats[i] for i in range(1, count) if stats[i, cv2.CC_STAT_AREA] >= min_area]
        blobs.sort(key=lambda s: -s[cv2.CC_STAT_AREA])
        found: list[tuple[int, Detection]] = []
        for x, y, w, h, _ in blobs[:_MAX_CANDIDATES]:
            # Already explained by a ball found from a larger blob (its other half)?
            cu, cv_ = (x + w / 2) * _COARSE_SCALE, (y + h / 2) * _COARSE_SCALE
            if any(math.hypot(cu - d.u, cv_ - d.v) < d.radius for _, d in found):
                continue
            # Window: the blob, grown by its size to take in the rest of a ball cut in two by
            # an occluder (a gripper finger in front of its middle).
            grow = (max(w, h) + 2) * _COARSE_SCALE
            x0 = max(0, x * _COARSE_SCALE - grow)
            y0 = max(0, y * _COARSE_SCALE - grow)
            x1 = min(width, (x + w) * _COARSE_SCALE + grow)
            y1 = min(height, (y + h) * _COARSE_SCALE + grow)
            result = self._refine(rgb, x0, y0, x1, y1)
            if result is not None and not any(
                    math.hypot(result[1].u - d.u, result[1].v - d.v) < d.radius
                    for _, d in found):
                found.append(result)
        found.sort(key=lambda item: -item[0])
        return [detection for _, detection in found]

    def _refine(self, rgb: np.ndarray, x0: int, y0: int, x1: int, y1: int
                ) -> tuple[int, Detection] | None:
        """Fit a circle to the blobs in one window; return (on-circle points, detection)."""
        height, width = rgb.shape[:2]
        mask = self.color.mask(rgb[y0:y1, x0:x1])
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        contours = [c for c in contours if len(c) >= _MIN_CONTOUR_POINTS]
        if not contours:
            return None
        points = np.concatenate(contours).reshape(-1, 2).astype(np.float64)
        points += (x0, y0)
        # The image border cuts a ball like an occluder does: its edge is not the ball's.
        inside = ((points[:, 0] > 0) & (points[:, 0] < width - 1)
                  & (points[:, 1] > 0) & (points[:, 1] < height - 1))
        points = points[inside]
        if len(points) < _MIN_CONTOUR_POINTS:
            return None
        max_radius = max(width, height) / 2
        circle = _ransac_circle(points, self.min_radius_px, max_radius)
        if circle is None:
            return None
        u, v, radius = circle
        tol = max(_TOL_PX, _TOL_FRACTION * radius)
        distance = np.hypot(points[:, 0] - u, points[:, 1] - v)
        on_circle = np.abs(distance - radius) <= tol
        bulge = (distance > radius + tol) & (distance < _BULGE_LIMIT * radius)
        n_on = int(on_circle.sum())
        angles = np.arctan2(points[on_circle, 1] - v, points[on_circle, 0] - u)
        bins = np.unique(((angles + math.pi) / (2 * math.pi) * _COVERAGE_BINS).astype(int)
                         % _COVERAGE_BINS)
        coverage = len(bins) / _COVERAGE_BINS
        if coverage < _MIN_COVERAGE or bulge.sum() > _MAX_BULGE_RATIO * n_on:
            return None
        # Contour points are the blob's outermost pixel centres, half a pixel inside its edge.
        radius += 0.5
        if not self.min_radius_px <= radius <= max_radius:
            return None
        rows, cols = np.mgrid[y0:y1, x0:x1]
        in_circle = np.hypot(cols - u, rows - v) <= radius
        return n_on, Detection(u=float(u), v=float(v), radius=float(radius),
                               coverage=coverage, mask=(mask > 0) & in_circle, x0=x0, y0=y0)


def _ransac_circle(points: np.ndarray, min_radius: float, max_radius: float
                   ) -> tuple[float, float, float] | None:
    """Return the circle (u, v, r) through the most points, refined by least squares."""
    rng = np.random.default_rng(0)  # deterministic: the same frame gives the same answer
    sample = points
    if len(points) > _RANSAC_MAX_POINTS:
        sample = points[rng.choice(len(points), _RANSAC_MAX_POINTS, replace=False)]
    triples = sample[rng.integers(0, len(sample), size=(_RANSAC_HYPOTHESES, 3))]
    centres, radii = _circles_through(triples)
    usable = np.isfinite(radii) & (radii >= 0.8 * min_radius) & (radii <= max_radius)
    if not usable.any():
        return None
    centres, radii = centres[usable], radii[usable]
    tol = np.maximum(_TOL_PX, _TOL_FRACTION * radii)
    distance = np.linalg.norm(sample[None, :, :] - centres[:, None, :], axis=2)
    residual = distance - radii[:, None]
    # Score: points on the circle, minus points bulging out of it (a polygon's corners).
    on_circle = np.abs(residual) <= tol[:, None]
    bulge = (residual > tol[:, None]) & (distance < _BULGE_LIMIT * radii[:, None])
    best = int(np.argmax(on_circle.sum(axis=1) - 2 * bulge.sum(axis=1)))
    u, v, r = centres[best, 0], centres[best, 1], radii[best]
    for _ in range(2):  # least-squares refit on the points of the current circle
        tol = max(_TOL_PX, _TOL_FRACTION * r)
        inliers = points[np.abs(np.hypot(points[:, 0] - u, points[:, 1] - v) - r) <= tol]
        if len(inliers) < 3:
            return None
        u, v, r = _fit_circle(inliers, (u, v, r))
    if not (np.isfinite(r) and 0.8 * min_radius <= r <= max_radius):
        return None
    return float(u), float(v), float(r)


def _circles_through(triples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return centres (M, 2) and radii (M,) of the circles through (M, 3, 2) point triples."""
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    ab, ac = b - a, c - a
    det = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    ab2, ac2 = (ab ** 2).sum(axis=1), (ac ** 2).sum(axis=1)
    with np.errstate(divide='ignore', invalid='ignore'):
        ox = (ac[:, 1] * ab2 - ab[:, 1] * ac2) / det
        oy = (ab[:, 0] * ac2 - ac[:, 0] * ab2) / det
    centres = a + np.stack([ox, oy], axis=1)
    return centres, np.hypot(ox, oy)


def _fit_circle(points: np.ndarray, start: tuple[float, float, float]
                ) -> tuple[float, float, float]:
    """Geometric least-squares circle fit (Gauss-Newton from ``start``)."""
    u, v, r = start
    for _ in range(5):
        dx, dy = points[:, 0] - u, points[:, 1] - v
        distance = np.maximum(np.hypot(dx, dy), 1e-9)
        jacobian = np.column_stack([-dx / distance, -dy / distance, -np.ones(len(points))])
        step, *_ = np.linalg.lstsq(jacobian, -(distance - r), rcond=None)
        u, v, r = u + step[0], v + step[1], r + step[2]
        if abs(step).max() < 1e-3:
            break
    return u, v, r
