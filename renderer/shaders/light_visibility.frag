#version 400 core
// The soft-shadow pass of renderer.layers: the area lights' visibility at 1 / SOFT_SHADOW_SCALE of the frame's
// resolution, drawn over the whole of a target that size (fullscreen.vert), between the surface attributes and the
// shading pass (km_layers.frag), which upsamples it after soft_shadow_filter.frag has filtered it.
//
// Each texel covers a block of SOFT_SHADOW_SCALE x SOFT_SHADOW_SCALE pixels; its point is the first of them (row by
// row from the bottom left) whose first sample shows a surface (surface_attributes.frag). There, for each area light,
// the percentage-closer soft shadow of shadow_lookup.glsl (the 32 taps that make soft shadows the costliest part of
// the shading), the discs turned by this texel's noise. Outputs: the visibility of light i in channel i (1 where a
// light is not an area light or no surface shows); the plane of the surface there (its interpolated unit normal n
// and n.p, p the point in mm; 0 where no surface shows), for the shading pass to tell whether a texel lies on the
// surface it shades; and, for the filter (soft_shadow_filter.frag), the point p and how far (texels of this pass) the
// filter may reach there: the smallest disc radius (half the penumbra's width) of the lights that found a blocker, in
// texels of this pass on the surface, foreshortened by the surface's slope to the view; 0 where no light found one.
//
// Compile-time constants (renderer.layers): SAMPLES, SOFT_SHADOW_SCALE, LIGHT_COUNT, POINT_LIGHTS, SOFT_LIGHTS,
// ORTHOGRAPHIC.

#define MAX_LIGHTS 4
#define BIT(mask, i) (((mask) >> (i)) & 1)

#if SAMPLES > 1
#define ATTRIBUTES sampler2DMS
#define ATTRIBUTE_SIZE(a) textureSize(a)
#else
#define ATTRIBUTES sampler2D
#define ATTRIBUTE_SIZE(a) textureSize(a, 0)
#endif
uniform ATTRIBUTES u_attributes0;            // position (mm), view depth
uniform ATTRIBUTES u_attributes1;            // interpolated normal, occlusion
uniform ATTRIBUTES u_attributes2;            // shading normal, the mesh's index (-1: nothing drawn)
uniform vec2 u_footprint;                    // a pixel's size (mm) at view depth d: x + y d
uniform vec3 u_view_vector;                  // ORTHOGRAPHIC: unit vector towards the camera; else: eye (mm)

#include "shadow_lookup.glsl"

layout(location = 0) out vec4 f_visibility;
layout(location = 1) out vec4 f_plane;
layout(location = 2) out vec4 f_reach;

void main() {
    ivec2 size = ATTRIBUTE_SIZE(u_attributes2);
    ivec2 corner = ivec2(gl_FragCoord.xy) * SOFT_SHADOW_SCALE;
    ivec2 pixel = corner;
    float object = -1.0;
    for (int k = SOFT_SHADOW_SCALE * SOFT_SHADOW_SCALE - 1; k >= 0; --k) {  // the first one showing a surface wins
        ivec2 candidate = min(corner + ivec2(k % SOFT_SHADOW_SCALE, k / SOFT_SHADOW_SCALE), size - 1);
        float index = texelFetch(u_attributes2, candidate, 0).w;
        if (index >= 0.0) {
            pixel = candidate;
            object = index;
        }
    }
    vec4 a0 = texelFetch(u_attributes0, pixel, 0);
    vec3 position = a0.xyz;
    vec3 normal = normalize(texelFetch(u_attributes1, pixel, 0).xyz);
    vec4 visibility = vec4(1.0);
    float disc = 0.0;  // the smallest disc radius (mm) of the lights that found a blocker; 0: none did
#if SOFT_LIGHTS != 0
    for (int light = 0; light < LIGHT_COUNT; ++light) {
        if (BIT(SOFT_LIGHTS, light) == 1) {
            vec3 point = shadow_point(light, position, normal, towards_light(light, position));
            float radius;
            visibility[light] = soft_visibility(light, point, normal, shadow_texel(light), gl_FragCoord.xy, radius);
            if (radius > 0.0) disc = disc > 0.0 ? min(disc, radius) : radius;
        }
    }
#endif
    vec3 view = ORTHOGRAPHIC == 1 ? u_view_vector : normalize(u_view_vector - position);
    float texel_mm = float(SOFT_SHADOW_SCALE) * (u_footprint.x + u_footprint.y * a0.w);
    f_visibility = object >= 0.0 ? visibility : vec4(1.0);
    f_plane = object >= 0.0 ? vec4(normal, dot(normal, position)) : vec4(0.0);
    f_reach = object >= 0.0 ? vec4(position, disc * max(abs(dot(normal, view)), 0.25) / texel_mm) : vec4(0.0);
}
