#version 330 core
// Shadow-map depth pass: transforms a mesh into the light's clip space. Only the depth is written; normals and
// texture coordinates (locations 1 and 2) are in the vertex arrays but unused. The world position is computed as
// in the lighting passes (u_model first), so that both passes round it the same way in float32.

layout(location = 0) in vec3 a_position;  // object space, scene units (mm)

uniform mat4 u_model;            // object -> world
uniform mat4 u_view_projection;  // world -> light clip space (renderer.shadows.light_view_projection)

void main() {
    gl_Position = u_view_projection * (u_model * vec4(a_position, 1.0));
}
