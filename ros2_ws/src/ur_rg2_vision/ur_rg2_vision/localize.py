"""The ball's 3D centre and radius from a registered depth image and the camera intrinsics.

No ROS. Only pixels of the ball's colour inside the detected circle are used, so an occluder in
front of the ball (a gripper finger, an arm link) contributes no depth; mixed pixels on the
ball's rim and anything else that slipped through are dropped as outliers of the sphere fits.

The ball's size is measured, not assumed (unless ``ball_radius`` is given). Two estimates:

1. Outline and depth: the detected circle is the image of the cone tangent to the sphere, of
   half-angle alpha; a sphere of radius ``distance * sin(alpha)`` fills that cone at every
   distance. Each ball pixel's depth fixes the one distance at which that sphere's surface
   passes through it; the middle of the densest cluster of these distances is robust to
   outliers, an occluder over more than half the ball's disc too. Precise to about
   half a pixel of the circle's radius: a few per cent on a small, far ball.
2. Depth alone: a sphere with free centre and radius fitted to the back-projected pixels
   (algebraic least squares on the points near estimate 1, then Gauss-Newton of the geometric
   residuals, trimming points far beyond their median absolute deviation). Precise where the
   ball covers many pixels; on a small cap its radius is uncertain. Its uncertainty: the fit's
   covariance, the residuals' rms, and a few per cent for a surface that is no perfect sphere.

The two must agree (in curvature, within their uncertainties): a flat patch of the ball's colour
has the outline of a ball but no curvature, a cube's faces have the wrong one. The radius is
their inverse-variance weighted mean. A final fit of a sphere of that radius gives the centre,
which must explain the depth (residuals), lie behind the surface it was fitted to, and look as
large as the detected circle. A ball partly hidden is found: the points the fit leaves out may
be an occluder in front of it, not depth seen behind its front surface.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math

import cv2
import numpy as np

from ur_rg2_vision.circle_fit import least_squares_step
from ur_rg2_vision.detector import Detection

_CORE = 0.85  # use pixels within this fraction of the circle radius (the rim mixes depths)
_MIN_POINTS = 6
_MAX_POINTS = 800  # surface points fitted: plenty for sub-millimetre fits, bounded time
_ITERATIONS = 6
_CONVERGED = 1e-5  # m: a step this small with the same points kept ends a fit
_TRIM_SIGMAS = 3.0
_TRIM_FLOOR = 0.001  # m: residuals this close to the median are never trimmed
_FIRST_TRIM_FLOOR = 0.2  # of the radius, in the first round
_MIN_KEPT_FRACTION = 0.4  # of the points: the rest may be an occluder in front of the ball,
_MAX_SEEN_THROUGH = 0.2  # ... but no more than this share seen behind its front surface
_THROUGH_TOLERANCE = 0.1  # of the radius: behind the front surface by more than this
_ESTIMATE_WINDOW = 0.2  # of the radius: the distance estimates of one sphere's points agree
_MAX_RMS_FRACTION = 0.06  # of the radius: worse fits are not a sphere of that size
_SIZE_TOLERANCE = 1.25  # the detected circle's radius may be this factor off the expected
_MIN_RADIUS = 0.005  # m: the range of balls measured (the sim makes 0.005-0.5 m)
_MAX_RADIUS = 0.5
_CIRCLE_SIGMA_PX = 0.5  # uncertainty of the detected circle's radius
_AGREE_SIGMAS = 3.0  # the two radius estimates agree within this many standard deviations
_AGREE_FRACTION = 0.15  # ... plus this fraction of the curvature (model error)
_MIN_CENTRE_BEHIND = 0.4  # of the radius: the centre behind the median surface point
# Of the radius: a real surface is no perfect sphere (a rendered one is a polyhedron inside it,
# a sensor smooths and warps it), and that error does not average out over pixels.
_SURFACE_MODEL_ERROR = 0.04


@dataclass(frozen=True)
class BallPosition:
    """The ball's centre in the camera's optical frame, its radius, how well the sphere fits."""

    x: float  # m, right
    y: float  # m, down
    z: float  # m, forward
    radius: float  # m: measured, or the radius given
    rms: float  # m, residual of the sphere fit
    points: int  # depth pixels in the fit


@dataclass(frozen=True)
class _Fit:
    centre: np.ndarray
    radius: float
    keep: np.ndarray  # bool, the points not trimmed
    rms: float
    radius_sigma: float  # m, standard deviation of a free radius (0 when it was fixed)


def locate_ball(detection: Detection, depth: np.ndarray, k: np.ndarray,
                ball_radius: float = 0.0) -> BallPosition | None:
    """Return the centre of the detected ball, or None when the depth does not show a ball.

    ``depth`` is metres along the optical axis, registered to the colour image the detection
    comes from; non-finite and non-positive values mean no return. ``k`` is the 3x3 camera
    matrix. ``ball_radius`` in metres fixes the radius; 0 measures it.
    """
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    # A large ball: a grid of its pixels, still about twice as many core pixels as are used.
    core_pixels = math.pi * (_CORE * detection.radius) ** 2
    cols, rows = detection.pixels(max(1, int(math.sqrt(core_pixels / (2 * _MAX_POINTS)))))
    du, dv = cols - detection.u, rows - detection.v
    core = du * du + dv * dv <= (_CORE * detection.radius) ** 2
    if np.count_nonzero(core) >= _MIN_POINTS:  # a tiny ball has (almost) no core: use all
        cols, rows = cols[core], rows[core]
    if len(cols) > _MAX_POINTS:  # an even spread over the ball, the same for the same frame
        pick = np.linspace(0, len(cols) - 1, _MAX_POINTS).astype(int)
        cols, rows = cols[pick], rows[pick]
    z = depth[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    if np.count_nonzero(valid) < _MIN_POINTS:
        return None
    cols, rows, z = cols[valid], rows[valid], z[valid]
    # Coordinates as rows (3, N): the fits' arithmetic runs on contiguous arrays.
    points = np.empty((3, len(z)))
    np.multiply((cols - cx) / fx, z, out=points[0])
    np.multiply((rows - cy) / fy, z, out=points[1])
    points[2] = z
    ray = np.array([(detection.u - cx) / fx, (detection.v - cy) / fy, 1.0])
    ray /= np.linalg.norm(ray)
    along = ray @ points
    lateral2 = np.maximum(np.einsum('ij,ij->j', points, points) - along * along, 0.0)
    focal = (fx + fy) / 2
    # The sphere's outline is a cone of half-angle asin(radius / distance), on the axis a
    # circle of radius f tan(half-angle): the detector reports it as if seen on the axis.
    sin_alpha = math.sin(math.atan(detection.radius / focal))
    if ball_radius > 0:
        radius = ball_radius
        # Start: along the viewing ray, each pixel's depth fixes where the centre of a sphere
        # of that radius through it lies; the median.
        start = ray * _median(along + np.sqrt(np.maximum(radius ** 2 - lateral2, 0.0)))
        fit = _robust_fit(points, start, radius, free_radius=False)
    else:
        measured = _measure_radius(points, ray, along, lateral2, sin_alpha, focal)
        if measured is None:
            return None
        radius, free = measured
        # Start: the free fit's sphere, grown or shrunk away from its front.
        start = free.centre * (1 + (radius - free.radius) / np.linalg.norm(free.centre))
        fit = _robust_fit(points, start, radius, free_radius=False, keep=free.keep)
    if fit is None or not _is_sphere(points, fit) or not _hidden_at_most_in_part(points, fit):
        return None
    centre = fit.centre
    distance = float(np.linalg.norm(centre))
    if not radius < distance:
        return None
    # Off the axis by theta, the image is stretched by up to 1 / cos(theta)^2 unless the
    # detector was given the camera matrix to undo that.
    cos_theta = centre[2] / distance
    f_tan = focal * radius / math.sqrt(distance ** 2 - radius ** 2)
    if not (f_tan / _SIZE_TOLERANCE <= detection.radius
            <= f_tan / cos_theta ** 2 * _SIZE_TOLERANCE):
        return None
    return BallPosition(x=float(centre[0]), y=float(centre[1]), z=float(centre[2]),
                        radius=float(radius), rms=fit.rms,
                        points=int(np.count_nonzero(fit.keep)))


def locate_first(detections: Sequence[Detection], depth: np.ndarray, k: np.ndarray,
                 ball_radius: float = 0.0) -> BallPosition | None:
    """Return the position of the first detection that the depth confirms as a ball."""
    for detection in detections:
        position = locate_ball(detection, depth, k, ball_radius)
        if position is not None:
            return position
    return None


def _measure_radius(points: np.ndarray, ray: np.ndarray, along: np.ndarray,
                    lateral2: np.ndarray, sin_alpha: float, focal: float
                    ) -> tuple[float, _Fit] | None:
    """Return (radius, the free fit) from outline and depth; None when the two disagree.

    ``points``: (3, N) coordinates.
    """
    # 1. The sphere of radius distance * sin(alpha) through each point: solve
    #    |p - distance * ray| = distance * sin(alpha) for the distance.
    cone = 1 - sin_alpha ** 2
    estimates = (along + np.sqrt(np.maximum(sin_alpha ** 2 * (along ** 2 + lateral2) - lateral2,
                                            0.0))) / cone
    distance = _densest(estimates, _ESTIMATE_WINDOW * sin_alpha)
    outline_radius = distance * sin_alpha
    # Half a pixel on the circle's radius moves the radius by about distance / f / cone.
    outline_sigma = distance * _CIRCLE_SIGMA_PX / focal / cone
    # 2. Depth alone, from the points near estimate 1.
    centre = ray * distance
    residual = _SphereJacobian(points, free_radius=False).update(centre, outline_radius)
    near = np.abs(residual) <= _FIRST_TRIM_FLOOR * outline_radius
    if np.count_nonzero(near) < _MIN_POINTS:
        return None
    centre, radius = _algebraic_sphere(points.compress(near, axis=1), centre, outline_radius)
    fit = _robust_fit(points, centre, radius, free_radius=True, keep=near)
    if fit is None or not np.isfinite(fit.radius_sigma) or fit.radius <= 0:
        return None
    # Agreement in curvature, where a plane (curvature 0, radius unbounded) is not a special
    # case: 1/r has the uncertainty sigma_r / r^2.
    disagreement = abs(1 / fit.radius - 1 / outline_radius)
    allowed = (_AGREE_SIGMAS * math.hypot(fit.radius_sigma / fit.radius ** 2,
                                          outline_sigma / outline_radius ** 2)
               + _AGREE_FRACTION / outline_radius)
    if disagreement > allowed:
        return None
    weights = 1 / fit.radius_sigma ** 2, 1 / outline_sigma ** 2
    radius = (weights[0] * fit.radius + weights[1] * outline_radius) / sum(weights)
    if not _MIN_RADIUS <= radius <= _MAX_RADIUS:
        return None
    return float(radius), fit


def _densest(values: np.ndarray, width: float) -> float:
    """Return the median of the values in the window of relative ``width`` that holds most.

    The robust middle of a cluster when outliers may be the majority: the estimates of a ball's
    points agree, an occluder's in front of it spread.
    """
    ordered = np.sort(values)
    counts = np.searchsorted(ordered, ordered * (1 + width), side='right') - np.arange(
        len(ordered))
    start = int(np.argmax(counts))
    return float(ordered[start + counts[start] // 2])


def _median(values: np.ndarray) -> float:
    """Return the (upper) median: np.median's checks cost more than the partition here."""
    middle = len(values) // 2
    return float(np.partition(values, middle)[middle])


