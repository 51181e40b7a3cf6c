"""A robust circle fit to a blob's contour points: RANSAC, then least squares. No ROS.

:func:`ransac_circle` fits one circle to the contour points of every piece of a blob, leaving
out the points of an occluder's edge; :func:`bulge` counts the points that stick out of it like
a polygon's corners. Used by :class:`ur_rg2_vision.detector.BallDetector`.
"""

import math

import cv2
import numpy as np

_RANSAC_HYPOTHESES = 96
_RANSAC_MAX_POINTS = 240  # contour points used to score hypotheses
# A contour point lies on the circle within max(TOL_PX, TOL_FRACTION * radius) pixels.
TOL_PX = 1.0
TOL_FRACTION = 0.04
# Contour points just outside the circle, by up to _BULGE_FRACTION of the radius or
# _BULGE_TOLS tolerances, are "bulge": a polygon's corners. Farther out is another object.
_BULGE_FRACTION = 0.3
_BULGE_TOLS = 3.0
# Where each RANSAC triple lies on its run: its quantile among all points (which run), and
# its start and spacing as fractions of the run. Fixed: the same frame gives the same answer.
_HYPOTHESIS_QUANTILES = (np.arange(_RANSAC_HYPOTHESES) + 0.5) / _RANSAC_HYPOTHESES
_HYPOTHESIS_STARTS, _HYPOTHESIS_GAPS = np.random.default_rng(0).random((2, _RANSAC_HYPOTHESES))
_TRIPLE = np.arange(3)


class Arcs:
    """Contour points (2, N) off the image border, in runs along their contours."""

    def __init__(self, points: np.ndarray, lengths: np.ndarray, border: np.ndarray) -> None:
        if not border.any():
            self.points, self.lengths = points, lengths
            return
        kept = np.add.reduceat((~border).astype(np.intp), np.cumsum(lengths) - lengths)
        use = np.repeat(kept >= 3, lengths) & ~border
        self.points, self.lengths = points.compress(use, axis=1), kept[kept >= 3]


def distances(points: np.ndarray, u: float, v: float) -> np.ndarray:
    """Return the distances of points (2, N) from (u, v) (np.hypot is several times slower)."""
    dx, dy = points[0] - u, points[1] - v
    return np.sqrt(dx * dx + dy * dy)


def _bulge_limit(radius: np.ndarray | float, tol: np.ndarray | float) -> np.ndarray | float:
    """Return the distance from the centre up to which a point outside is a bulge."""
    return radius + np.maximum(_BULGE_FRACTION * radius, _BULGE_TOLS * tol)


def bulge(distance: np.ndarray, lengths: np.ndarray, border: np.ndarray, radius: float,
           tol: float) -> int:
    """Return how many contour points bulge out of the circle like corners.

    ``distance``: of every point of the closed contours (``lengths`` points each, in turn)
    from the centre. Between two stretches on the circle, a contour either dips inside it
    (an occluder's edge), runs along the image border, leaves for good (another object of
    the ball's colour touching it in the image), or stays just outside: only the last is a
    bulge.
    """
    on = np.abs(distance - radius) <= tol
    excused = ~on & (border | (distance < radius - tol) | (distance > _bulge_limit(radius, tol)))
    bulge = 0
    for start, end in zip(np.cumsum(lengths) - lengths, np.cumsum(lengths)):
        contour_on = on[start:end]
        if not contour_on.any():  # a separate blob in the window
            continue
        # Points between two on-circle points share a number; those before the first one
        # close the contour's last stretch.
        stretch = np.cumsum(contour_on)
        stretch[:int(np.argmax(contour_on))] = stretch[-1]
        spoilt = np.zeros(stretch[-1] + 1, dtype=bool)
        spoilt[stretch[excused[start:end]]] = True
        bulge += int(np.count_nonzero(~contour_on & ~spoilt[stretch]))
    return bulge


