#version 330 core
// Transforms a mesh to clip space and passes its world-space position, normal and texture coordinates on to the
// Kubelka-Munk layer pass (km_layers.frag), which lights the surface and looks up per-layer thickness maps over uv.

layout(location = 0) in vec3 a_position;  // object space, scene units (mm)
layout(location = 1) in vec3 a_normal;    // object space, unit length
layout(location = 2) in vec2 a_uv;        // texture coordinates, (0, 0) bottom-left
layout(location = 3) in float a_occlusion; // ambient occlusion baked per vertex, 1: open sky

uniform mat4 u_model;            // object -> world
uniform mat4 u_view_projection;  // world -> clip
uniform mat3 u_normal_matrix;    // inverse transpose of the model's upper 3x3
uniform mat4 u_view;             // world -> camera

out vec3 v_position;
out vec3 v_normal;
out vec2 v_uv;
out float v_occlusion;
out float v_view_depth;          // distance in front of the camera along its axis, mm

void main() {
    vec4 world = u_model * vec4(a_position, 1.0);
    v_position = world.xyz;
    v_normal = u_normal_matrix * a_normal;
    v_uv = a_uv;
    v_occlusion = a_occlusion;
    v_view_depth = -(u_view * world).z;
    gl_Position = u_view_projection * world;
}
