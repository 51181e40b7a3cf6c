"""Universal Robots' DH tables and the closed-form forward and inverse kinematics. Plain Python.

The arm is described by Universal Robots' published DH parameters. The DH base frame is the
UR controller's ``base`` frame (ROS's ``base``, 180 degrees about z from ``base_link``) and the
DH flange frame is ``tool0``. The inverse is the analytic solution of K. P. Hawkins, "Analytic
Inverse Kinematics for the Universal Robots UR-5/UR-10 Arms" (2013), the one behind ROS's
ur_kinematics: shoulder pan from the wrist centre's distance to the base axis, wrist 2 from
the flange's height along the shoulder's axis, wrist 3 from the flange's orientation, then the
planar shoulder-elbow-wrist 1 triangle. Two choices each for shoulder, wrist and elbow give up
to 8 solutions. Forward kinematics is vectorised with numpy (many joint vectors, or every
frame of the chain, at once); the inverse is scalar, which for one pose is faster.

:class:`KinematicsError` is the error of every check of ur_rg2_motion.kinematics.
"""

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
import math

import numpy as np

# Below this wrist 1 and wrist 3 lose a degree of freedom (see inverse).
_WRIST_SINGULAR = 1e-9  # |sin(wrist_2)|: wrist 1 and wrist 3 axes parallel
# acos arguments this far beyond +-1 are rounding, not an unreachable pose.
_ACOS_SLACK = 1e-9


@dataclass(frozen=True)
class DhParameters:
    """Universal Robots' DH parameters of one arm model, metres."""

    d1: float
    a2: float
    a3: float
    d4: float
    d5: float
    d6: float

    @property
    def a(self) -> np.ndarray:
        """Link lengths a_i."""
        return np.array([0.0, self.a2, self.a3, 0.0, 0.0, 0.0])

    @property
    def d(self) -> np.ndarray:
        """Link offsets d_i."""
        return np.array([self.d1, 0.0, 0.0, self.d4, self.d5, self.d6])


