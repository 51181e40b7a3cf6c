"""OpenGL camera renderer (moderngl on an EGL context: Mesa's llvmpipe on a CPU, or a GPU).

It draws a :class:`~ur_rg2_sim.render_scene.SceneSnapshot` as pybullet's TinyRenderer does:
the same pinhole camera, the same shading formula (ambient 0.6, diffuse 0.35, specular 0.05,
colours truncated to 8 bits as TinyRenderer truncates them) and the analytic floor under the
bodies. Depth is written as the optical z of each fragment, in metres, to a float target of
its own, so it is exact rather than read back from a non-linear depth buffer and needs no
conversion. Plain Python, no ROS; one renderer belongs to the thread that made it (an OpenGL
context is current on one thread).

What a frame costs is mostly llvmpipe's, per triangle, so the Python around it is kept to a
few calls: every shape of a scene is in one indexed vertex buffer, drawn in one call with the
poses and colours in uniform blocks, and of the pre-drawn floor only the rectangle where
shapes were or are is copied back.
"""

from collections.abc import Sequence
import ctypes
import ctypes.util
from dataclasses import dataclass
from functools import lru_cache
import math
import os
import threading
from typing import Optional

import cv2
import numpy as np

from ur_rg2_sim.gl_shaders import (
    BODY_FRAGMENT,
    BODY_VERTEX,
    FLOOR_FRAGMENT,
    FLOOR_VERTEX,
    SHAPES_PER_DRAW,
)
from ur_rg2_sim.render_scene import GeometryKey, SceneSnapshot, shape_mesh


@dataclass(frozen=True)
class FloorLook:
    """The floor as the camera sees it: two shaded tile colours, tile size, background."""

    tile_colors: np.ndarray  # (2, 3) uint8, the shading applied
    tile_size: float  # m
    background: np.ndarray  # (3,) uint8, where no surface is in view


def create_context():
    """Return a new headless OpenGL 3.3+ context (moderngl on EGL); raise when none loads."""
    import moderngl  # imported here: the fallback renderer runs without it

    return moderngl.create_standalone_context(backend='egl', require=330)


_per_thread = threading.local()


def thread_context():
    """Return this thread's OpenGL context, made on first use and current on this thread.

    Every renderer of a thread shares it: a context made later would be the current one, and
    the earlier renderers' calls would go to it.
    """
    context = getattr(_per_thread, 'context', None)
    if context is None:
        context = _per_thread.context = create_context()
    return context


def release_thread_context() -> None:
    """Free this thread's context (its renderers become unusable)."""
    context = getattr(_per_thread, 'context', None)
    if context is not None:
        context.release()
        _per_thread.context = None


def describe(context) -> str:
    """Return the context's renderer and version, e.g. ``llvmpipe (LLVM 15.0.6), GL 4.5``."""
    info = context.info
    return f"{info['GL_RENDERER']}, OpenGL {info['GL_VERSION']}"


# glBlitFramebuffer's names, for copying part of a framebuffer (moderngl copies all of it).
_READ_FRAMEBUFFER, _DRAW_FRAMEBUFFER, _COLOR_ATTACHMENT0 = 0x8CA8, 0x8CA9, 0x8CE0
_COLOR_BUFFER_BIT, _DEPTH_BUFFER_BIT, _NEAREST = 0x4000, 0x100, 0x2600


@lru_cache(maxsize=1)
def _gl_library():
    """Return the OpenGL library moderngl's EGL context calls through, or None."""
    name = os.environ.get('GLCONTEXT_LINUX_LIBGL') or ctypes.util.find_library('GL')
    try:
        gl = ctypes.CDLL(name)
        gl.glBlitFramebuffer.argtypes = [ctypes.c_int] * 8 + [ctypes.c_uint, ctypes.c_uint]
        gl.glBlitFramebuffer.restype = None
        for function in (gl.glBindFramebuffer, gl.glReadBuffer, gl.glDrawBuffer,
                         gl.glDrawBuffers):
            function.restype = None
    except (OSError, TypeError, AttributeError):
        return None
    return gl


