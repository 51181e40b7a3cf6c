"""The ball's 3D centre from a registered depth image and the camera intrinsics. No ROS.

Only pixels of the ball's colour inside the detected circle are used, so an occluder in front
of the ball (a gripper finger, an arm link) contributes no depth; mixed pixels on the ball's rim
and anything else that slipped through are dropped as outliers of the sphere fit.

1. Start: along the viewing ray through the circle centre, each ball pixel's depth plus the
   sphere's height over the pixel (``radius * sqrt(1 - rho^2)``, rho = the pixel's distance
   from the centre over the circle radius) estimates the distance to the centre; take the median.
2. Refine: Gauss-Newton fit of a sphere of the known radius to the back-projected pixels,
   trimming points whose residual is far beyond the median absolute deviation.
3. Check: the fitted sphere must explain the depth, and a ball of that radius at that
   distance must look as large as the detected circle. A cube of the ball's colour whose
   outline looks round from afar has flat faces that a ball-sized sphere does not fit, or is
   the wrong size for the ball.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ur_rg2_vision.detector import Detection, least_squares_step

_CORE = 0.85  # use pixels within this fraction of the circle radius (the rim mixes depths)
_MIN_POINTS = 6
_ITERATIONS = 6
_TRIM_SIGMAS = 3.0
_TRIM_FLOOR = 0.001  # m: residuals this close to the median are never trimmed
_FIRST_TRIM_FLOOR = 0.2  # of the radius, in the first round
_MIN_KEPT_FRACTION = 0.6
_MAX_RMS_FRACTION = 0.06  # of the radius: worse fits are not a sphere of that size
_SIZE_TOLERANCE = 1.25  # the detected circle's radius may be this factor off the expected


@dataclass(frozen=True)
class BallPosition:
    """The ball's centre in the camera's optical frame and how well the sphere fits."""

    x: float  # m, right
    y: float  # m, down
    z: float  # m, forward
    rms: float  # m, residual of the sphere fit
    points: int  # depth pixels in the fit


def locate_ball(detection: Detection, depth: np.ndarray, k: np.ndarray,
                ball_radius: float) -> BallPosition | None:
    """Return the centre of the detected ball, or None when the depth does not show a ball.

    ``depth`` is metres along the optical axis, registered to the colour image the detection
    comes from; non-finite and non-positive values mean no return. ``k`` is the 3x3 camera
    matrix, ``ball_radius`` in metres.
    """
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    cols, rows = detection.pixels()
    rho = np.hypot(cols - detection.u, rows - detection.v) / detection.radius
    core = rho <= _CORE
    if core.sum() >= _MIN_POINTS:  # a tiny ball has (almost) no core: use all its pixels
        cols, rows, rho = cols[core], rows[core], rho[core]
    z = depth[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    if valid.sum() < _MIN_POINTS:
        return None
    cols, rows, rho, z = cols[valid], rows[valid], rho[valid], z[valid]
    points = np.column_stack([(cols - cx) / fx * z, (rows - cy) / fy * z, z])
    ray = np.array([(detection.u - cx) / fx, (detection.v - cy) / fy, 1.0])
    ray /= np.linalg.norm(ray)
    distance = np.median(points @ ray + ball_radius * np.sqrt(np.clip(1 - rho ** 2, 0, 1)))
    centre = ray * distance
    keep = np.ones(len(points), dtype=bool)
    floor = _FIRST_TRIM_FLOOR * ball_radius  # the start is a few millimetres off
    for _ in range(_ITERATIONS):
        residual = np.linalg.norm(points - centre, axis=1) - ball_radius
        offset = np.median(residual[keep])
        spread = 1.4826 * np.median(np.abs(residual[keep] - offset))
        keep = np.abs(residual - offset) <= max(_TRIM_SIGMAS * spread, floor)
        if keep.sum() < _MIN_POINTS:
            return None
        centre = _gauss_newton_step(points[keep], centre, ball_radius)
        floor = _TRIM_FLOOR
    residual = np.linalg.norm(points[keep] - centre, axis=1) - ball_radius
    rms = float(np.sqrt(np.mean(residual ** 2)))
    if keep.mean() < _MIN_KEPT_FRACTION or rms > _MAX_RMS_FRACTION * ball_radius:
        return None
    # The sphere's outline is a cone of half-angle asin(radius / distance): on the axis a
    # circle of radius f tan(half-angle). Off the axis by theta, the image is stretched by up to
    # 1 / cos(theta)^2 unless the detector was given the camera matrix to undo that.
    distance = float(np.linalg.norm(centre))
    if not ball_radius < distance:
        return None
    cos_theta = centre[2] / distance
    f_tan = (fx + fy) / 2 * ball_radius / np.sqrt(distance ** 2 - ball_radius ** 2)
    if not (f_tan / _SIZE_TOLERANCE <= detection.radius
            <= f_tan / cos_theta ** 2 * _SIZE_TOLERANCE):
        return None
    return BallPosition(x=float(centre[0]), y=float(centre[1]), z=float(centre[2]), rms=rms,
                        points=int(keep.sum()))


def locate_first(detections: Sequence[Detection], depth: np.ndarray, k: np.ndarray,
                 ball_radius: float) -> BallPosition | None:
    """Return the position of the first detection that the depth confirms as a ball."""
    for detection in detections:
        position = locate_ball(detection, depth, k, ball_radius)
        if position is not None:
            return position
    return None


def _gauss_newton_step(points: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """One Gauss-Newton step of min sum (|p - c| - radius)^2 over the centre c."""
    offset = centre - points
    distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-9)
    return centre + least_squares_step(offset / distance[:, None], distance - radius)
