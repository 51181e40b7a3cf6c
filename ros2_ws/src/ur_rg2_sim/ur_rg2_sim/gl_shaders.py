"""The GL camera's shader programs (GLSL 3.30), as :mod:`ur_rg2_sim.gl_renderer` compiles them.

The body program shades as TinyRenderer does (ambient, diffuse and specular terms, colours
truncated to 8 bits) and writes the fragment's optical z in metres to a second target; the
floor program draws the analytic tiles under the bodies.
"""

# Shapes drawn in one call: each vertex names its shape, whose pose and colour come from
# uniform blocks (std140: a mat4 is 64 bytes, a vec4 16). 256 of each fits the 16 KB a block
# may always hold; a scene with more shapes is drawn in several calls.
SHAPES_PER_DRAW = 256

BODY_VERTEX = """
#version 330
layout(std140) uniform Poses { mat4 poses[256]; };
layout(std140) uniform Colors { vec4 colors[256]; };
uniform mat4 view_projection;
in vec3 in_position;
in vec3 in_normal;
in int in_shape;
out vec3 world_normal;
flat out vec3 color;
void main() {
    mat4 model = poses[in_shape];
    world_normal = mat3(model) * in_normal;
    color = colors[in_shape].rgb;
    gl_Position = view_projection * (model * vec4(in_position, 1.0));
}
"""

# TinyRenderer's shader (bullet3 examples/TinyRenderer): the specular term uses the world z
# of the reflected light, with exponent 2 when a model has no specular map. The depth output
# is the fragment's optical z in metres: the clip w of this camera's projection, 1 / w here.
BODY_FRAGMENT = """
#version 330
uniform vec3 light;
in vec3 world_normal;
flat in vec3 color;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
void main() {
    vec3 n = normalize(world_normal);
    float lit = dot(n, light);
    // The z of the light reflected about n (unit: n and light are), squared.
    float specular = max(n.z * (lit * 2.0) - light.z, 0.0);
    float intensity = 0.6 + min(max(0.0, lit) * 0.35 + specular * specular * 0.05, 0.4);
    out_color = vec4(floor(floor(255.0 * intensity) * color) / 255.0, 1.0);
    out_depth = 1.0 / gl_FragCoord.w;
}
"""

# The floor plane z = 0 as the camera's own floor model computes it (camera.py): tiles of
# two colours, one Lambert shade, truncated to 8 bits. Tile coordinates come from the vertex
# shader: the less a fragment computes, the less llvmpipe spends on the screenful of floor.
FLOOR_VERTEX = """
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

FLOOR_FRAGMENT = """
#version 330
uniform vec3 tile_colors[2];
in vec2 tile_xy;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;
void main() {
    vec2 tile = floor(tile_xy);
    float parity = tile.x + tile.y - 2.0 * floor(0.5 * (tile.x + tile.y));
    out_color = vec4(mix(tile_colors[0], tile_colors[1], parity) / 255.0, 1.0);
    out_depth = 1.0 / gl_FragCoord.w;
}
"""