def ransac_circle(arcs: Arcs, min_radius: float, max_radius: float
                   ) -> tuple[float, float, float] | None:
    """Return the best-supported circle (u, v, r) through contour points, least-squares refined.

    Hypotheses come from point triples spaced along one run of contour points, so that all
    three usually lie on the same outline (the ball's, not that of an object touching it);
    runs get hypotheses in proportion to their length. A hypothesis scores its on-circle
    points times the fraction of its circumference they cover, less a penalty for points
    bulging out of it: a large circle that grazes a straight edge gets little.
    """
    points, lengths = arcs.points, arcs.lengths
    ends = np.cumsum(lengths)
    which = np.searchsorted(ends, _HYPOTHESIS_QUANTILES * ends[-1], side='right')
    n = lengths[which]
    start = (_HYPOTHESIS_STARTS * n).astype(int)
    shortest = np.maximum(1, n // 24)
    gap = shortest + (_HYPOTHESIS_GAPS * (np.maximum(2, n // 3 + 1) - shortest)).astype(int)
    index = (ends - lengths)[which, None] + (start[:, None] + gap[:, None] * _TRIPLE) % n[:, None]
    centres, radii = _circles_through(points[0, index], points[1, index])
    usable = np.isfinite(radii) & (radii >= 0.8 * min_radius) & (radii <= max_radius)
    if not usable.any():
        return None
    centres, radii = centres.compress(usable, axis=1), radii[usable]
    # Every so many points, evenly along the outlines; float32 keeps the (hypotheses, points)
    # arrays small (allocations of over 128 kB each cost fresh pages from the kernel).
    total = points.shape[1]
    sample = points[:, ::-(-total // _RANSAC_MAX_POINTS)].astype(np.float32)
    scale = total / sample.shape[1]
    centres32 = centres.astype(np.float32)[:, :, None]
    dx = sample[0] - centres32[0]
    dy = sample[1] - centres32[1]
    distance = np.sqrt(dx * dx + dy * dy)
    tol = np.maximum(TOL_PX, TOL_FRACTION * radii)
    residual = distance - radii[:, None].astype(np.float32)
    on_circle = (np.abs(residual) <= tol[:, None]).sum(axis=1) * scale
    bulge = ((residual > tol[:, None]) & (distance < _bulge_limit(radii, tol)[:, None])
             ).sum(axis=1)
    seen = np.minimum(1.0, on_circle / (2 * math.pi * radii))
    best = int(np.argmax((on_circle - 2 * bulge * scale) * seen))
    u, v, r = centres[0, best], centres[1, best], radii[best]
    for _ in range(2):  # least-squares refit on the points of the current circle
        tol = max(TOL_PX, TOL_FRACTION * r)
        inliers = points.compress(np.abs(distances(points, u, v) - r) <= tol, axis=1)
        if inliers.shape[1] < 3:
            return None
        u, v, r = _fit_circle(inliers, (u, v, r))
    if not (np.isfinite(r) and 0.8 * min_radius <= r <= max_radius):
        return None
    return float(u), float(v), float(r)


def _circles_through(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return centres (2, M) and radii (M,) of the circles through (M, 3) point triples."""
    abx, aby = x[:, 1] - x[:, 0], y[:, 1] - y[:, 0]
    acx, acy = x[:, 2] - x[:, 0], y[:, 2] - y[:, 0]
    det = 2.0 * (abx * acy - aby * acx)
    ab2, ac2 = abx * abx + aby * aby, acx * acx + acy * acy
    with np.errstate(divide='ignore', invalid='ignore'):
        ox = (acy * ab2 - aby * ac2) / det
        oy = (abx * ac2 - acx * ab2) / det
    return np.stack([x[:, 0] + ox, y[:, 0] + oy]), np.sqrt(ox * ox + oy * oy)


def least_squares_step(jacobian: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Return the Gauss-Newton step that minimises |jacobian @ step + residual|."""
    solved, step = cv2.solve(jacobian.T @ jacobian, -(jacobian.T @ residual)[:, None],
                             flags=cv2.DECOMP_CHOLESKY)
    if solved:
        return step[:, 0]
    # Degenerate points: least squares still answers.
    return np.linalg.lstsq(jacobian, -residual, rcond=None)[0]


def _fit_circle(points: np.ndarray, start: tuple[float, float, float]
                ) -> tuple[float, float, float]:
    """Geometric least-squares circle fit (Gauss-Newton from ``start``) to points (2, N)."""
    u, v, r = start
    jacobian = np.empty((3, points.shape[1]))  # transposed
    jacobian[2] = -1.0
    offset = jacobian[:2]
    for _ in range(5):
        np.subtract(((u,), (v,)), points, out=offset)
        squares = offset * offset
        distance = np.sqrt(squares[0] + squares[1])
        np.maximum(distance, 1e-9, out=distance)
        offset /= distance
        step = least_squares_step(jacobian.T, distance - r)
        u, v, r = u + step[0], v + step[1], r + step[2]
        if abs(step).max() < 1e-3:
            break
    return u, v, r
