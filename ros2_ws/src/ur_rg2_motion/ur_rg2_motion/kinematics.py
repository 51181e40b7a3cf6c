"""A UR arm (UR5, UR3, UR5e, UR3e) with the RG2: TCP poses <-> joint positions. Plain Python.

The closed-form forward and inverse kinematics and the DH tables are in
ur_rg2_motion.closed_form, the reading of the robot description in ur_rg2_motion.urdf.

:class:`ArmKinematics` adds what a controller needs on top: the ``base_link``->DH base and
``tool0``->TCP transforms (read from the robot description), the joint limits, the floor and
the pedestal; :meth:`ArmKinematics.solve` picks the solution nearest the current joints that
respects all of them, or raises :class:`KinematicsError` with the reason.

The robot description may be the sim's (``base_link`` -> ``shoulder_link``, ``rg2_tcp``) or
Universal Robots' own (ur_description's ``ur_macro.xacro``: ``base_link`` ->
``base_link_inertia`` -> ``shoulder_link`` ... ``wrist_3_link`` -> ``flange`` -> ``tool0``):
the arm model is the one whose DH forward kinematics reproduces the description's own chain
from ``base_link`` to ``tool0`` (joint origins and axes) at a set of joint vectors, within
:data:`CHAIN_TOLERANCE`. Without an ``rg2_tcp`` frame the TCP is an offset from ``tool0``.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
import xml.etree.ElementTree as ET

import numpy as np
from ur_rg2_common.contract import ARM_JOINTS

from ur_rg2_motion.closed_form import (
    UR_DH,
    DhParameters,
    KinematicsError,
    forward,
    inverse,
    inverse_by_shoulder,
)
from ur_rg2_motion.urdf import (
    FLANGE,
    _arm_path,
    _chain_pose,
    _finger_half,
    _finite_offset,
    fixed_transform,
    urdf_joint_limits,
    urdf_joints,
)

# Defaults of the checks against the sim's floor and pedestal (the motion node's parameters).
FLOOR_CLEARANCE = 0.005  # m that the TCP, finger tips, wrist and elbow keep above the floor
PEDESTAL_HALF_WIDTH = 0.11  # m, half the width of the column under base_link
TCP = 'rg2_tcp'

_TAU = 2 * math.pi
# Below this the formulas lose a degree of freedom (see ArmKinematics.solve).
_BOUNDARY_SINGULAR = 1e-6  # |sin(elbow)| or wrist centre distance - d4 (m): workspace boundary
# How far (m) the DH model may put tool0 from where the description's chain has it.
CHAIN_TOLERANCE = 1e-3
# Joint vectors the DH model is checked against the chain at (rad): zero and a spread.
_CHAIN_SAMPLES = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.5, -1.2, 1.4, -0.9, 1.1, 0.3],
    [-2.0, -0.4, -1.9, 2.2, -0.7, 1.5],
    [1.3, -2.4, 0.8, 0.4, 2.6, -2.2],
])


def rotation_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the angle (rad) of the rotation between the rotation parts of poses a and b."""
    r = np.swapaxes(a[..., :3, :3], -1, -2) @ b[..., :3, :3]
    sine = np.linalg.norm(np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                                    r[..., 1, 0] - r[..., 0, 1]], axis=-1), axis=-1) / 2
    return np.arctan2(sine, (np.trace(r, axis1=-2, axis2=-1) - 1) / 2)


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in ``base_link`` that no checked point of the arm may enter."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]