class GlRenderer:
    """Renders snapshots through one camera, over the tiled floor plane z = 0.

    ``k`` is the 3x3 intrinsic matrix in the camera model's convention (pixel ``i`` is at
    coordinate ``i``); ``world_to_optical`` the 4x4 view transform; colours are 8-bit RGB.
    Meshes must wind counter-clockwise seen from outside (back faces are culled).
    """

    def __init__(self, context, width: int, height: int, k: np.ndarray,
                 world_to_optical: np.ndarray, light_direction: Sequence[float],
                 clip: tuple[float, float], floor: FloorLook) -> None:
        self.ctx = ctx = context
        self.width, self.height = width, height
        self._body = ctx.program(vertex_shader=BODY_VERTEX, fragment_shader=BODY_FRAGMENT)
        self._floor = ctx.program(vertex_shader=FLOOR_VERTEX, fragment_shader=FLOOR_FRAGMENT)
        self._body['Poses'].binding, self._body['Colors'].binding = 0, 1
        self._poses = ctx.buffer(reserve=64 * SHAPES_PER_DRAW, dynamic=True)
        self._colors = ctx.buffer(reserve=16 * SHAPES_PER_DRAW, dynamic=True)
        near, far = clip
        a, b = (far + near) / (far - near), -2 * far * near / (far - near)
        # Optical frame to clip space with pixel i's centre (window i + 0.5) on coordinate i;
        # image row v is window row v, so the read-back rows come top first (and a face
        # counter-clockwise seen from outside is clockwise on the window). Clip w is the
        # optical z, which the shaders write as depth.
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        projection = np.array([
            [2 * fx / width, 0, 2 * (cx + 0.5) / width - 1, 0],
            [0, 2 * fy / height, 2 * (cy + 0.5) / height - 1, 0],
            [0, 0, a, b],
            [0, 0, 1, 0]])
        view = np.asarray(world_to_optical, dtype=float)
        view_projection = (projection @ view).T.astype('f4').tobytes()
        for program in (self._body, self._floor):
            program['view_projection'].write(view_projection)
        light = np.asarray(light_direction, dtype=float)
        self._body['light'].value = tuple(light / np.linalg.norm(light))
        self._floor['tile_colors'].value = [tuple(float(c) for c in color)
                                            for color in floor.tile_colors]
        self._floor['per_tile'].value = 1.0 / floor.tile_size
        background = tuple(float(c) / 255 for c in floor.background)
        # A floor square around the camera wider than the far clip: the clip cuts its edge.
        centre = np.linalg.inv(view)[:2, 3]
        corners = (centre + 2 * far * np.array([[-1, -1], [1, -1], [1, 1], [-1, -1], [1, 1],
                                                [-1, 1]])).astype('f4')
        floor_corners = ctx.buffer(corners.tobytes())
        floor_vao = ctx.vertex_array(self._floor, [(floor_corners, '2f', 'in_xy')])
        # Colour (RGBA, 8 bits) and depth (metres, float) attachments, and a depth buffer.
        self._fbo, self._floor_fbo = (
            ctx.framebuffer([ctx.renderbuffer((width, height), 4),
                             ctx.renderbuffer((width, height), 1, dtype='f4')],
                            ctx.depth_renderbuffer((width, height))) for _ in range(2))
        # The floor and background never change for a camera: drawn once, copied each frame
        # with their depth (a copy costs a twentieth of drawing them). +inf: nothing seen.
        self._floor_fbo.clear(*background, 1.0, depth=1.0)
        depth_only = ctx.framebuffer([self._floor_fbo.color_attachments[1]])
        depth_only.clear(np.inf)
        depth_only.release()
        self._floor_fbo.use()
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        ctx.depth_func = '<'
        floor_vao.render()
        self._rgba = np.empty((height, width, 4), dtype=np.uint8)
        self._view_projection = projection @ view
        self._near = near
        self._eye_height = float(np.linalg.inv(view)[2, 3])  # the camera's side of the floor
        # Where the frame buffer may differ from the floor's: (left, top, right, bottom)
        # window pixels, right and bottom excluded; all of it before the first frame.
        self._stale: Optional[tuple[int, int, int, int]] = (0, 0, width, height)
        # The vertex arrays of the last few sets of shapes drawn, newest last.
        self._layouts: dict[tuple[GeometryKey, ...], _Layout] = {}
        self._resources = [
            self._body, self._floor, floor_vao, floor_corners, self._poses, self._colors,
            *(item for fbo in (self._fbo, self._floor_fbo)
              for item in (fbo, *fbo.color_attachments, fbo.depth_attachment))]

    def render(self, snapshot: SceneSnapshot) -> tuple[np.ndarray, np.ndarray]:
        """Return colour (H, W, 3) uint8 and depth (H, W) float32 metres (+inf: no return)."""
        ctx = self.ctx
        layout = self._layout(snapshot.keys) if snapshot.keys else None
        drawn = None if layout is None else self._screen_rect(snapshot.poses, layout.corners)
        # The floor back where the last frame's shapes were and this frame's will be.
        self._copy_floor(_union(self._stale, drawn))
        self._stale = drawn
        if drawn is not None:
            self._fbo.use()
            ctx.enable(ctx.DEPTH_TEST | ctx.CULL_FACE)
            ctx.front_face = 'cw'
            ctx.depth_func = '<'
            self._poses.bind_to_uniform_block(0)
            self._colors.bind_to_uniform_block(1)
            # Column-major, as OpenGL reads a mat4: each pose transposed.
            poses = snapshot.poses.transpose(0, 2, 1)
            for start, vao in layout.draws:
                end = start + SHAPES_PER_DRAW
                self._poses.write(np.ascontiguousarray(poses[start:end], dtype=np.float32))
                self._colors.write(np.ascontiguousarray(snapshot.colors[start:end],
                                                        dtype=np.float32))
                vao.render()
        # RGBA reads back as stored; RGB would be repacked pixel by pixel, as numpy would.
        self._fbo.read_into(self._rgba, components=4, attachment=0, alignment=1)
        depth = np.empty((self.height, self.width), dtype=np.float32)
        self._fbo.read_into(depth, components=1, attachment=1, alignment=1, dtype='f4')
        return cv2.cvtColor(self._rgba, cv2.COLOR_RGBA2RGB), depth

    def release(self) -> None:
        """Free this renderer's OpenGL objects (the thread's context stays)."""
        for layout in self._layouts.values():
            layout.release()
        for resource in self._resources:
            resource.release()
        self._layouts.clear()
        self._resources.clear()

    def _copy_floor(self, rect: Optional[tuple[int, int, int, int]]) -> None:
        """Copy the pre-drawn floor's colour and depths over a rectangle of the frame buffer.

        A copy of part of a frame buffer costs in proportion (moderngl copies all of it, and
        a scissored copy is drawn, which costs llvmpipe ten times as much).
        """
        if rect is None:
            return
        gl = _gl_library()
        if gl is None:
            self.ctx.copy_framebuffer(self._fbo, self._floor_fbo)
            return
        left, top, right, bottom = rect
        gl.glBindFramebuffer(_READ_FRAMEBUFFER, self._floor_fbo.glo)
        gl.glBindFramebuffer(_DRAW_FRAMEBUFFER, self._fbo.glo)
        for attachment, depth in ((0, _DEPTH_BUFFER_BIT), (1, 0)):
            gl.glReadBuffer(_COLOR_ATTACHMENT0 + attachment)
            gl.glDrawBuffer(_COLOR_ATTACHMENT0 + attachment)
            gl.glBlitFramebuffer(left, top, right, bottom, left, top, right, bottom,
                                 _COLOR_BUFFER_BIT | depth, _NEAREST)
        gl.glDrawBuffers(2, (ctypes.c_uint * 2)(_COLOR_ATTACHMENT0, _COLOR_ATTACHMENT0 + 1))
        self._fbo.use()  # bound again for reading and drawing, as moderngl expects

    def _screen_rect(self, poses: np.ndarray,
                     corners: np.ndarray) -> Optional[tuple[int, int, int, int]]:
        """Return the window pixels the shapes may cover, (left, top, right, bottom), or None.

        It bounds the shapes' boxes, a pixel wider on each side, but for boxes wholly on the far
        side of the floor, which hides them (the floor's speck, bodies parked out of sight); all
        of the window when a box reaches nearer than the near clip, where its projection bounds
        nothing.
        """
        world = poses.astype(float) @ corners
        heights = world[:, 2, :] * np.sign(self._eye_height)
        world = world[heights.max(axis=1) >= 0] if self._eye_height else world
        if not len(world):
            return None
        clip = world.transpose(0, 2, 1) @ self._view_projection.T
        w = clip[..., 3]
        if w.min() <= self._near:
            return 0, 0, self.width, self.height
        x, y = clip[..., 0] / w, clip[..., 1] / w
        left = max(math.floor((x.min() + 1) * self.width / 2) - 1, 0)
        right = min(math.ceil((x.max() + 1) * self.width / 2) + 1, self.width)
        top = max(math.floor((y.min() + 1) * self.height / 2) - 1, 0)
        bottom = min(math.ceil((y.max() + 1) * self.height / 2) + 1, self.height)
        if left >= right or top >= bottom:
            return None
        return left, top, right, bottom

    def _layout(self, keys: tuple[GeometryKey, ...]) -> '_Layout':
        """Return the vertex arrays drawing these shapes, made on first use."""
        layout = self._layouts.pop(keys, None)
        if layout is None:
            layout = _Layout(self.ctx, self._body, keys)
            while len(self._layouts) >= _LAYOUTS_KEPT:
                self._layouts.pop(next(iter(self._layouts))).release()
        self._layouts[keys] = layout
        return layout


