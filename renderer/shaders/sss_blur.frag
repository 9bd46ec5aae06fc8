#version 330 core
// One separable pass of screen-space subsurface scattering (Jimenez et al. 2009; thesis section 3.2).
//
// A 7-tap Gaussian along u_direction (1, 0) or (0, 1) of the skin irradiance u_source, restricted to skin pixels
// (the skin mask rides in u_source's alpha, 1 on skin, so that a tap is one texture fetch). The taps lie at k / 3 of the kernel's reach w (pixels), k = -3 .. 3, with weights 0.006,
// 0.061, 0.242, 0.382, 0.242, 0.061, 0.006 (a Gaussian of standard deviation w / 3 sampled at -3 .. 3 deviations).
// The reach follows the stretch S of thesis eq. 3.1 and thesis eq. 3.2:
//   S = alpha / (d + beta * min(|grad d|, clamp)),   w = 3 * width * S * c
// with width = sqrt(v_i - v_(i-1)) (mm) the widening of this Gaussian of the skin profile, d the view depth in metres
// (1 for an orthographic camera), grad d its larger change to either neighbour along the pass's direction
// (metres; at the image's border the pixel itself stands in for the missing neighbour) and c the
// camera's scale: pixels per mm at 1 m (perspective: the focal length in pixels / 1000; orthographic: pixels per mm).
// With beta = 0, alpha = 1 makes w / 3 the Gaussian's true projected standard deviation: alpha is the scale of the
// blur against the measured skin profile.
// A tap on a pixel that is not skin takes the centre's value instead, so the blur neither bleeds skin light onto the
// background nor darkens the skin's silhouette; the weights sum to 1, so a uniform region keeps its value.
// Outside the skin the pass writes its input unchanged.
// A multisampled frame's silhouette pixel (renderer.multisample) is partly skin: its mask a (0.5 <= a < 1) is the
// skin's share of the pixel and its light the skin's light times a. It is blurred as skin of light rgb / a (its taps
// that are not skin take that value), and the result is scaled back by a: the blur neither brightens nor darkens the
// share of the pixel that is skin. Pixels less than half skin pass unchanged.

in vec2 v_uv;

uniform sampler2D u_source;   // RGB: light that entered the skin and came back out (linear); A: skin mask
uniform sampler2D u_depth;    // r: view depth (mm)
uniform vec2 u_direction;     // (1, 0): horizontal, (0, 1): vertical
uniform vec2 u_pixel;         // size of a pixel in uv
uniform float u_width;        // sqrt of the variance added by this Gaussian, mm
uniform float u_alpha;        // global subsurface scattering level (1: the measured profile at true scale)
uniform float u_scale;        // c: pixels per mm at 1 m (perspective) or pixels per mm (orthographic)
uniform int u_orthographic;   // 1: d = 1 (no perspective)
uniform float u_beta;         // depth-gradient correction
uniform float u_clamp;        // largest depth gradient used, metres per pixel

layout(location = 0) out vec4 f_colour;      // the blurred light, the next pass's source
layout(location = 1) out vec4 f_accumulate;  // the same, for the accumulator (alpha-blended by the caller)

const float WEIGHTS[7] = float[7](0.006, 0.061, 0.242, 0.382, 0.242, 0.061, 0.006);

void main() {
    vec4 centre = texelFetch(u_source, ivec2(gl_FragCoord.xy), 0);
    if (centre.a < 0.5) {
        f_colour = centre;
        f_accumulate = centre;
        return;
    }
    ivec2 here = ivec2(gl_FragCoord.xy);
    ivec2 last = textureSize(u_depth, 0) - 1;
    ivec2 offset = ivec2(u_direction);
    float depth = texelFetch(u_depth, here, 0).r * 1e-3;
    float next = texelFetch(u_depth, clamp(here + offset, ivec2(0), last), 0).r * 1e-3;
    float previous = texelFetch(u_depth, clamp(here - offset, ivec2(0), last), 0).r * 1e-3;
    float gradient = max(abs(next - depth), abs(depth - previous));  // steeper side (a silhouette: the clamp)
    float d = u_orthographic == 1 ? 1.0 : depth;
    float reach = 3.0 * u_width * u_scale * u_alpha / (d + u_beta * min(gradient, u_clamp));
    vec2 step_uv = u_direction * u_pixel;
    vec3 own = centre.rgb / centre.a;
    vec3 sum = vec3(0.0);
    for (int k = 0; k < 7; ++k) {
        vec4 tap = texture(u_source, v_uv + float(k - 3) / 3.0 * reach * step_uv);
        sum += WEIGHTS[k] * (tap.a > 0.999 ? tap.rgb : own);  // filtered mask: skin on both texels
    }
    f_colour = vec4(sum * centre.a, centre.a);
    f_accumulate = f_colour;
}
