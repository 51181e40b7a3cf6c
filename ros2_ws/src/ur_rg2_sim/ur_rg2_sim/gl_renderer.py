"""OpenGL camera renderer (moderngl on an EGL context: Mesa's llvmpipe on a CPU, or a GPU).

It draws a :class:`~ur_rg2_sim.render_scene.SceneSnapshot` as pybullet's TinyRenderer does:
the same pinhole camera, the same shading formula (ambient 0.6, diffuse 0.35, specular 0.05,
colours truncated to 8 bits as TinyRenderer truncates them) and the analytic floor under the
bodies. Depth is written as the optical z of each fragment, in metres, so it is exact rather
than read back from a non-linear depth buffer. Plain Python, no ROS; one renderer belongs to
the thread that made it (an OpenGL context is current on one thread).
"""

from collections.abc import Sequence
from dataclasses import dataclass
import threading

import cv2
import numpy as np

from ur_rg2_sim.render_scene import GeometryKey, SceneSnapshot, shape_mesh

_BODY_VERTEX = """
#version 330
uniform mat4 model;
uniform mat4 view;
uniform mat4 projection;
in vec3 in_position;
in vec3 in_normal;
out vec3 world_normal;
out float optical_z;
void main() {
    vec4 world = model * vec4(in_position, 1.0);
    world_normal = mat3(model) * in_normal;
    vec4 optical = view * world;
    optical_z = optical.z;
    gl_Position = projection * optical;
}
"""

# TinyRenderer's shader (bullet3 examples/TinyRenderer): the specular term uses the world z
# of the reflected light, with exponent 2 when a model has no specular map.
_BODY_FRAGMENT = """
#version 330
uniform vec4 color;
uniform vec3 light;
in vec3 world_normal;
in float optical_z;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
void main() {
    vec3 n = normalize(world_normal);
    vec3 reflected = normalize(n * (dot(n, light) * 2.0) - light);
    float specular = pow(max(reflected.z, 0.0), 2.0);
    float diffuse = max(0.0, dot(n, light));
    float intensity = 0.6 + min(diffuse * 0.35 + specular * 0.05, 0.4);
    vec3 truncated = floor(floor(255.0 * intensity) * color.rgb);
    out_color = vec4(truncated / 255.0, 1.0);
    out_depth = optical_z;
}
"""

# The floor plane z = 0 as the camera's own floor model computes it (camera.py): tiles of
# two colours, one Lambert shade, truncated to 8 bits.
_FLOOR_VERTEX = """
#version 330
uniform mat4 view;
uniform mat4 projection;
in vec2 in_xy;
out vec2 world_xy;
out float optical_z;
void main() {
    world_xy = in_xy;
    vec4 optical = view * vec4(in_xy, 0.0, 1.0);
    optical_z = optical.z;
    gl_Position = projection * optical;
}
"""

_FLOOR_FRAGMENT = """
#version 330
uniform vec3 tile_colors[2];
uniform float tile_size;
in vec2 world_xy;
in float optical_z;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
void main() {
    vec2 tile = floor(world_xy / tile_size);
    int parity = int(mod(tile.x + tile.y, 2.0));
    out_color = vec4(tile_colors[parity] / 255.0, 1.0);
    out_depth = optical_z;
}
"""

# What no surface covers: the background colour at no depth (+inf), drawn on the far plane.
_BACKGROUND_VERTEX = """
#version 330
in vec2 in_corner;
void main() {
    gl_Position = vec4(in_corner, 1.0, 1.0);
}
"""

_BACKGROUND_FRAGMENT = """
#version 330
uniform vec3 background;
uniform float no_depth;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
void main() {
    out_color = vec4(background / 255.0, 1.0);
    out_depth = no_depth;
}
"""


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


