#version 330 core
// Depth bound of what each multisample shows (renderer.visible_depth): the winning fragment's window depth at the
// pixel's centre plus half its footprint, z + 0.5 fwidth(z), an upper bound on its depth anywhere in the pixel (a
// triangle's window depth is linear in x and y, and every sample lies within half a pixel of the centre on each axis).

layout(location = 0) out vec4 f_bound;

void main() {
    f_bound = vec4(gl_FragCoord.z + 0.5 * fwidth(gl_FragCoord.z), 0.0, 0.0, 1.0);
}
