"""The image box of a ball: the outline of a projected sphere, as the data set labels it.

Off the optical axis the outline of a sphere is an ellipse (the cone of rays tangent to the
sphere, cut by the image plane), so the box is found from the four planes through the optical
centre that touch the sphere and contain an image row or column, not from the projected centre
and a radius. The learned detector's sphere fit (:mod:`ur_rg2_vision.learned`) and the data
set's labels (:mod:`ur_rg2_vision.dataset`) share it.
"""

from collections.abc import Sequence
import math

import numpy as np


def sphere_box(center: Sequence[float], radius: float, k: np.ndarray
               ) -> tuple[float, float, float, float] | None:
    """Return the image box (u0, v0, u1, v1) of a sphere, in pixel coordinates, unclipped.

    ``center`` is in the optical frame (x right, y down, z forward), ``k`` the 3x3 camera
    matrix; pixel (u, v) has its centre at integer coordinates (ROS). A plane through the
    optical centre containing the image line x/z = a is tangent to the sphere when its distance
    to the centre equals the radius: (cx - a cz)^2 = r^2 (1 + a^2), a quadratic in a whose two
    roots are the outline's extremes; likewise for y. None when the sphere reaches behind the
    optical centre's plane (z <= r): its outline is then no closed curve.
    """
    cx, cy, cz = (float(c) for c in center)
    r = float(radius)
    if cz <= r:
        return None
    denominator = cz * cz - r * r
    extremes = []
    for c in (cx, cy):
        root = r * math.sqrt(c * c + denominator)
        extremes.append(((c * cz - root) / denominator, (c * cz + root) / denominator))
    (x0, x1), (y0, y1) = extremes
    fx, fy, px, py = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    return fx * x0 + px, fy * y0 + py, fx * x1 + px, fy * y1 + py