class GlRenderer:
    """Renders snapshots through one camera, over the tiled floor plane z = 0.

    ``k`` is the 3x3 intrinsic matrix in the camera model's convention (pixel ``i`` is at
    coordinate ``i``); ``world_to_optical`` the 4x4 view transform; colours are 8-bit RGB.
    """

    def __init__(self, context, width: int, height: int, k: np.ndarray,
                 world_to_optical: np.ndarray, light_direction: Sequence[float],
                 clip: tuple[float, float], floor: FloorLook) -> None:
        self.ctx = ctx = context
        self.width, self.height = width, height
        self._body = ctx.program(vertex_shader=_BODY_VERTEX, fragment_shader=_BODY_FRAGMENT)
        self._floor = ctx.program(vertex_shader=_FLOOR_VERTEX, fragment_shader=_FLOOR_FRAGMENT)
        self._background = ctx.program(vertex_shader=_BACKGROUND_VERTEX,
                                       fragment_shader=_BACKGROUND_FRAGMENT)
        near, far = clip
        a, b = (far + near) / (far - near), -2 * far * near / (far - near)
        # Optical frame to clip space with pixel i's centre (window i + 0.5) on coordinate i;
        # image row v is window row v, so the read-back rows come top first.
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
        projection = np.array([
            [2 * fx / width, 0, 2 * (cx + 0.5) / width - 1, 0],
            [0, 2 * fy / height, 2 * (cy + 0.5) / height - 1, 0],
            [0, 0, a, b],
            [0, 0, 1, 0]]).T.astype('f4').tobytes()
        view = np.asarray(world_to_optical, dtype=float)
        for program in (self._body, self._floor):
            program['projection'].write(projection)
            program['view'].write(view.T.astype('f4').tobytes())
        light = np.asarray(light_direction, dtype=float)
        self._body['light'].value = tuple(light / np.linalg.norm(light))
        self._floor['tile_colors'].value = [tuple(float(c) for c in color)
                                            for color in floor.tile_colors]
        self._floor['tile_size'].value = floor.tile_size
        self._background['background'].value = tuple(float(c) for c in floor.background)
        self._background['no_depth'].value = float('inf')
        # A floor square around the camera wider than the far clip: the clip cuts its edge.
        centre = np.linalg.inv(view)[:2, 3]
        corners = (centre + 2 * far * np.array([[-1, -1], [1, -1], [1, 1], [-1, -1], [1, 1],
                                                [-1, 1]])).astype('f4')
        screen = np.array([[-1, -1], [3, -1], [-1, 3]], dtype='f4')
        self._buffers = [ctx.buffer(corners.tobytes()), ctx.buffer(screen.tobytes())]
        self._floor_vao = ctx.vertex_array(self._floor, [(self._buffers[0], '2f', 'in_xy')])
        self._background_vao = ctx.vertex_array(self._background,
                                                [(self._buffers[1], '2f', 'in_corner')])
        self._fbo = ctx.framebuffer(
            [ctx.renderbuffer((width, height), 4), ctx.renderbuffer((width, height), 1,
                                                                    dtype='f4')],
            ctx.depth_renderbuffer((width, height)))
        self._rgba = np.empty((height, width, 4), dtype=np.uint8)
        self._meshes: dict[GeometryKey, object] = {}
        self._resources = [*self._buffers, self._fbo, *self._fbo.color_attachments,
                           self._fbo.depth_attachment, self._floor_vao, self._background_vao,
                           self._body, self._floor, self._background]

    def render(self, snapshot: SceneSnapshot) -> tuple[np.ndarray, np.ndarray]:
        """Return colour (H, W, 3) uint8 and depth (H, W) float32 metres (+inf: no return)."""
        ctx = self.ctx
        self._fbo.use()
        self._fbo.clear(depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        # Front to back, so that the depth test spares the floor's hidden pixels.
        ctx.depth_func = '<'
        model = self._body['model']
        color = self._body['color']
        for key, pose, rgba in zip(snapshot.keys, snapshot.poses, snapshot.colors):
            model.write(pose.T.tobytes())
            color.value = tuple(rgba)
            self._vertex_array(key).render()
        self._floor_vao.render()
        ctx.depth_func = '<='
        self._background_vao.render(vertices=3)
        # RGBA reads back as stored; RGB would be repacked pixel by pixel, as numpy would.
        self._fbo.read_into(self._rgba, components=4, attachment=0, alignment=1)
        depth = np.empty((self.height, self.width), dtype=np.float32)
        self._fbo.read_into(depth, components=1, attachment=1, dtype='f4')
        return cv2.cvtColor(self._rgba, cv2.COLOR_RGBA2RGB), depth

    def release(self) -> None:
        """Free this renderer's OpenGL objects (the thread's context stays)."""
        for vao in self._meshes.values():
            vao.release()
        for resource in self._resources:
            resource.release()
        self._meshes.clear()
        self._resources.clear()

    def _vertex_array(self, key: GeometryKey):
        vao = self._meshes.get(key)
        if vao is None:
            positions, normals = shape_mesh(key)
            buffer = self.ctx.buffer(np.hstack([positions, normals]).astype('f4').tobytes())
            self._resources.append(buffer)
            vao = self.ctx.vertex_array(self._body,
                                        [(buffer, '3f 3f', 'in_position', 'in_normal')])
            self._meshes[key] = vao
        return vao
