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

# OpenCV's 8-bit HSV: hue 0-179 (degrees / 2), saturation and value 0-255.
HUE_MAX = 179
SV_MAX = 255

_COARSE_SCALE = 2  # the coarse stage works on every second pixel of every second row
_MAX_CANDIDATES = 6  # largest coarse blobs refined per frame
_RANSAC_HYPOTHESES = 96
_RANSAC_MAX_POINTS = 240  # contour points used to score hypotheses
_MIN_CONTOUR_POINTS = 8
_MAX_PIECES = 8  # outlines per window, longest first
# A contour point lies on the circle within max(_TOL_PX, _TOL_FRACTION * radius) pixels.
_TOL_PX = 1.0
_TOL_FRACTION = 0.04
# Contour points just outside the circle, by up to _BULGE_FRACTION of the radius or
# _BULGE_TOLS tolerances, are "bulge": a polygon's corners. Farther out is another object.
_BULGE_FRACTION = 0.3
_BULGE_TOLS = 3.0
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

    u: float  # the ball centre's image, column
    v: float  # the ball centre's image, row
    radius: float  # pixels, as if the ball were on the optical axis (see the module docstring)
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

    def detect(self, rgb: np.ndarray, k: np.ndarray | None = None) -> list[Detection]:
        """Return the balls in an RGB uint8 image, the most completely seen first.

        ``k``: the 3x3 camera matrix. Without it, outlines are taken as seen on the axis.
        """
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f'expected an RGB uint8 image, got {rgb.dtype} {rgb.shape}')
        height, width = rgb.shape[:2]
        small = cv2.resize(rgb, (width // _COARSE_SCALE, height // _COARSE_SCALE),
                           interpolation=cv2.INTER_NEAREST)
        coarse = self.color.mask(small)
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
            # an occluder (a gripper finger in front of its middle).
            grow = (max(w, h) + 2) * _COARSE_SCALE
            x0 = max(0, x * _COARSE_SCALE - grow)
            y0 = max(0, y * _COARSE_SCALE - grow)
            x1 = min(width, (x + w) * _COARSE_SCALE + grow)
            y1 = min(height, (y + h) * _COARSE_SCALE + grow)
            result = self._refine(rgb, k, x0, y0, x1, y1)
            if result is not None and not any(
                    math.hypot(result[1].u - d.u, result[1].v - d.v) < d.radius
                    for _, d in found):
                found.append(result)
        found.sort(key=lambda item: -item[0])
        return [detection for _, detection in found]

    def _refine(self, rgb: np.ndarray, k: np.ndarray | None, x0: int, y0: int, x1: int,
                y1: int) -> tuple[int, Detection] | None:
        """Fit a circle to the blobs in one window; return (on-circle points, detection)."""
        height, width = rgb.shape[:2]
        mask = self.color.mask(rgb[y0:y1, x0:x1])
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        # The longest outlines only: a ball is in at most a few pieces; this bounds the work
        # on cluttered frames.
        contours = sorted((c for c in contours if len(c) >= _MIN_CONTOUR_POINTS),
                          key=len, reverse=True)[:_MAX_PIECES]
        if not contours:
            return None
        contours = [c.reshape(-1, 2) + (x0, y0) for c in contours]
        # The image border cuts a ball like an occluder does: its edge is not the ball's.
        borders = [(c[:, 0] <= 0) | (c[:, 0] >= width - 1) | (c[:, 1] <= 0)
                   | (c[:, 1] >= height - 1) for c in contours]
        view = _BallView(k, *np.concatenate(contours).mean(axis=0))
        contours = [view.from_image(c.astype(np.float64)) for c in contours]
        arcs = [c[~b] for c, b in zip(contours, borders) if (~b).sum() >= 3]
        if sum(len(a) for a in arcs) < _MIN_CONTOUR_POINTS:
            return None
        points = np.concatenate(arcs)
        max_radius = max(width, height) / 2
        circle = _ransac_circle(arcs, self.min_radius_px, max_radius)
        if circle is None:
            return None
        cu, cv_, radius = circle
        tol = max(_TOL_PX, _TOL_FRACTION * radius)
        on_circle = np.abs(np.hypot(points[:, 0] - cu, points[:, 1] - cv_) - radius) <= tol
        n_on = int(on_circle.sum())
        angles = np.arctan2(points[on_circle, 1] - cv_, points[on_circle, 0] - cu)
        bins = np.unique(((angles + math.pi) / (2 * math.pi) * _COVERAGE_BINS).astype(int)
                         % _COVERAGE_BINS)
        coverage = len(bins) / _COVERAGE_BINS
        bulge = sum(_bulge(c, b, cu, cv_, radius, tol) for c, b in zip(contours, borders))
        if coverage < _MIN_COVERAGE or bulge > _MAX_BULGE_RATIO * n_on:
            return None
        # Contour points are the blob's outermost pixel centres, half a pixel inside its edge.
        radius += 0.5
        if not self.min_radius_px <= radius <= max_radius:
            return None
        u, v = view.to_image(cu, cv_)
        # Ball-colour pixels inside the outline, around it (an ellipse within 1.3 radii).
        reach = int(1.3 * radius) + 2
        bx0, by0 = max(x0, int(u) - reach), max(y0, int(v) - reach)
        bx1, by1 = min(x1, int(u) + reach + 1), min(y1, int(v) + reach + 1)
        if bx0 >= bx1 or by0 >= by1:
            return None
        rows, cols = np.mgrid[by0:by1, bx0:bx1]
        grid = view.from_image(np.column_stack([cols.ravel(), rows.ravel()]).astype(np.float64))
        inside = (np.hypot(grid[:, 0] - cu, grid[:, 1] - cv_) <= radius).reshape(rows.shape)
        ball_mask = (mask[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] > 0) & inside
        return n_on, Detection(u=float(u), v=float(v), radius=float(radius),
                               coverage=coverage, mask=ball_mask, x0=bx0, y0=by0)


class _BallView:
    """Pixel coordinates of a virtual camera turned to look straight at one image point.

    Same focal length and centre as the real camera; only the rotation differs, so the image
    of a sphere centred on the new axis is a circle. The identity without a camera matrix.
    """

    def __init__(self, k: np.ndarray | None, u: float, v: float) -> None:
        self.k = k
        if k is None:
            return
        self.f = (k[0, 0] + k[1, 1]) / 2
        ray = self._rays(np.array([[u, v]]))[0]
        ray /= np.linalg.norm(ray)
        # Rodrigues: the rotation taking the ray onto the optical axis.
        axis = np.cross(ray, [0.0, 0.0, 1.0])
        sin, cos = np.linalg.norm(axis), ray[2]
        self.rotation = np.eye(3)
        if sin > 1e-12:
            x, y, z = axis / sin
            cross = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
            self.rotation += sin * cross + (1 - cos) * cross @ cross

    def _rays(self, points: np.ndarray) -> np.ndarray:
        k = self.k
        return np.column_stack([(points[:, 0] - k[0, 2]) / k[0, 0],
                                (points[:, 1] - k[1, 2]) / k[1, 1], np.ones(len(points))])

    def from_image(self, points: np.ndarray) -> np.ndarray:
        """Return (N, 2) image points in the virtual view's pixels."""
        if self.k is None:
            return points
        rays = self._rays(points) @ self.rotation.T
        return self.f * rays[:, :2] / rays[:, 2:]

    def to_image(self, x: float, y: float) -> tuple[float, float]:
        """Return the image point of a point of the virtual view."""
        if self.k is None:
            return x, y
        ray = self.rotation.T @ [x / self.f, y / self.f, 1.0]
        k = self.k
        return k[0, 0] * ray[0] / ray[2] + k[0, 2], k[1, 1] * ray[1] / ray[2] + k[1, 2]


def _bulge_limit(radius: np.ndarray | float, tol: np.ndarray | float) -> np.ndarray | float:
    """Return the distance from the centre up to which a point outside is a bulge."""
    return radius + np.maximum(_BULGE_FRACTION * radius, _BULGE_TOLS * tol)


def _bulge(contour: np.ndarray, border: np.ndarray, u: float, v: float, radius: float,
           tol: float) -> int:
    """Return how many points of a closed contour bulge out of the circle like corners.

    Between two stretches on the circle, the contour either dips inside it (an occluder's
    edge), runs along the image border, leaves for good (another object of the ball's colour
    touching it in the image), or stays just outside: only the last is a bulge.
    """
    distance = np.hypot(contour[:, 0] - u, contour[:, 1] - v)
    on = np.abs(distance - radius) <= tol
    if not on.any():  # a separate blob in the window
        return 0
    start = int(np.argmax(on))  # walk the closed contour from a point on the circle
    distance, on, border = (np.roll(a, -start) for a in (distance, on, border))
    stretch = np.cumsum(on)  # points between two on-circle points share a number
    excused = ~on & (border | (distance < radius - tol) | (distance > _bulge_limit(radius, tol)))
    return int((~on & ~np.isin(stretch, stretch[excused])).sum())


def _ransac_circle(arcs: list[np.ndarray], min_radius: float, max_radius: float
                   ) -> tuple[float, float, float] | None:
    """Return the best-supported circle (u, v, r) through contour points, least-squares refined.

    ``arcs`` are ordered runs of contour points. Hypotheses come from point triples spaced
    along one run, so that all three usually lie on the same outline (the ball's, not that of
    an object touching it). A hypothesis scores its on-circle points times the fraction of
    its circumference they cover, less a penalty for points bulging out of it: a large circle
    that grazes a straight edge gets little.
    """
    rng = np.random.default_rng(0)  # deterministic: the same frame gives the same answer
    lengths = np.array([len(a) for a in arcs])
    points = np.concatenate(arcs)
    which = rng.choice(len(arcs), size=_RANSAC_HYPOTHESES, p=lengths / lengths.sum())
    n = lengths[which]
    start = rng.integers(0, n)
    gap = rng.integers(np.maximum(1, n // 24), np.maximum(2, n // 3 + 1))
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]])[which]
    index = offsets[:, None] + (start[:, None] + gap[:, None] * np.arange(3)) % n[:, None]
    centres, radii = _circles_through(points[index])
    usable = np.isfinite(radii) & (radii >= 0.8 * min_radius) & (radii <= max_radius)
    if not usable.any():
        return None
    centres, radii = centres[usable], radii[usable]
    sample = points
    if len(points) > _RANSAC_MAX_POINTS:
        sample = points[rng.choice(len(points), _RANSAC_MAX_POINTS, replace=False)]
    tol = np.maximum(_TOL_PX, _TOL_FRACTION * radii)[:, None]
    # hypot of the two coordinate differences: a third of the time of norm over an axis.
    distance = np.hypot(sample[None, :, 0] - centres[:, 0, None],
                        sample[None, :, 1] - centres[:, 1, None])
    residual = distance - radii[:, None]
    scale = len(points) / len(sample)
    on_circle = (np.abs(residual) <= tol).sum(axis=1) * scale
    bulge = ((residual > tol) & (distance < _bulge_limit(radii[:, None], tol))).sum(axis=1)
    seen = np.minimum(1.0, on_circle / (2 * math.pi * radii))
    best = int(np.argmax((on_circle - 2 * bulge * scale) * seen))
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


def least_squares_step(jacobian: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Return the Gauss-Newton step that minimises |jacobian @ step + residual|."""
    normal = jacobian.T @ jacobian
    try:
        return np.linalg.solve(normal, -(jacobian.T @ residual))
    except np.linalg.LinAlgError:  # degenerate points: least squares still answers
        return np.linalg.lstsq(jacobian, -residual, rcond=None)[0]


def _fit_circle(points: np.ndarray, start: tuple[float, float, float]
                ) -> tuple[float, float, float]:
    """Geometric least-squares circle fit (Gauss-Newton from ``start``)."""
    u, v, r = start
    for _ in range(5):
        dx, dy = points[:, 0] - u, points[:, 1] - v
        distance = np.maximum(np.hypot(dx, dy), 1e-9)
        jacobian = np.column_stack([-dx / distance, -dy / distance, -np.ones(len(points))])
        step = least_squares_step(jacobian, distance - r)
        u, v, r = u + step[0], v + step[1], r + step[2]
        if abs(step).max() < 1e-3:
            break
    return u, v, r