def _algebraic_sphere(points: np.ndarray, centre: np.ndarray, radius: float
                      ) -> tuple[np.ndarray, float]:
    """Return the least-squares sphere of |p|^2 = 2 c.p + d; the start given if degenerate.

    ``points``: (3, N). Linear, so it needs no start, but it weighs points unevenly: a start
    for the geometric fit.
    """
    offset = points.mean(axis=1)  # conditioning: points around the origin
    design = np.empty((4, points.shape[1]))
    np.subtract(points, offset[:, None], out=design[:3])
    target = np.einsum('ij,ij->j', design[:3], design[:3])
    design[:3] *= 2
    design[3] = 1.0
    solved, solution = cv2.solve(design @ design.T, (design @ target)[:, None],
                                 flags=cv2.DECOMP_CHOLESKY)
    if not solved:
        return centre, radius
    solution = solution[:, 0]
    squared = solution[3] + solution[:3] @ solution[:3]
    if not (np.isfinite(squared) and squared > 0):
        return centre, radius
    return solution[:3] + offset, float(np.sqrt(squared))


def _robust_fit(points: np.ndarray, centre: np.ndarray, radius: float, free_radius: bool,
                keep: np.ndarray | None = None) -> _Fit | None:
    """Gauss-Newton sphere fit with trimming; the radius fixed unless ``free_radius``.

    ``points``: (3, N). ``keep``: the points a fit close to this start kept; without it, the
    start may be a few millimetres off and the first round trims only points far off.
    """
    if keep is None:
        kept, floor = np.ones(points.shape[1], dtype=bool), _FIRST_TRIM_FLOOR * radius
    else:
        kept, floor = keep, _TRIM_FLOOR
    jacobian = _SphereJacobian(points, free_radius)
    for _ in range(_ITERATIONS):
        residual = jacobian.update(centre, radius)
        kept_residual = residual[kept]
        offset = _median(kept_residual)
        spread = 1.4826 * _median(np.abs(kept_residual - offset))
        keep = np.abs(residual - offset) <= max(_TRIM_SIGMAS * spread, floor)
        if np.count_nonzero(keep) < _MIN_POINTS:
            return None
        step = jacobian.step(keep, residual)
        centre = centre + step[:3]
        if free_radius:
            radius += step[3]
        floor = _TRIM_FLOOR
        converged = np.abs(step).max() < _CONVERGED and np.array_equal(keep, kept)
        kept = keep
        if converged:
            break
    residual = jacobian.update(centre, radius)[kept]
    rms = math.sqrt(residual @ residual / len(residual))
    sigma = 0.0
    if free_radius:
        columns = jacobian.columns.compress(kept, axis=1)
        try:
            covariance = np.linalg.inv(columns @ columns.T)
        except np.linalg.LinAlgError:
            return None
        # Residuals of a real surface are not independent (a rendered sphere's faces, a
        # sensor's correlated noise): the radius is known no better than their rms.
        sigma = math.hypot(rms * math.sqrt(max(covariance[3, 3], 0.0)), rms,
                           _SURFACE_MODEL_ERROR * radius)
    return _Fit(centre, float(radius), kept, rms, sigma)