# Sets of shapes whose vertex arrays a renderer keeps: bodies added and removed now and then
# come back to a set drawn before.
_LAYOUTS_KEPT = 4

_VERTEX = np.dtype([('position', '<f4', 3), ('normal', '<f4', 3), ('shape', '<i4')])


class _Layout:
    """A set of shapes on the GPU: ``draws``, (first shape, vertex array) pairs, and boxes.

    Each vertex array holds up to :data:`SHAPES_PER_DRAW` shapes' triangles in one indexed
    buffer, each vertex with its shape's index in the draw. ``corners`` (n, 4, 8) are the
    corners of each shape's bounding box in its own frame, as homogeneous columns.
    """

    def __init__(self, ctx, program, keys: tuple[GeometryKey, ...]) -> None:
        self.draws, self._resources = [], []
        for start in range(0, len(keys), SHAPES_PER_DRAW):
            vertices, indices = _merged_meshes(keys[start:start + SHAPES_PER_DRAW])
            buffer, index_buffer = ctx.buffer(vertices), ctx.buffer(indices)
            vao = ctx.vertex_array(
                program, [(buffer, '3f 3f 1i', 'in_position', 'in_normal', 'in_shape')],
                index_buffer, index_element_size=4)
            self.draws.append((start, vao))
            self._resources += [vao, buffer, index_buffer]
        self.corners = np.stack([_box_corners(key) for key in keys])

    def release(self) -> None:
        for resource in self._resources:
            resource.release()
        self._resources.clear()


