#version 400 core
// The filter of the soft-shadow pass (renderer.layers), between light_visibility.frag and the shading pass: each
// texel's visibility averaged with its neighbours' on the same surface, which removes the noise of the discs turned
// per texel (16 taps each) without widening the penumbra much. Drawn twice over the whole of a target of the pass's
// size (fullscreen.vert): along x (AXIS 0), then along y (AXIS 1) over what the first drew, a tent each time, their
// product the filter's kernel (a separable filter: 2 (2 RADIUS + 1) taps where the kernel has (2 RADIUS + 1)^2).
//
// At a texel whose reach r (texels; light_visibility.frag: half the penumbra's width, 0 where no light found a
// blocker) is positive, the weights are a tent, w = max(0, 1 - |d| / h) with h = min(r / 2, RADIUS + 1) for the
// offset d (texels) along the axis, over the texels up to RADIUS away: a kernel at most a quarter of the penumbra's
// width (2 r) from its centre to its edge, so that a penumbra, linear across where the kernel lies wholly inside it,
// keeps its shape (its 10-90 % width grows by at most 4 %, tests/test_renderer_environment.py); a penumbra narrower
// than 4 texels is kept as it is. A neighbour counts only where it lies on the texel's surface: its normal within 25
// degrees of the texel's, and its point within 15 degrees of the texel's plane as seen from the texel's point (not
// behind a silhouette or across a step). Where r is 0 the texel is lit by every light, exactly, and kept.
//
// Inputs: the visibility to filter, the pass's plane and reach targets. Outputs: the filtered visibility, and the
// plane as it was, for the shading pass (the first pass's target has no room for it, and it is dropped there).
// Compile-time constants: RADIUS (texels), AXIS (0: x, 1: y).

uniform sampler2D u_visibility;   // light i's visibility in channel i (AXIS 1: as filtered along x)
uniform sampler2D u_plane;        // unit normal n, n.p (mm); 0 where no surface shows
uniform sampler2D u_reach;        // point p (mm), the filter's reach r (texels)

layout(location = 0) out vec4 f_visibility;
layout(location = 1) out vec4 f_plane;

void main() {
    ivec2 at = ivec2(gl_FragCoord.xy);
    ivec2 last = textureSize(u_visibility, 0) - 1;
    ivec2 step = AXIS == 0 ? ivec2(1, 0) : ivec2(0, 1);
    vec4 centre = texelFetch(u_visibility, at, 0);
    vec4 plane = texelFetch(u_plane, at, 0);
    vec4 reach = texelFetch(u_reach, at, 0);
    vec4 visibility = centre;
    if (reach.w > 0.0) {
        float h = min(0.5 * reach.w, float(RADIUS + 1));
        int n = int(ceil(h)) - 1;  // texels each way with a weight above 0
        vec4 sum = vec4(0.0);
        float total = 0.0;
        for (int d = -n; d <= n; ++d) {
            float w = max(1.0 - abs(float(d)) / h, 0.0);
            ivec2 texel = clamp(at + d * step, ivec2(0), last);
            vec4 other = texelFetch(u_plane, texel, 0);
            vec3 offset = texelFetch(u_reach, texel, 0).xyz - reach.xyz;
            if (dot(other.xyz, plane.xyz) >= 0.9 && abs(dot(plane.xyz, offset)) <= 0.26 * length(offset)) {
                sum += w * texelFetch(u_visibility, texel, 0);
                total += w;
            }
        }
        visibility = total > 0.0 ? sum / total : centre;  // (the texel itself counts unless its normal is degenerate)
    }
    f_visibility = visibility;
    f_plane = plane;
}
