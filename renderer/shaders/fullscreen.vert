#version 330 core
// A triangle covering the whole viewport, from gl_VertexID alone (draw 3 vertices, no attributes): uv in [0, 1]^2
// over the viewport, (0, 0) at the bottom-left.

out vec2 v_uv;

void main() {
    vec2 corner = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));  // (0,0), (2,0), (0,2)
    v_uv = corner;
    gl_Position = vec4(2.0 * corner - 1.0, 0.0, 1.0);
}
