// Shadow-map lookups (renderer.shadows), shared by the shading pass (km_layers.frag) and the soft-shadow pass
// (light_visibility.frag), which include this file. The including shader defines MAX_LIGHTS, BIT(mask, i),
// LIGHT_COUNT and the bit masks POINT_LIGHTS and SOFT_LIGHTS (km_layers.frag lists them).
//
// A light's visibility at a point (0 = shadowed, 1 = lit) is looked up a little off the surface, along its
// interpolated normal (more at grazing light), so that a curved surface does not shadow itself between the map's
// texels ("acne"). A hard light takes 3 x 3 PCF taps, each a 2 x 2 filtered lookup. An area light takes
// percentage-closer soft shadows: 16 taps of a blocker search over the region the light can be seen through (a disc
// as wide as its penumbra for an occluder at the frustum's near end), their mean distance d_o, then 16 PCF taps over
// a disc as wide as the penumbra the light casts from there, the disc turned per pixel by interleaved gradient noise
// (Jimenez 2014), whose noise soft_shadow_filter.frag filters out along each surface (and supersampling averages).
// Both discs have a radius of 1 texel up to a sixteenth of the map's side, whatever its size, and every tap is
// compared with the depth of the receiver's own plane there (soft_visibility says more).

uniform vec3 u_light_vector[MAX_LIGHTS];     // directional: unit vector towards the light; point: position (mm)
uniform mat4 u_shadow_matrix[MAX_LIGHTS];    // world -> shadow map texture coordinates and depth, [0, 1]^3
uniform float u_shadow_texel[MAX_LIGHTS];    // size of a shadow map texel at the scene's centre, mm
uniform sampler2DShadow u_shadow0;
uniform sampler2DShadow u_shadow1;
uniform sampler2DShadow u_shadow2;
uniform sampler2DShadow u_shadow3;
uniform float u_light_softness[MAX_LIGHTS];  // an area light's size: directional: 2 tan(angle / 2); point: diameter, mm
uniform vec2 u_shadow_range[MAX_LIGHTS];     // near and far distance (mm) of the light's shadow frustum
uniform sampler2D u_shadow_depth0;           // the shadow maps' raw depths (no comparison), for the blocker search
uniform sampler2D u_shadow_depth1;
uniform sampler2D u_shadow_depth2;
uniform sampler2D u_shadow_depth3;

// Unit vector from `position` towards the light.
vec3 towards_light(int light, vec3 position) {
    if (BIT(POINT_LIGHTS, light) == 1) return normalize(u_light_vector[light] - position);
    return u_light_vector[light];
}

// Where a light's shadow map is looked up for a surface at `position` of interpolated unit normal `geometric` lit
// from the unit direction `l`: 0.5 to 2 texels off the surface along the normal, more at grazing light.
vec3 shadow_point(int light, vec3 position, vec3 geometric, vec3 l) {
    float cos_geometric = max(dot(geometric, l), 0.0);
    return position + geometric * u_shadow_texel[light] * (0.5 + 1.5 * (1.0 - cos_geometric));
}

// Shadow-map texture coordinates (xy) and depth (z) of a world point.
vec3 shadow_coordinates(int light, vec3 point) {
    vec4 coordinates = u_shadow_matrix[light] * vec4(point, 1.0);
    return coordinates.xyz / coordinates.w;
}

// The size of a texel of the light's shadow map in texture coordinates.
vec2 shadow_texel(int light) {
    if (light == 0) return 1.0 / vec2(textureSize(u_shadow0, 0));
    if (light == 1) return 1.0 / vec2(textureSize(u_shadow1, 0));
    if (light == 2) return 1.0 / vec2(textureSize(u_shadow2, 0));
    return 1.0 / vec2(textureSize(u_shadow3, 0));
}

float shadow_compare(int light, vec3 tap) {
    if (light == 0) return texture(u_shadow0, tap);
    if (light == 1) return texture(u_shadow1, tap);
    if (light == 2) return texture(u_shadow2, tap);
    return texture(u_shadow3, tap);
}

// Visibility of a hard light at shadow-map coordinates p: 3 x 3 PCF taps.
float hard_visibility(int light, vec3 p, vec2 texel) {
    float lit = 0.0;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) lit += shadow_compare(light, vec3(p.xy + vec2(dx, dy) * texel, p.z));
    }
    return lit / 9.0;
}

#if SOFT_LIGHTS != 0
float shadow_depth(int light, vec2 at) {
    if (light == 0) return textureLod(u_shadow_depth0, at, 0.0).r;
    if (light == 1) return textureLod(u_shadow_depth1, at, 0.0).r;
    if (light == 2) return textureLod(u_shadow_depth2, at, 0.0).r;
    return textureLod(u_shadow_depth3, at, 0.0).r;
}

// Distance (mm) from the light along its axis of a shadow-map depth: linear for a directional light's orthographic
// frustum, s = f n / (f - depth (f - n)) for a point light's perspective one.
float light_distance(int light, float depth) {
    vec2 r = u_shadow_range[light];
    if (BIT(POINT_LIGHTS, light) == 1) return r.x * r.y / (r.y - depth * (r.y - r.x));
    return r.x + depth * (r.y - r.x);
}

// Penumbra width (mm) of a light at a receiver `receiver` mm from it behind an occluder `blocker` mm from it.
float penumbra(int light, float receiver, float blocker) {
    float gap = max(receiver - blocker, 0.0);
    return u_light_softness[light] * (BIT(POINT_LIGHTS, light) == 1 ? gap / max(blocker, 1e-6) : gap);
}