def _union(a: Optional[tuple[int, ...]], b: Optional[tuple[int, ...]]) -> Optional[tuple]:
    """Return the rectangle holding two (left, top, right, bottom) rectangles (None: empty)."""
    if a is None or b is None:
        return a or b
    return min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])


@lru_cache(maxsize=256)
def _box_corners(key: GeometryKey) -> np.ndarray:
    """Return the 8 corners of a shape's bounding box as homogeneous columns, (4, 8)."""
    vertices = _indexed_mesh(key)[0][:, :3]
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    corners = np.array([[(high if bit & 1 << axis else low)[axis] for axis in range(3)]
                        for bit in range(8)], dtype=float)
    return np.vstack([corners.T, np.ones(8)])


@lru_cache(maxsize=256)
def _indexed_mesh(key: GeometryKey) -> tuple[np.ndarray, np.ndarray]:
    """Return a shape's distinct (position, normal) vertices, (m, 6), and its triangles' indices.

    The triangles keep their order; a vertex shared by several is transformed once, and the
    vertices are numbered as the triangles first use them (llvmpipe's vertex cache is small).
    """
    positions, normals = shape_mesh(key)
    vertices, first, indices = np.unique(np.hstack([positions, normals]).astype(np.float32),
                                         axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    renumber = np.empty_like(order)
    renumber[order] = np.arange(len(order))
    return vertices[order], renumber[indices.reshape(-1)].astype(np.uint32)


def _merged_meshes(keys: Sequence[GeometryKey]) -> tuple[bytes, bytes]:
    """Return one vertex buffer and one index buffer holding all these shapes' triangles."""
    meshes = [_indexed_mesh(key) for key in keys]
    vertices = np.empty(sum(len(mesh[0]) for mesh in meshes), dtype=_VERTEX)
    indices, first = [], 0
    for shape, (mesh_vertices, mesh_indices) in enumerate(meshes):
        rows = vertices[first:first + len(mesh_vertices)]
        rows['position'], rows['normal'], rows['shape'] = (
            mesh_vertices[:, :3], mesh_vertices[:, 3:], shape)
        indices.append(mesh_indices + np.uint32(first))
        first += len(mesh_vertices)
    return vertices.tobytes(), np.concatenate(indices).tobytes()