def _is_sphere(points: np.ndarray, fit: _Fit) -> bool:
    """Return whether the fitted sphere explains the depth and lies behind the surface."""
    if fit.rms > _MAX_RMS_FRACTION * fit.radius:
        return False
    distance = np.linalg.norm(fit.centre)
    # A concave or flat surface can be fitted from the wrong side; a ball faces the camera.
    surface = _median((fit.centre / distance) @ points.compress(fit.keep, axis=1))
    return bool(distance - surface >= _MIN_CENTRE_BEHIND * fit.radius)


def _hidden_at_most_in_part(points: np.ndarray, fit: _Fit) -> bool:
    """Return whether the fitted sphere explains enough points and the rest are in front of it.

    A ball partly hidden loses the points of its occluder, in front of it; a point behind its
    front surface, on a ray through its disc, would be seen through the ball.
    """
    count = points.shape[1]
    if np.count_nonzero(fit.keep) < _MIN_KEPT_FRACTION * count:
        return False
    ranges = np.sqrt(np.einsum('ij,ij->j', points, points))
    along = fit.centre @ points / ranges
    disc = along * along - fit.centre @ fit.centre + fit.radius ** 2
    front = along - np.sqrt(np.maximum(disc, 0.0))
    behind = (disc > 0) & (ranges > front + _THROUGH_TOLERANCE * fit.radius)
    return np.count_nonzero(behind) <= _MAX_SEEN_THROUGH * count


class _SphereJacobian:
    """|p - centre| - radius and its Jacobian over the centre (and the radius), for points."""

    def __init__(self, points: np.ndarray, free_radius: bool) -> None:
        self.points = points  # (3, N)
        self.columns = np.empty((4 if free_radius else 3, points.shape[1]))  # transposed
        if free_radius:
            self.columns[3] = -1.0

    def update(self, centre: np.ndarray, radius: float) -> np.ndarray:
        """Fill the Jacobian in for a sphere; return its residuals."""
        offset = self.columns[:3]
        np.subtract(centre[:, None], self.points, out=offset)
        squares = offset * offset
        distance = np.sqrt(squares[0] + squares[1] + squares[2])
        np.maximum(distance, 1e-9, out=distance)
        offset /= distance
        return distance - radius

    def step(self, rows: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """Return the Gauss-Newton step on the chosen rows (bool) from the last update."""
        # compress: several times faster than a boolean index along the second axis
        return least_squares_step(self.columns.compress(rows, axis=1).T, residual[rows])