// How far beyond half its own penumbra's width a tap of the PCF disc in front of the receiver still counts as a
// blocker (soft_visibility): the slack that the one mean blocker distance of percentage-closer soft shadows needs.
const float PENUMBRA_SLACK = 3.0;

const vec2 DISC[16] = vec2[16](
    vec2(-0.9465, -0.1484), vec2(-0.7431, 0.5353), vec2(-0.5863, -0.5879), vec2(-0.3935, 0.1025),
    vec2(-0.2428, 0.8663), vec2(-0.1672, -0.9260), vec2(-0.0793, -0.3570), vec2(0.0626, 0.4394),
    vec2(0.1790, -0.0364), vec2(0.2735, 0.9045), vec2(0.3360, -0.6447), vec2(0.4768, 0.2973),
    vec2(0.6063, -0.2457), vec2(0.7140, 0.6440), vec2(0.8413, -0.5226), vec2(0.9620, 0.1130));

// The depth gradient d(depth) / d(xy) in the shadow map of the plane through the world point `point` (shadow-map
// coordinates p) with unit normal `normal`: from two points of the plane a texel away along two tangents, Cramer's
// rule on depth = p.z + g . (xy - p.xy). (0, 0) where the map sees the plane edge-on (it holds no depth of it there).
vec2 receiver_gradient(int light, vec3 point, vec3 normal, vec3 p) {
    vec3 t1 = normalize(cross(normal, abs(normal.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0)));
    vec3 t2 = cross(normal, t1);
    vec3 d1 = shadow_coordinates(light, point + u_shadow_texel[light] * t1) - p;
    vec3 d2 = shadow_coordinates(light, point + u_shadow_texel[light] * t2) - p;
    float det = d1.x * d2.y - d1.y * d2.x;
    vec2 g = vec2(d1.z * d2.y - d1.y * d2.z, d1.x * d2.z - d1.z * d2.x) / det;
    return abs(det) > 1e-3 * length(d1.xy) * length(d2.xy) ? g : vec2(0.0);
}

// Visibility of an area light at the world point `point` of a surface of unit normal `normal` (percentage-closer
// soft shadows, as the top of this file says), the discs turned by the noise of window position `pixel`. Each tap
// is compared with the depth of the surface's own plane there (receiver_gradient) or the point's, whichever is
// nearer the light: over a disc many texels wide, a surface at an angle to the map would otherwise shadow itself on
// the side nearer the light, and nothing farther from the light than the point can hide the light from it. A tap of
// the PCF disc in front of that depth counts as a blocker only within (PENUMBRA_SLACK times) half the penumbra a
// blocker at its own depth casts: where the light it hides can reach the point. A floor in front of a wall that
// stands on it lies in front of the wall's plane but sees the light at too low an angle to hide it from the wall.
// `disc`: the radius (mm, across the light's axis) of the disc the visibility was filtered over, half the estimated
// penumbra's width; 0 where the blocker search found nothing (the point is lit, exactly).
float soft_visibility(int light, vec3 point, vec3 normal, vec2 texel, vec2 pixel, out float disc) {
    // (if blocks, no early returns: llvmpipe runs the code after a return)
    vec3 p = shadow_coordinates(light, point);
    vec2 g = receiver_gradient(light, point, normal, p);
    float visibility = 1.0;
    float angle = 6.2831853 * fract(52.9829189 * fract(dot(pixel, vec2(0.06711056, 0.00583715))));
    mat2 turn = mat2(cos(angle), sin(angle), -sin(angle), cos(angle));
    float receiver = light_distance(light, p.z);
    // disc radii (texels): half the penumbra's width, at most a sixteenth of the map's side (64 texels of a 1024 map):
    // the same disc on the scene whatever the map's size, a larger map sampling it more finely
    float most = max(1.0, 0.0625 / texel.x);
    float reach = 0.5 * penumbra(light, receiver, u_shadow_range[light].x) / u_shadow_texel[light];
    float search = clamp(reach, 1.0, most);
    float blockers = 0.0;
    int found = 0;
    disc = 0.0;
    for (int i = 0; i < 16; ++i) {
        vec2 offset = turn * DISC[i] * search * texel;
        float depth = shadow_depth(light, p.xy + offset);
        if (depth < min(p.z, p.z + dot(g, offset))) {
            blockers += light_distance(light, depth);
            ++found;
        }
    }
    if (found > 0) {
        float spread = 0.5 * penumbra(light, receiver, blockers / float(found)) / u_shadow_texel[light];
        float width = clamp(spread, 1.0, most);
        float lit = 0.0;
        for (int i = 0; i < 16; ++i) {
            vec2 offset = turn * DISC[i] * width * texel;
            float reference = min(p.z, p.z + dot(g, offset));
            float tap = shadow_compare(light, vec3(p.xy + offset, reference));
            if (tap < 1.0) {  // (a lit tap, which most are, needs no more)
                float depth = shadow_depth(light, p.xy + offset);
                float across = width * length(DISC[i]) * u_shadow_texel[light];
                float reaches = PENUMBRA_SLACK * 0.5 * penumbra(light, receiver, light_distance(light, depth));
                tap = depth >= reference || across <= reaches ? tap : 1.0;  // (lit texels are filtered as they are)
            }
            lit += tap;
        }
        visibility = lit / 16.0;
        disc = width * u_shadow_texel[light];
    }
    return visibility;
}
#endif