@dataclass
class ArmKinematics:
    """A UR arm with the RG2: TCP poses in ``base_link`` <-> joint positions.

    ``floor_z`` is the floor's height in ``base_link`` (minus the pedestal's height);
    ``clearance`` the least height above it of the TCP, the finger tips and the wrist and
    elbow joints; ``keep_out`` boxes (the pedestal) they may not enter.
    """

    dh: DhParameters
    base_in_base_link: np.ndarray
    tcp_in_flange: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    floor_z: float = -math.inf
    clearance: float = 0.0
    finger_length: float = 0.0
    keep_out: list[Box] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._base_inverse = np.linalg.inv(self.base_in_base_link)
        self._tcp_inverse = np.linalg.inv(self.tcp_in_flange)
        # Plain floats for the scalar inner loop of solve().
        self._limits = [(float(lo), float(hi)) for lo, hi in zip(self.lower, self.upper)]
        self._base_rotation = self.base_in_base_link[:3, :3].tolist()
        self._base_offset = self.base_in_base_link[:3, 3].tolist()

    @classmethod
    def from_urdf(cls, urdf: str, model: str | None = None,
                  tcp_offset: Sequence[float] | None = None, **checks) -> 'ArmKinematics':
        """Build from robot description text.

        ``model`` (a key of :data:`UR_DH`): None picks the one that fits the description's
        chain. The TCP is the ``rg2_tcp`` frame, or else ``tcp_offset`` (x, y, z in m along
        ``tool0``'s axes); with neither, KinematicsError says so. ``checks`` are the floor and
        obstacle fields (``floor_z``, ``clearance``, ``keep_out``).
        """
        joints = urdf_joints(urdf)
        chain = {(parent, child): origin for child, (_, _, parent, origin, _) in joints.items()}
        path = _arm_path(joints)
        limits = urdf_joint_limits(urdf)
        missing = [name for name in ARM_JOINTS if name not in limits]
        if missing:
            raise KinematicsError('invalid', f"the robot description has no limits for "
                                  f"{', '.join(missing)}")
        candidates = UR_DH if model is None else {model: UR_DH.get(model)}
        if None in candidates.values():
            raise KinematicsError('invalid', f'no DH parameters for robot model {model!r}')
        # DH base -> flange against base_link -> tool0 along the description's own chain.
        described = np.array([_chain_pose(path, q) for q in _CHAIN_SAMPLES])
        fits = {}
        for name, dh in candidates.items():
            base = described[0] @ np.linalg.inv(forward(dh, _CHAIN_SAMPLES[0]))
            error = np.abs(base @ forward(dh, _CHAIN_SAMPLES) - described)[:, :3, 3].max()
            fits[name] = (float(error), base)
        model = min(fits, key=lambda name: fits[name][0])
        error, base = fits[model]
        if error > CHAIN_TOLERANCE:
            raise KinematicsError(
                'invalid', f'the robot description\'s arm is none of {", ".join(candidates)}: '
                f'the nearest, {model}, puts {FLANGE} {1000 * error:.1f} mm from where its chain '
                'has it')
        if TCP in joints:
            tcp = fixed_transform(chain, FLANGE, TCP)
        elif tcp_offset is not None:
            tcp = np.eye(4)
            tcp[:3, 3] = _finite_offset(tcp_offset)
        else:
            raise KinematicsError(
                'invalid', f"the robot description has no {TCP} frame (the RG2's grasp point "
                f'below {FLANGE}) and no TCP offset from {FLANGE} is set')
        # The fingers reach past the TCP to the tips of their pads.
        tip = max((fixed_transform(chain, FLANGE, child)[2, 3] for _, child in chain
                   if child.endswith('_finger')), default=tcp[2, 3]) + _finger_half(urdf)
        return cls(
            dh=UR_DH[model],
            base_in_base_link=np.round(base, 12),
            tcp_in_flange=tcp,
            lower=np.array([limits[name][0] for name in ARM_JOINTS]),
            upper=np.array([limits[name][1] for name in ARM_JOINTS]),
            finger_length=max(tip - tcp[2, 3], 0.0),
            **checks,
        )

    @property
    def model(self) -> str:
        """The arm model (a key of UR_DH) of the DH parameters."""
        return next(name for name, dh in UR_DH.items() if dh == self.dh)

    def tcp_pose(self, q: Sequence[float] | np.ndarray) -> np.ndarray:
        """Return ``base_link`` -> ``rg2_tcp`` (..., 4, 4) at joints ``q`` (..., 6)."""
        return self.base_in_base_link @ forward(self.dh, q) @ self.tcp_in_flange

    def solutions(self, target: np.ndarray, wrist_3: float = 0.0) -> list[tuple]:
        """Return every IK branch (up to 8 tuples of 6) of a TCP pose in ``base_link``."""
        flange = self._base_inverse @ np.asarray(target, dtype=float) @ self._tcp_inverse
        return inverse(self.dh, flange, wrist_3)

    def solve(self, target: np.ndarray, current: Sequence[float]) -> np.ndarray:
        """Return the joints (6,) nearest ``current`` that put the TCP at ``target``.

        ``target`` is ``base_link`` -> ``rg2_tcp`` (4x4). Each joint is taken modulo 2 pi to
        the value nearest its current one within the limits; of the branches left, those that
        keep the TCP, the finger tips, the wrist and the elbow above the floor and out of the
        keep-out boxes compete, and the nearest (sum of squared joint motions) wins.
        Raises :class:`KinematicsError` saying why no branch is acceptable (of the reasons the
        branches met, the last check: keep-out box, then floor, then joint limits).
        """
        target = np.asarray(target, dtype=float)
        check_pose(target)
        current = np.asarray(current, dtype=float).tolist()
        pans = inverse_by_shoulder(self.dh, self._base_inverse @ target @ self._tcp_inverse,
                                   current[5])
        # Points that the target alone fixes: the TCP, the finger tips, the wrist centre. In
        # plain floats, the same operations numpy would do elementwise: the learning
        # environments solve once every step, and on 3-vectors numpy's overhead dominates.
        tcp, finger = target.tolist()[:3], self.finger_length
        flange, d6 = (target @ self._tcp_inverse).tolist()[:3], self.dh.d6
        fixed_failure = self._obstacle_failure([
            [row[3] for row in tcp], [row[3] + finger * row[2] for row in tcp],
            [row[3] - d6 * row[2] for row in flange]])
        if not fixed_failure:
            # Usually the nearest branch within the limits passes the checks: found without
            # sorting them all (nor solving for a shoulder pan already further).
            best = _nearest(pans, current, self._limits)
            if best is not None and not self._obstacle_failure(self._arm_points(best)):
                return self._unless_singular(best, target)
        branches = [q for _, solutions in pans for q in solutions()]  # as self.solutions'
        if not branches:
            raise KinematicsError('unreachable', f"{_where(target)} is out of the arm's reach")
        candidates, failures = [], set()
        for branch in branches:
            q = _within_limits(branch, current, self._limits)
            if q is None:
                failures.add('joint_limits')
            else:
                candidates.append((sum([(a - b) ** 2 for a, b in zip(q, current)]), q))
        # Nearest first: the obstacle checks, the costly part, usually run for one branch only
        # (the learning environments solve once per step).
        best = None
        for _, q in sorted(candidates):
            failure = fixed_failure or self._obstacle_failure(self._arm_points(q))
            if not failure:
                best = q
                break
            failures.add(failure)
        if best is None:
            reason = next(r for r in ('pedestal', 'floor', 'joint_limits') if r in failures)
            raise KinematicsError(reason, {
                'joint_limits': f'every solution for {_where(target)} is outside the joint limits',
                'floor': f'{_where(target)} would put the arm or the gripper below the floor',
                'pedestal': f'{_where(target)} would put the arm into the pedestal',
            }[reason])
        return self._unless_singular(best, target)

    @staticmethod
    def _unless_singular(q: list[float], target: np.ndarray) -> np.ndarray:
        """Return ``q`` as an array, or raise KinematicsError if its elbow is stretched."""
        if abs(math.sin(q[2])) < _BOUNDARY_SINGULAR:
            raise KinematicsError(
                'singular', f'{_where(target)} needs the elbow fully stretched (a singularity '
                'on the edge of the reach)')
        return np.array(q)

    def _arm_points(self, q: Sequence[float]) -> list[tuple[float, float, float]]:
        """Return the elbow and the wrist 1 and 2 frame origins in ``base_link``."""
        d1, a2, a3, d4 = self.dh.d1, self.dh.a2, self.dh.a3, self.dh.d4
        c1, s1 = math.cos(q[0]), math.sin(q[0])
        # In the arm's vertical plane: the reach from the base axis and the height.
        reach2 = a2 * math.cos(q[1])
        reach3 = reach2 + a3 * math.cos(q[1] + q[2])
        z2 = d1 + a2 * math.sin(q[1])
        z3 = z2 + a3 * math.sin(q[1] + q[2])
        # Into base_link, written out: every solve checks the points of at least one branch.
        (r0, r1, r2), (o0, o1, o2) = self._base_rotation, self._base_offset
        return [(r0[0] * x + r0[1] * y + r0[2] * z + o0, r1[0] * x + r1[1] * y + r1[2] * z + o1,
                 r2[0] * x + r2[1] * y + r2[2] * z + o2)
                for x, y, z in ((reach2 * c1, reach2 * s1, z2), (reach3 * c1, reach3 * s1, z3),
                                (reach3 * c1 + d4 * s1, reach3 * s1 - d4 * c1, z3))]

    def _obstacle_failure(self, points: list) -> str | None:
        """Return 'floor' or 'pedestal' if a point is below the floor or in a keep-out box."""
        # Plain loops: called for every solve, where generator expressions cost more than
        # the comparisons.
        lowest = self.floor_z + self.clearance
        for p in points:
            if p[2] < lowest:
                return 'floor'
        for box in self.keep_out:
            (x0, y0, z0), (x1, y1, z1) = box.lower, box.upper
            for x, y, z in points:
                if x0 < x < x1 and y0 < y < y1 and z0 < z < z1:
                    return 'pedestal'
        return None


