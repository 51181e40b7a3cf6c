"""What the camera draws, read from pybullet: each visual shape's geometry, pose and colour.

A :class:`SceneSnapshot` is plain data (numpy arrays and tuples), so it can be handed to a
renderer on another thread or in another process while the physics goes on. The geometry of
each shape is built once per :data:`GeometryKey` by :func:`shape_mesh` (no pybullet needed).
"""

from dataclasses import dataclass
from functools import lru_cache
import math
from pathlib import Path

import numpy as np
import pybullet

# (pybullet geometry type, dimensions, mesh file): enough to build a shape's triangles.
GeometryKey = tuple[int, tuple[float, ...], str]

_CYLINDER_SLICES = 48


@dataclass(frozen=True)
class SceneSnapshot:
    """The visual shapes of a world at one instant.

    ``keys[i]`` is shape i's geometry, ``poses[i]`` its 4x4 world transform (float32) and
    ``colors[i]`` its RGBA (0-1).
    """

    keys: tuple[GeometryKey, ...]
    poses: np.ndarray
    colors: np.ndarray
    textured: bool = False  # a shape has a texture, which the OpenGL renderer does not draw


def read_snapshot(client: int) -> SceneSnapshot:
    """Return the visual shapes of every body of a pybullet client as they are now.

    Shapes and colours are read afresh each time (some 20 microseconds for the sim's world),
    so a body added, removed or repainted shows in the next frame. The link frames of all
    bodies become matrices in one go: numpy's cost is per call more than per row.
    """
    bodies, frames = [], []
    for index in range(pybullet.getNumBodies(physicsClientId=client)):
        body = pybullet.getBodyUniqueId(index, physicsClientId=client)
        shapes = _body_shapes(tuple(pybullet.getVisualShapeData(body, physicsClientId=client)))
        if not shapes.keys:
            continue
        frames.append(pybullet.getBasePositionAndOrientation(body, physicsClientId=client))
        links = pybullet.getNumJoints(body, physicsClientId=client)
        if links:
            states = pybullet.getLinkStates(body, list(range(links)), physicsClientId=client)
            frames += [(state[4], state[5]) for state in states]  # the URDF link frames
        bodies.append((shapes, links))
    if not bodies:
        return SceneSnapshot((), np.empty((0, 4, 4), np.float32), np.empty((0, 4), np.float32))
    scene = _scene_shapes(tuple(bodies))
    world = _matrices(frames)[scene.links]
    return SceneSnapshot(scene.keys, np.matmul(world, scene.local).astype(np.float32),
                         scene.colors.copy(), scene.textured)


@dataclass(frozen=True, eq=False)
class _SceneShapes:
    keys: tuple[GeometryKey, ...]
    links: np.ndarray  # each shape's row in the scene's link frames (each body's base, links)
    local: np.ndarray  # (n, 4, 4): each shape in its link's frame
    colors: np.ndarray  # (n, 4) float32
    textured: bool


@lru_cache(maxsize=64)
def _scene_shapes(bodies: tuple) -> _SceneShapes:
    """Join the shapes of (body shapes, link count) pairs, once per distinct scene."""
    rows, first = [], 0
    for shapes, links in bodies:
        rows.append(shapes.links + (first + 1))  # link -1 (the base) is the body's row 0
        first += 1 + links
    every = [shapes for shapes, _ in bodies]
    return _SceneShapes(tuple(key for shapes in every for key in shapes.keys),
                        np.concatenate(rows), np.concatenate([shapes.local for shapes in every]),
                        np.concatenate([shapes.colors for shapes in every]),
                        any(shapes.textured for shapes in every))


@dataclass(frozen=True, eq=False)  # told apart by identity: _body_shapes makes each once
class _BodyShapes:
    keys: tuple[GeometryKey, ...]
    links: np.ndarray  # each shape's link index, -1: the base
    local: np.ndarray  # (n, 4, 4): each shape in its link's frame
    colors: np.ndarray  # (n, 4) float32
    textured: bool


@lru_cache(maxsize=1024)
def _body_shapes(data: tuple) -> _BodyShapes:
    """Parse a body's getVisualShapeData once per distinct answer (they repeat every frame)."""
    keys, links, local, colors, textured = [], [], [], [], False
    for _, link, kind, dimensions, filename, position, orientation, rgba, *rest in data:
        if kind == pybullet.GEOM_PLANE:
            continue  # the floor: the camera draws it itself
        textured |= bool(rest) and rest[0] >= 0
        keys.append((kind, tuple(round(d, 9) for d in dimensions),
                     filename.decode() if isinstance(filename, bytes) else filename))
        links.append(link)
        local.append((position, orientation))
        colors.append(rgba)
    return _BodyShapes(tuple(keys), np.asarray(links, dtype=int),
                       _matrices(local) if local else np.empty((0, 4, 4)),
                       np.asarray(colors, dtype=np.float32).reshape(-1, 4), textured)


def _matrices(poses) -> np.ndarray:
    """Return the 4x4 transforms of (position, xyzw quaternion) pairs, (n, 4, 4).

    pybullet turns each quaternion into a rotation in half the time numpy takes for the lot.
    """
    matrices = np.zeros((len(poses), 4, 4))
    matrices[:, :3, :3] = np.reshape(
        [pybullet.getMatrixFromQuaternion(orientation) for _, orientation in poses], (-1, 3, 3))
    matrices[:, :3, 3] = [position for position, _ in poses]
    matrices[:, 3, 3] = 1
    return matrices


