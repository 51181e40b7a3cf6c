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
uniform mat4 view_projection;
in vec3 in_position;
in vec3 in_normal;
out vec3 world_normal;
void main() {
    world_normal = mat3(model) * in_normal;
    gl_Position = view_projection * (model * vec4(in_position, 1.0));
}
"""

# TinyRenderer's shader (bullet3 examples/TinyRenderer): the specular term uses the world z
# of the reflected light, with exponent 2 when a model has no specular map.
_BODY_FRAGMENT = """
#version 330
uniform vec4 color;
uniform vec3 light;
in vec3 world_normal;
out vec4 out_color;
void main() {
    vec3 n = normalize(world_normal);
    vec3 reflected = normalize(n * (dot(n, light) * 2.0) - light);
    float specular = pow(max(reflected.z, 0.0), 2.0);
    float diffuse = max(0.0, dot(n, light));
    float intensity = 0.6 + min(diffuse * 0.35 + specular * 0.05, 0.4);
    out_color = vec4(floor(floor(255.0 * intensity) * color.rgb) / 255.0, 1.0);
}
"""

# The floor plane z = 0 as the camera's own floor model computes it (camera.py): tiles of
# two colours, one Lambert shade, truncated to 8 bits. Tile coordinates come from the vertex
# shader: the less a fragment computes, the less llvmpipe spends on the screenful of floor.
_FLOOR_VERTEX = """
#version 330
uniform mat4 view_projection;
uniform float per_tile;
in vec2 in_xy;
out vec2 tile_xy;
void main() {
    tile_xy = in_xy * per_tile;
    gl_Position = view_projection * vec4(in_xy, 0.0, 1.0);
}
"""

_FLOOR_FRAGMENT = """
#version 330
uniform vec3 tile_colors[2];
in vec2 tile_xy;
out vec4 out_color;
void main() {
    vec2 tile = floor(tile_xy);
    float parity = tile.x + tile.y - 2.0 * floor(0.5 * (tile.x + tile.y));
    out_color = vec4(mix(tile_colors[0], tile_colors[1], parity) / 255.0, 1.0);
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
    Meshes must wind counter-clockwise seen from outside (back faces are culled).
    """

    def __init__(self, context, width: int, height: int, k: np.ndarray,
                 world_to_optical: np.ndarray, light_direction: Sequence[float],
                 clip: tuple[float, float], floor: FloorLook) -> None:
        self.ctx = ctx = context
        self.width, self.height = width, height
        self._body = ctx.program(vertex_shader=_BODY_VERTEX, fragment_shader=_BODY_FRAGMENT)
        self._floor = ctx.program(vertex_shader=_FLOOR_VERTEX, fragment_shader=_FLOOR_FRAGMENT)
        near, far = clip
        a, b = (far + near) / (far - near), -2 * far * near / (far - near)
        # The depth buffer's d (0-1) back to the optical z: z = (B / 2) / (d - (1 + A) / 2).
        self._depth_map = (np.float32((1 + a) / 2), np.float32(b / 2))
        # Optical frame to clip space with pixel i's centre (window i + 0.5) on coordinate i;
        # image row v is window row v, so the read-back rows come top first (and a face
        # counter-clockwise seen from outside is clockwise on the window).
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
        self._fbo, self._floor_fbo = (
            ctx.framebuffer([ctx.renderbuffer((width, height), 4)],
                            ctx.depth_renderbuffer((width, height))) for _ in range(2))
        # The floor and background never change for a camera: drawn once, copied each frame
        # with their depth (a copy costs a twentieth of drawing them).
        self._floor_fbo.use()
        self._floor_fbo.clear(*background, 1.0, depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        ctx.depth_func = '<'
        floor_vao.render()
        self._rgba = np.empty((height, width, 4), dtype=np.uint8)
        self._meshes: dict[GeometryKey, object] = {}
        self._resources = [
            self._body, self._floor, floor_vao, floor_corners,
            *(item for fbo in (self._fbo, self._floor_fbo)
              for item in (fbo, *fbo.color_attachments, fbo.depth_attachment))]

    def render(self, snapshot: SceneSnapshot) -> tuple[np.ndarray, np.ndarray]:
        """Return colour (H, W, 3) uint8 and depth (H, W) float32 metres (+inf: no return)."""
        ctx = self.ctx
        ctx.copy_framebuffer(self._fbo, self._floor_fbo)
        self._fbo.use()
        ctx.enable(ctx.DEPTH_TEST | ctx.CULL_FACE)
        ctx.front_face = 'cw'
        ctx.depth_func = '<'
        model, color = self._body['model'], self._body['color']
        # Column-major, as OpenGL reads a mat4: each pose transposed, all in one buffer.
        poses = snapshot.poses.transpose(0, 2, 1).tobytes()
        colors = snapshot.colors.tobytes()
        for i, key in enumerate(snapshot.keys):
            model.write(poses[64 * i:64 * i + 64])
            color.write(colors[16 * i:16 * i + 16])
            self._vertex_array(key).render()
        # RGBA reads back as stored; RGB would be repacked pixel by pixel, as numpy would.
        self._fbo.read_into(self._rgba, components=4, attachment=0, alignment=1)
        depth = np.empty((self.height, self.width), dtype=np.float32)
        self._fbo.read_into(depth, attachment=-1, dtype='f4')
        no_return = depth >= 1.0
        middle, half_b = self._depth_map
        depth -= middle
        np.divide(half_b, depth, out=depth)
        depth[no_return] = np.inf
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