def _wrapped(angle: float, now: float, lo: float, hi: float) -> float | None:
    """Return the 2 pi equivalent of ``angle`` nearest ``now``, moved into [lo, hi]; or None."""
    angle = now + math.remainder(angle - now, _TAU)
    if angle > hi:
        angle -= _TAU
    elif angle < lo:
        angle += _TAU
    return angle if lo <= angle <= hi else None


def _within_limits(q: Sequence[float], current: Sequence[float],
                   limits: Sequence[tuple[float, float]]) -> list[float] | None:
    """Return ``q`` with each joint the 2 pi equivalent nearest current inside the limits."""
    result = []
    for angle, now, (lo, hi) in zip(q, current, limits):
        angle = _wrapped(angle, now, lo, hi)
        if angle is None:
            return None
        result.append(angle)
    return result


def _nearest(pans: list[tuple[float, Callable[[], list[tuple]]]], current: Sequence[float],
             limits: Sequence[tuple[float, float]]) -> list[float] | None:
    """Return the branch that :func:`_within_limits` puts nearest ``current``, or None.

    ``pans`` are :func:`inverse_by_shoulder`'s. Nearest as :meth:`ArmKinematics.solve` orders
    them: by the sum of squared joint motions (summed in joint order), then by the joints. A
    branch is dropped as soon as its partial sum exceeds the best full one (in floating point
    too: rounding is monotonic, so adding non-negative terms never gives a smaller sum), and a
    shoulder pan whose own term already does is not solved for.
    """
    pan_now, (pan_low, pan_high) = current[0], limits[0]
    order = []
    for pan, solutions in pans:  # joint 0 taken as _within_limits takes it
        pan = _wrapped(pan, pan_now, pan_low, pan_high)
        if pan is not None:
            order.append(((pan - pan_now) ** 2, solutions))
    order.sort(key=lambda item: item[0])  # the nearest pan first
    best, best_cost = None, math.inf
    for pan_cost, solutions in order:
        if pan_cost > best_cost:
            break
        for branch in solutions():
            q, cost = [], 0
            for angle, now, (lo, hi) in zip(branch, current, limits):
                angle = _wrapped(angle, now, lo, hi)
                if angle is None:
                    break
                cost += (angle - now) ** 2
                if cost > best_cost:
                    break
                q.append(angle)
            else:
                if cost < best_cost or q < best:
                    best, best_cost = q, cost
    return best