@lru_cache(maxsize=256)
def shape_mesh(key: GeometryKey) -> tuple[np.ndarray, np.ndarray]:
    """Return a shape's triangles: positions and normals, (3 * faces, 3) float32 each."""
    kind, dimensions, filename = key
    if kind == pybullet.GEOM_MESH:
        return _obj_mesh(filename, tuple(dimensions[:3]))
    if kind == pybullet.GEOM_SPHERE:
        mesh = _sphere(dimensions[0])
    elif kind == pybullet.GEOM_BOX:
        mesh = _box(np.asarray(dimensions[:3]) / 2)
    elif kind in (pybullet.GEOM_CYLINDER, pybullet.GEOM_CAPSULE):
        mesh = _cylinder(dimensions[1], dimensions[0])
    else:
        raise ValueError(f'cannot draw pybullet geometry type {kind}')
    return _facing_out(*mesh)


def _facing_out(positions: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Wind each triangle of a convex shape round its centre counter-clockwise from outside."""
    triangles = positions.reshape(-1, 3, 3)
    facing = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    inward = np.einsum('ij,ij->i', facing, triangles.sum(axis=1)) < 0
    order = np.where(inward[:, None], [0, 2, 1], [0, 1, 2])
    rows = (np.arange(len(triangles))[:, None] * 3 + order).ravel()
    return positions[rows], normals[rows]


def _sphere(radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the sphere TinyRenderer draws: the hull of Bullet's 42 unit-sphere directions.

    That is an icosahedron (poles on z, its lower ring at -36 degrees) with each edge's
    midpoint pushed out to the sphere: 80 smooth-shaded triangles.
    """
    ring = np.arctan(0.5)
    top, bottom = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    upper = [np.array([math.cos(a) * math.cos(ring), math.sin(a) * math.cos(ring),
                       math.sin(ring)]) for a in np.radians(np.arange(0, 360, 72))]
    lower = [np.array([math.cos(a) * math.cos(ring), math.sin(a) * math.cos(ring),
                       -math.sin(ring)]) for a in np.radians(np.arange(-36, 324, 72))]
    faces = []
    for i in range(5):
        j = (i + 1) % 5
        faces += [(top, upper[i], upper[j]), (bottom, lower[j], lower[i]),
                  (upper[i], lower[i], lower[j]), (upper[i], lower[j], upper[j])]
    corners = []
    for a, b, c in faces:
        ab, bc, ca = (v / np.linalg.norm(v) for v in (a + b, b + c, c + a))
        corners += [a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca]
    normals = np.asarray(corners)
    return (normals * radius).astype(np.float32), normals.astype(np.float32)


def _box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    positions, normals = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            normal = np.zeros(3)
            normal[axis] = sign
            u, v = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
            corners = [normal + su * u + sv * v for su, sv in ((-1, -1), (1, -1), (1, 1),
                                                                (-1, 1))]
            for index in (0, 1, 2, 0, 2, 3):
                positions.append(corners[index] * half)
                normals.append(normal)
    return np.asarray(positions, np.float32), np.asarray(normals, np.float32)


def _cylinder(radius: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    angles = np.linspace(0, 2 * math.pi, _CYLINDER_SLICES + 1)
    rim = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=-1)
    top, bottom = np.array([0, 0, length / 2]), np.array([0, 0, -length / 2])
    positions, normals = [], []
    for i in range(_CYLINDER_SLICES):
        r0, r1 = rim[i], rim[i + 1]
        quad = [r0 * radius + bottom, r1 * radius + bottom, r1 * radius + top,
                r0 * radius + top]
        for index, n in zip((0, 1, 2, 0, 2, 3), (r0, r1, r1, r0, r1, r0)):
            positions.append(quad[index])
            normals.append(n)
        for centre, sign in ((top, 1.0), (bottom, -1.0)):
            positions += [centre, r0 * radius + centre, r1 * radius + centre]
            normals += [np.array([0, 0, sign])] * 3
    return np.asarray(positions, np.float32), np.asarray(normals, np.float32)


def _obj_mesh(filename: str, scale: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Read a Wavefront OBJ (triangles or polygons; normals computed where it has none)."""
    vertices, normals, faces = [], [], []
    for line in Path(filename).read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == 'v':
            vertices.append([float(x) for x in parts[1:4]])
        elif parts[0] == 'vn':
            normals.append([float(x) for x in parts[1:4]])
        elif parts[0] == 'f':
            corners = [corner.split('/') for corner in parts[1:]]
            for i in range(1, len(corners) - 1):
                faces.append([corners[0], corners[i], corners[i + 1]])
    vertex_array = np.asarray(vertices, dtype=float)
    positions = np.empty((len(faces) * 3, 3))
    face_normals = np.empty((len(faces) * 3, 3))
    normal_array = np.asarray(normals, dtype=float) if normals else None
    for f, face in enumerate(faces):
        corners = [vertex_array[int(c[0]) - 1] for c in face]
        positions[3 * f:3 * f + 3] = corners
        if normal_array is not None and all(len(c) > 2 and c[2] for c in face):
            face_normals[3 * f:3 * f + 3] = [normal_array[int(c[2]) - 1] for c in face]
        else:
            flat = np.cross(corners[1] - corners[0], corners[2] - corners[0])
            face_normals[3 * f:3 * f + 3] = flat / (np.linalg.norm(flat) or 1.0)
    positions *= np.asarray(scale, dtype=float)
    return positions.astype(np.float32), face_normals.astype(np.float32)