# From Universal Robots' "DH parameters for calculations of kinematics and dynamics" (the same
# values as ur_description's config/<model>/default_kinematics.yaml).
UR_DH = {
    'ur5': DhParameters(0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    'ur3': DhParameters(0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    'ur5e': DhParameters(0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    'ur3e': DhParameters(0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
}
_ALPHA = np.array([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])
_COS_ALPHA = np.round(np.cos(_ALPHA))  # exactly 0 and +-1, as the DH table means
_SIN_ALPHA = np.round(np.sin(_ALPHA))


class KinematicsError(ValueError):
    """A target pose has no acceptable joint solution; ``reason`` says which check failed.

    Reasons: ``invalid`` (not a finite rigid transform), ``unreachable`` (out of the arm's
    reach), ``singular`` (on the workspace boundary, where the arm loses a degree of freedom),
    ``joint_limits``, ``floor`` (the arm or the TCP would go below the floor), ``pedestal``.
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def forward(dh: DhParameters, q: np.ndarray, all_frames: bool = False) -> np.ndarray:
    """Return the DH base -> flange transforms (..., 4, 4) of joint vectors ``q`` (..., 6).

    With ``all_frames`` the result is (..., 6, 4, 4): base -> frame i for i = 1..6.
    """
    q = np.asarray(q, dtype=float)
    ct, st = np.cos(q), np.sin(q)
    zero, one = np.zeros_like(q), np.ones_like(q)
    links = np.stack([
        ct, -st * _COS_ALPHA, st * _SIN_ALPHA, dh.a * ct,
        st, ct * _COS_ALPHA, -ct * _SIN_ALPHA, dh.a * st,
        zero, zero + _SIN_ALPHA, zero + _COS_ALPHA, zero + dh.d,
        zero, zero, zero, one,
    ], axis=-1).reshape(q.shape + (4, 4))
    frames = [links[..., 0, :, :]]
    for i in range(1, 6):
        frames.append(frames[-1] @ links[..., i, :, :])
    return np.stack(frames, axis=-3) if all_frames else frames[-1]


def inverse(dh: DhParameters, pose: np.ndarray, wrist_3: float = 0.0) -> list[tuple]:
    """Return every joint solution (up to 8 tuples of 6, in [-pi, pi]) of a flange pose.

    ``pose`` is DH base -> flange (4x4). Branches: shoulder left/right x wrist up/down x elbow
    up/down, the ones that exist. Where wrist 1 and wrist 3 are aligned (wrist 2 at 0 or pi)
    only their sum is defined: wrist 3 is then set to ``wrist_3`` (the current one keeps the
    wrist still). Scalar arithmetic: for one pose it is several times faster than numpy.
    """
    return [q for _, solutions in inverse_by_shoulder(dh, pose, wrist_3) for q in solutions()]


def inverse_by_shoulder(dh: DhParameters, pose: np.ndarray,
                        wrist_3: float = 0.0) -> list[tuple[float, Callable[[], list[tuple]]]]:
    """Return :func:`inverse`'s solutions by shoulder pan: (pan in [-pi, pi], its solutions).

    The second of each pair computes that pan's (up to 4) solutions when called: a search for
    the solution nearest some joints can skip a pan already too far from them.
    """
    rows = pose.tolist()[:3]
    (_, _, zx, px), (_, _, zy, py) = rows[:2]
    d4, d6 = dh.d4, dh.d6
    # Shoulder pan: the wrist centre (flange minus d6 along z) lies d4 off the arm's plane.
    wx, wy = px - d6 * zx, py - d6 * zy
    radius = math.hypot(wx, wy)
    if radius == 0.0 or abs(d4) > radius * (1 + _ACOS_SLACK):
        return []
    spread = math.acos(min(d4 / radius, 1.0))
    heading = math.atan2(wy, wx) + math.pi / 2
    return [(math.remainder(q1, 2 * math.pi), partial(_pan_solutions, dh, rows, q1, wrist_3))
            for q1 in (heading + spread, heading - spread)]


def _pan_solutions(dh: DhParameters, rows: list[list[float]], q1: float,
                   wrist_3: float) -> list[tuple]:
    """Return the solutions (up to 4) with shoulder pan ``q1``: see :func:`inverse`."""
    (nx, ox, zx, px), (ny, oy, zy, py), (nz, oz, zz, pz) = rows
    d1, a2, a3, d4, d5, d6 = dh.d1, dh.a2, dh.a3, dh.d4, dh.d5, dh.d6
    remainder, tau = math.remainder, 2 * math.pi
    solutions = []
    c1, s1 = math.cos(q1), math.sin(q1)
    # Wrist 2: the flange's offset along the shoulder axis is d4 + d6 cos(q5).
    height = (px * s1 - py * c1 - d4) / d6
    if abs(height) > 1 + _ACOS_SLACK:
        return solutions
    tilt = math.acos(max(-1.0, min(height, 1.0)))
    nc, oc, zc = nx * c1 + ny * s1, ox * c1 + oy * s1, zx * c1 + zy * s1
    u, v = nx * s1 - ny * c1, ox * s1 - oy * c1
    for q5 in (tilt, -tilt):
        c5, s5 = math.cos(q5), math.sin(q5)
        # |(u, v)| is |sin q5| from the orientation, exact where acos near 1 is not.
        if math.hypot(u, v) < _WRIST_SINGULAR:
            q6 = wrist_3
        else:
            # Wrist 3 from the flange's x and y axes seen along the shoulder axis.
            sign = 1.0 if s5 > 0 else -1.0
            q6 = math.atan2(-v * sign, u * sign)
        c6, s6 = math.cos(q6), math.sin(q6)
        # The planar chain shoulder lift, elbow, wrist 1 from frame 1 to frame 4.
        x04x = -s5 * zc - c5 * (s6 * oc - c6 * nc)
        x04y = c5 * (nz * c6 - oz * s6) - zz * s5
        p13x = d5 * (s6 * nc + c6 * oc) - d6 * zc + px * c1 + py * s1
        p13y = pz - d1 - d6 * zz + d5 * (oz * c6 + nz * s6)
        c3 = (p13x * p13x + p13y * p13y - a2 * a2 - a3 * a3) / (2 * a2 * a3)
        if abs(c3) > 1 + _ACOS_SLACK:
            continue
        bend = math.acos(max(-1.0, min(c3, 1.0)))
        for q3 in (bend, -bend):
            ea, eb = a2 + a3 * math.cos(q3), a3 * math.sin(q3)
            q2 = math.atan2(ea * p13y - eb * p13x, ea * p13x + eb * p13y)
            c23, s23 = math.cos(q2 + q3), math.sin(q2 + q3)
            q4 = math.atan2(c23 * x04y - s23 * x04x, x04x * c23 + x04y * s23)
            solutions.append((remainder(q1, tau), remainder(q2, tau), remainder(q3, tau),
                              remainder(q4, tau), remainder(q5, tau), remainder(q6, tau)))
    return solutions