def check_pose(pose: np.ndarray) -> None:
    """Raise KinematicsError('invalid') unless ``pose`` is a finite 4x4 rigid transform."""
    # Scalar arithmetic throughout: for one 4x4 it is several times faster than numpy, and
    # every solve (every step of the learning environments) checks its target.
    values = pose.ravel().tolist() if pose.shape == (4, 4) else None
    if values is None or not all(map(math.isfinite, values)):
        raise KinematicsError('invalid', 'the target pose is not finite')
    a, b, c, _, d, e, f, _, g, h, i, _ = values[:12]
    # Orthonormal columns (R^T R = I), and the determinant, the triple product of the columns.
    gram = (a * a + d * d + g * g - 1.0, b * b + e * e + h * h - 1.0, c * c + f * f + i * i - 1.0,
            a * b + d * e + g * h, a * c + d * f + g * i, b * c + e * f + h * i)
    determinant = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if max(map(abs, gram)) > 1e-6 or determinant < 0:
        raise KinematicsError('invalid', 'the target orientation is not a rotation')


def _where(target: np.ndarray) -> str:
    x, y, z = target[:3, 3]
    return f'the pose at ({x:.3f}, {y:.3f}, {z:.3f}) m'


def urdf_velocity_limits(urdf: str) -> np.ndarray:
    """Return the six arm joints' velocity limits (rad/s) from robot description text."""
    limits = {}
    for joint in ET.fromstring(urdf).iter('joint'):
        limit = joint.find('limit')
        if limit is not None and limit.get('velocity') is not None:
            limits[joint.get('name')] = float(limit.get('velocity'))
    missing = [name for name in ARM_JOINTS if name not in limits]
    if missing:
        raise KinematicsError('invalid', f"no velocity limit for {', '.join(missing)}")
    return np.array([limits[name] for name in ARM_JOINTS])


def arm_on_pedestal(urdf: str, pedestal_height: float,
                    pedestal_half_width: float = PEDESTAL_HALF_WIDTH,
                    clearance: float = FLOOR_CLEARANCE,
                    tcp_offset: Sequence[float] | None = None) -> ArmKinematics:
    """Return the arm of robot description text ``urdf`` with the sim's floor and pedestal.

    ``pedestal_height``: base_link above the floor, m (inf: no floor known); the pedestal is
    a square column of ``pedestal_half_width`` under base_link (0: none). ``tcp_offset``: see
    :meth:`ArmKinematics.from_urdf`.
    """
    keep_out = [Box((-pedestal_half_width, -pedestal_half_width, -pedestal_height - 1.0),
                    (pedestal_half_width, pedestal_half_width, 0.0))] if (
        pedestal_half_width > 0 and math.isfinite(pedestal_height) and pedestal_height > 0
    ) else []
    return ArmKinematics.from_urdf(urdf, tcp_offset=tcp_offset, floor_z=-pedestal_height,
                                   clearance=clearance, keep_out=keep_out)
