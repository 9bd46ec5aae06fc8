#version 330 core
// Transforms a mesh to clip space and passes its world-space normal on to the fragment stage.
// Texture coordinates (location 2) are in the vertex arrays but unused by this pass.

layout(location = 0) in vec3 a_position;  // object space, scene units (mm)
layout(location = 1) in vec3 a_normal;    // object space, unit length

uniform mat4 u_model;            // object -> world
uniform mat4 u_view_projection;  // world -> clip
uniform mat3 u_normal_matrix;    // inverse transpose of the model's upper 3x3

out vec3 v_normal;

void main() {
    v_normal = u_normal_matrix * a_normal;
    gl_Position = u_view_projection * (u_model * vec4(a_position, 1.0));
}
