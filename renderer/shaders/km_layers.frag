#version 400 core
// Kubelka-Munk layer compositing with per-layer specular lobes, under up to 4 lights with shadow maps: the shading pass
// of renderer.layers, drawn over the whole frame (fullscreen.vert) once per mesh, reading what each sample shows from
// the surface attributes (surface_attributes.frag: position, view depth, normals, occlusion, uv, the mesh's index).
//
// Samples and pixels. A pixel's samples that show this mesh (u_object; the stencil lets only pixels with one through)
// are grouped: a sample joins the first one not yet shaded when it shows the same smooth surface, its normal within
// SAME_COS of the other's and its view depth within SAME_PIXELS pixel footprints (divided by max(|n.v|, 0.25), for
// a surface seen at a grazing angle) of it. Each group is shaded once, at its first sample's attributes, and counts
// for its number of samples; the outputs are the sum over groups of count x value / SAMPLES, added (blending) to
// what the other meshes' passes put there. So a pixel inside one triangle is shaded once and keeps its value
// exactly, a pixel crossed by a silhouette or a crease takes the share of its samples on each side, and a pixel
// where two triangles of one smooth surface meet is shaded once, as multisampling shades a triangle once a pixel.
// Alpha is the share of samples shown (the background fills the rest, renderer.background).
//
// Diffuse part. Up to 4 layers, listed bottom-up (layer 0 lies on the substrate). For each layer the fragment looks
// up the reflectance R0 and transmittance T of the film at its thickness X (mm) in an optical table, interpolating
// linearly between thickness samples and clamping at the ends, then composes it onto the reflectance Rg of
// everything beneath it (thesis eq. 3.14; the thesis prints T2 where R2 belongs):  Rg <- R0 + T^2 Rg / (1 - R0 Rg).
// The substrate is uniform (u_substrate) or varies over uv (an albedo texture): then its channels are a mix of three
// basis reflectances with weights read from u_substrate_map, clamped to [0, 1].
// Channels are rgb (3) or spectral bands (up to MAX_CHANNELS), processed four at a time as vec4 groups; the
// composite is converted to linear RGB with u_to_rgb. In precomposed mode (PRECOMPOSED = 1, the `exact` render
// mode) the stack's linear RGB reflectance and each layer's specular attenuation come ready-made from u_composite.
//
// Specular part (thesis eq. 3.15, Kelemen and Szirmay-Kalos 2001), for each layer with a lobe, at the layer's own
// top surface (all layers share the mesh's normal N):
//   f_spec = P(H) F(H.L) / (2 (1 + L.V)),  P(H) = exp(-tan^2(a) / m^2) / (pi m^2 cos^4(a)),  cos(a) = N.H,
//   F(c) = F0 + (1 - F0) (1 - c)^5 (Schlick),  F0 = ((n - 1) / (n + 1))^2.
// P carries the 1/pi that normalises the Beckmann distribution (integral of P cos(a) over the hemisphere = 1; the
// thesis prints it without), so a lobe reflects at most the fraction F of the light. The light reaching layer i and
// coming back out is attenuated by the films above it: A_i = product over layers j above i of T_j^2 (per channel,
// converted to RGB like the diffuse part).
//
// The substrate may have a lobe of its own (skin: F0 ~ 0.028), attenuated by every film (A = product of all T^2),
// its roughness from a map over uv where there is one (ROUGHNESS_MAP). A film's own lobe is weighted by its
// cover, clamp(t / u_lobe_cover_mm, 0, 1) (renderer.stack.LOBE_COVER_MM): where a thickness map falls to zero the film,
// and its gloss, are gone (a precomposed stack comes with the cover in its attenuation).
//
// Fine detail: every term uses the shading normal (surface_attributes.frag: the normal map's detail over the
// interpolated normal, its tilt smoothed by the films' total thickness, as a film fills fine lines); shadow lookups
// keep the interpolated normal.
//
// Radiance. With E_l the light's value for a white Lambert surface facing it (the unit of the whole renderer) and
// v_l its shadow visibility (0 = shadowed, 1 = lit; shadow_lookup.glsl: a hard light's 3 x 3 PCF taps, an area
// light's percentage-closer soft shadow, computed here or upsampled from the soft-shadow pass, light_visibility.frag):
//   colour = sum over lights of E_l v_l max(N.L, 0) (R_rgb + pi sum_i A_i f_spec,i)
// (a white Lambert surface renders as E cos(theta), so its BRDF 1/pi is scaled by pi; the lobes follow suit).
//
// Environment (ENVIRONMENT = 1; renderer.environment): with the normal n and mirror direction r = reflect(-v, n) turned
// into the environment's frame by u_env_rotation, and AO the vertex's baked ambient occlusion (renderer.occlusion)
// times, on a floor, its baked grid's (floor_occlusion below),
//   colour += s AO (E(n) / pi) R_rgb + s AO sum_i A_i (F0_i a(mu, m_i) + b(mu, m_i)) L_m_i(r)
// with s the intensity, E / pi the prefiltered irradiance map, L_m the specular level for roughness m (linear between
// levels) and (a, b) the lobe albedo table at mu = max(n.v, 0) (the split sum). The diffuse term enters the skin like
// a light's: E / pi AO (R_rgb - R_black) goes to f_skin in split mode.
//
// Split mode (SKIN_SPLIT = 1: the skin pass of renderer.skin, on the skin): the light that entered the substrate and
// came back out, E v cos (R_rgb - R_black) with R_black the stack's reflectance over a black substrate, goes to f_skin
// (to be blurred by subsurface scattering) with the skin mask in its alpha; everything else, E v cos (R_black +
// pi sum A f), to f_colour. f_depth holds the view-space depth (mm) of every surface. Without a blur, f_colour +
// f_skin = colour.
//
// Table texture layout (RGBA32F, read with texelFetch, one texel column per thickness sample):
//   rows 0 .. G-1      R0 of channel group g (channels 4g .. 4g+3)
//   rows G .. 2G-1     T of channel group g
//   row  2G            thickness of the sample in mm (red)
// Padding channels hold R0 = T = 0 and a zero row of u_to_rgb, so they contribute nothing.
// Composite texture (precomposed mode; 2-D array over uv): layer 0 the stack's RGB reflectance over the substrate,
// layer 1 over black, layer 2 the substrate lobe's attenuation, layer 3 + i the attenuation A of film i (bottom-up).

// Compile-time constants, defined by renderer.layers for each mesh it shades (one program per combination: the loops
// over the counts unroll and the per-layer arrays stay in registers, and a switch leaves out the code it turns off,
// which llvmpipe would otherwise run under an empty mask): LAYER_COUNT (the films, 0 .. MAX_LAYERS), GROUP_COUNT
// (G = ceil(channels / 4), 1 .. MAX_GROUPS), LIGHT_COUNT (1 .. MAX_LIGHTS), SAMPLES (samples a pixel of the surface
// attributes: 1, 2 or 4); switches 0 or 1: PRECOMPOSED (reflectance and attenuation from u_composite), SUBSTRATE_MAP
// (the substrate varies over uv: an albedo texture), ROUGHNESS_MAP (the substrate lobe's roughness varies over uv),
// ENVIRONMENT (light from the environment), FLOOR (a floor with a baked occlusion grid), ORTHOGRAPHIC (the view
// direction is u_view_vector everywhere), SKIN_SPLIT (the skin pass's outputs: this surface is skin); bit masks (bit i
// for film or light i): THICKNESS_MAPS (the film's thickness from its map, else u_thickness), LOBES (the film has a
// lobe; bit MAX_LAYERS: the substrate), POINT_LIGHTS (else directional), SHADOW_LIGHTS (the light's shadow map is
// looked up), SOFT_LIGHTS (an area light: soft shadows); SOFT_SHADOW_SCALE (the soft-shadow pass's blocks, pixels a
// side: 1 or 2).
#define BIT(mask, i) (((mask) >> (i)) & 1)
#define MAX_LAYERS 4
#define MAX_GROUPS 8
#define MAX_CHANNELS 32
#define MAX_LIGHTS 4
#define PI 3.14159265358979
#define MAX_LEVELS 8

#define SAME_COS 0.9999
#define SAME_PIXELS 1.0

#if SAMPLES > 1
#define ATTRIBUTES sampler2DMS
#else
#define ATTRIBUTES sampler2D
#endif
uniform ATTRIBUTES u_attributes0;            // the surface attributes (surface_attributes.frag), targets 0 .. 3
uniform ATTRIBUTES u_attributes1;
uniform ATTRIBUTES u_attributes2;
uniform ATTRIBUTES u_attributes3;
uniform float u_object;                      // the mesh this pass shades
uniform vec2 u_footprint;                    // a pixel's size (mm) at view depth d: x + y d

// The sample being shaded (shade() reads these as a forward pass reads its varyings).
vec3 g_position = vec3(0.0);
vec3 g_normal = vec3(0.0, 0.0, 1.0);
vec2 g_uv = vec2(0.0);
float g_occlusion = 1.0;
float g_view_depth = 0.0;
vec3 g_shading = vec3(0.0, 0.0, 1.0);

uniform int u_sample_count[MAX_LAYERS];      // thickness samples per layer table (>= 1)
uniform float u_thickness[MAX_LAYERS];       // uniform layer thickness, mm
uniform vec2 u_axis[MAX_LAYERS];             // an evenly spaced thickness axis: (first sample, 1 / spacing), mm and
                                             // 1/mm; spacing unknown (0, 0): the axis is searched
uniform sampler2D u_table0;                  // optical tables of layers 0 .. 3 (layout above)
uniform sampler2D u_table1;
uniform sampler2D u_table2;
uniform sampler2D u_table3;
uniform sampler2D u_map0;                    // thickness maps over uv, mm in the red channel
uniform sampler2D u_map1;
uniform sampler2D u_map2;
uniform sampler2D u_map3;
uniform vec4 u_substrate[MAX_GROUPS];        // substrate albedo per channel, in [0, 1]
uniform sampler2D u_substrate_map;           // rgb: weights w of the three basis spectra at this uv
uniform vec4 u_substrate_basis[3 * MAX_GROUPS];  // basis b (0 .. 2), group g at b * MAX_GROUPS + g
uniform vec3 u_to_rgb[MAX_CHANNELS];         // row c: linear RGB contributed by unit reflectance in channel c
uniform sampler2DArray u_composite;          // precomposed layers (layout above)

uniform float u_roughness[MAX_LAYERS + 1];   // Beckmann m (RMS microfacet slope), > 0
uniform float u_f0[MAX_LAYERS + 1];          // Fresnel reflectance at normal incidence

uniform vec3 u_light_radiance[MAX_LIGHTS];   // E (at the reference distance for a point light)
uniform float u_light_reference[MAX_LIGHTS]; // point light: distance (mm) at which it delivers E

uniform sampler2D u_env_irradiance;          // E / pi over directions (equirectangular, u wraps)
uniform sampler2DArray u_env_specular;       // prefiltered radiance per roughness level (equirectangular)
uniform sampler2D u_env_lobe;                // lobe albedo (a, b) over mu (s) and sqrt(m) (t), texel centres at ends
uniform mat3 u_env_rotation;                 // world -> environment frame
uniform float u_env_intensity;               // s
uniform int u_env_level_count;               // specular levels (<= MAX_LEVELS)
uniform float u_env_level_m[MAX_LEVELS];     // their Beckmann m, increasing (level 0: m = 0, the image itself)
uniform vec2 u_env_lobe_range;               // sqrt(m) at the lobe table's first and last rows

uniform sampler2D u_floor;                   // the grid's AO (red): texel row i, column j at z_i, x_j (bilinear)
uniform mat4 u_floor_frame;                  // world -> the grid's frame (the product unturned), mm
uniform vec4 u_floor_grid;                   // centre x, centre z, half width (mm) and nodes per side n
uniform vec3 u_floor_fade;                   // floor height y, fade height (mm) and the rim's width (in half widths)

uniform sampler2D u_roughness_map;           // its Beckmann m (red)
uniform float u_lobe_cover_mm;               // a film's lobe is weighted by clamp(thickness / this, 0, 1)

uniform vec3 u_view_vector;                  // ORTHOGRAPHIC: unit vector towards the camera; else: eye (mm)

#include "shadow_lookup.glsl"

#if SOFT_LIGHTS != 0
uniform sampler2D u_soft_visibility;         // the soft lights' visibility (light_visibility.frag), a channel each
uniform sampler2D u_soft_plane;              // the surface's plane there: unit normal n, n.p (mm); 0 where none
#endif

layout(location = 0) out vec4 f_colour;
layout(location = 1) out vec4 f_skin;
layout(location = 2) out vec4 f_depth;

float layer_thickness(int layer) {
    if (BIT(THICKNESS_MAPS, layer) == 0) return u_thickness[layer];
    if (layer == 0) return textureLod(u_map0, g_uv, 0.0).r;
    if (layer == 1) return textureLod(u_map1, g_uv, 0.0).r;
    if (layer == 2) return textureLod(u_map2, g_uv, 0.0).r;
    return textureLod(u_map3, g_uv, 0.0).r;
}

vec4 fetch(int layer, ivec2 texel) {
    if (layer == 0) return texelFetch(u_table0, texel, 0);
    if (layer == 1) return texelFetch(u_table1, texel, 0);
    if (layer == 2) return texelFetch(u_table2, texel, 0);
    return texelFetch(u_table3, texel, 0);
}

// Where thickness x falls in a layer's table of n samples: the segment [j0, j0 + 1], the last j0 <= n - 2 whose
// sample is <= x (0 below the first), and the weight w of sample j0 + 1; clamped at both ends (w = 0 or 1 on the end
// segment). On an evenly spaced axis the segment comes from the spacing and is moved by one where rounding put it
// off by one (the samples as stored decide, so the segment is the one a search finds); else a binary search.
void locate(int layer, int n, float x, out int j0, out float w) {
    j0 = 0;
    w = 0.0;
    if (n < 2) return;
    int row = 2 * GROUP_COUNT;
    int lo = 0;
    if (u_axis[layer].y > 0.0) {
        lo = clamp(int(floor((x - u_axis[layer].x) * u_axis[layer].y)), 0, n - 2);
    } else {
        int hi = n - 1;
        while (hi - lo > 1) {
            int mid = (lo + hi) / 2;
            if (fetch(layer, ivec2(mid, row)).r <= x) lo = mid;
            else hi = mid;
        }
    }
    float x0 = fetch(layer, ivec2(lo, row)).r;
    float x1 = fetch(layer, ivec2(lo + 1, row)).r;
    if (x < x0 && lo > 0) {
        lo -= 1;
        x1 = x0;
        x0 = fetch(layer, ivec2(lo, row)).r;
    } else if (x >= x1 && lo < n - 2) {
        lo += 1;
        x0 = x1;
        x1 = fetch(layer, ivec2(lo + 1, row)).r;
    }
    j0 = lo;
    w = clamp((x - x0) / (x1 - x0), 0.0, 1.0);
}

vec3 group_to_rgb(vec4 channels, int g) {
    return channels.x * u_to_rgb[4 * g] + channels.y * u_to_rgb[4 * g + 1] + channels.z * u_to_rgb[4 * g + 2]
         + channels.w * u_to_rgb[4 * g + 3];
}

// The stack's linear RGB reflectance over the substrate and over black, and the RGB specular attenuation of each film
// (bottom-up index) and of the substrate (index MAX_LAYERS), at the films' thicknesses (mm), composed one channel group at a time: every film's R0 and
// T for the group, bottom-up, then the group's share of the RGB.
void stack_optics(float thickness[MAX_LAYERS], out vec3 reflectance, out vec3 over_black,
                  out vec3 attenuation[MAX_LAYERS + 1]) {
    for (int layer = 0; layer <= MAX_LAYERS; ++layer) attenuation[layer] = vec3(0.0);
    if (PRECOMPOSED == 1) {
        reflectance = textureLod(u_composite, vec3(g_uv, 0.0), 0.0).rgb;
        over_black = textureLod(u_composite, vec3(g_uv, 1.0), 0.0).rgb;
        attenuation[MAX_LAYERS] = textureLod(u_composite, vec3(g_uv, 2.0), 0.0).rgb;
        for (int layer = 0; layer < LAYER_COUNT; ++layer) {
            attenuation[layer] = textureLod(u_composite, vec3(g_uv, float(layer + 3)), 0.0).rgb;
        }
        return;
    }
    int j0[MAX_LAYERS];
    float w[MAX_LAYERS];
    for (int layer = 0; layer < LAYER_COUNT; ++layer) {
        locate(layer, u_sample_count[layer], thickness[layer], j0[layer], w[layer]);
    }
    reflectance = vec3(0.0);
    over_black = vec3(0.0);
    vec3 mix_weights = vec3(0.0);
#if SUBSTRATE_MAP
    mix_weights = textureLod(u_substrate_map, g_uv, 0.0).rgb;
#endif
    for (int g = 0; g < GROUP_COUNT; ++g) {
        vec4 ground = u_substrate[g];
        if (SUBSTRATE_MAP == 1) {
            ground = clamp(mix_weights.r * u_substrate_basis[g] + mix_weights.g * u_substrate_basis[MAX_GROUPS + g]
                           + mix_weights.b * u_substrate_basis[2 * MAX_GROUPS + g], 0.0, 1.0);
        }
        vec4 black = vec4(0.0);
        vec4 t2[MAX_LAYERS];
        for (int layer = 0; layer < LAYER_COUNT; ++layer) {
            int n = u_sample_count[layer];
            int j1 = min(j0[layer] + 1, n - 1);
            vec4 r0 = mix(fetch(layer, ivec2(j0[layer], g)), fetch(layer, ivec2(j1, g)), w[layer]);
            int gt = g + GROUP_COUNT;
            vec4 t = mix(fetch(layer, ivec2(j0[layer], gt)), fetch(layer, ivec2(j1, gt)), w[layer]);
            // Padding channels (r0 = t = rg = 0) and a lossless white over a white ground (denominator 0) stay finite.
            vec4 denominator = max(vec4(1.0) - r0 * ground, vec4(1e-30));
            ground = r0 + t * t * ground / denominator;
            black = r0 + t * t * black / max(vec4(1.0) - r0 * black, vec4(1e-30));
            t2[layer] = t * t;
        }
        reflectance += group_to_rgb(ground, g);
        over_black += group_to_rgb(black, g);
        if (LOBES != 0) {
            // Attenuation of film i: product of T^2 over the films above it (the top film: 1 in every channel); the
            // substrate's: over all films.
            vec4 above = vec4(1.0);
            for (int layer = LAYER_COUNT - 1; layer >= 0; --layer) {
                attenuation[layer] += group_to_rgb(above, g);
                above *= t2[layer];
            }
            attenuation[MAX_LAYERS] += group_to_rgb(above, g);
        }
    }
}

#if SOFT_LIGHTS != 0
// The soft lights' visibility at the surface point `position` (unit normal `normal`, view depth `depth`) in window
// pixel `pixel`, from the soft-shadow pass at 1 / SOFT_SHADOW_SCALE of the resolution (light_visibility.frag): the
// 3 x 3 texels around the pixel's centre, weighted by a tent 1.5 texels wide each way (which also smooths the pass's
// sampling noise), each only where its point lies on this surface (the point here within 2 texels' footprint of the
// texel's plane, the normals within 25 degrees), so that shadows do not leak across silhouettes and creases; -1
// where no texel lies on the surface.
vec4 upsampled_visibility(ivec2 pixel, vec3 position, vec3 normal, float depth) {
    vec2 c = (vec2(pixel) + 0.5) / float(SOFT_SHADOW_SCALE) - 0.5;
    ivec2 nearest = ivec2(floor(c + 0.5));
    ivec2 last = textureSize(u_soft_visibility, 0) - 1;
    float reach = 2.0 * float(SOFT_SHADOW_SCALE) * (u_footprint.x + u_footprint.y * depth);
    vec4 sum = vec4(0.0);
    float total = 0.0;
    for (int k = 0; k < 9; ++k) {
        ivec2 texel = nearest + ivec2(k % 3 - 1, k / 3 - 1);
        vec2 tent = max(1.0 - abs(vec2(texel) - c) / 1.5, 0.0);
        texel = clamp(texel, ivec2(0), last);
        vec4 plane = texelFetch(u_soft_plane, texel, 0);
        if (dot(plane.xyz, normal) >= 0.9 && abs(dot(plane.xyz, position) - plane.w) <= reach) {
            float w = tent.x * tent.y + 1e-3;
            sum += w * texelFetch(u_soft_visibility, texel, 0);
            total += w;
        }
    }
    return total > 0.0 ? sum / total : vec4(-1.0);
}
#endif

// Visibility of a light (0 = shadowed, 1 = lit) at the shadow lookup point `point` (shadow_lookup.glsl): 1 for a
// light without shadows; an area light's from the soft-shadow pass (`upsampled`, where it is >= 0) or, where that
// pass has no point on this surface nearby (a sliver of a surface), one 2 x 2 filtered lookup.
float light_visibility(int light, vec3 point, float upsampled) {
    float visibility = 1.0;
    if (BIT(SHADOW_LIGHTS, light) == 1) {
        vec3 p = shadow_coordinates(light, point);
        vec2 texel = shadow_texel(light);
#if SOFT_LIGHTS != 0
        if (BIT(SOFT_LIGHTS, light) == 1) {  // (a single filtered tap where the pass has no point: rare, and cheap)
            visibility = upsampled >= 0.0 ? upsampled : shadow_compare(light, p);
        } else {
            visibility = hard_visibility(light, p, texel);
        }
#else
        visibility = hard_visibility(light, p, texel);
#endif
    }
    return visibility;
}

// A floor's ambient occlusion at the fragment (renderer.occlusion.FloorOcclusion.at, per pixel): the grid's bilinear
// value at the fragment's place in the grid's frame, s = (x - centre) / half width in [-1, 1]^2 on the grid, its
// darkening 1 - AO scaled by smoothstep((1 - max |s|) / rim) and by smoothstep(1 - (y - floor) / fade); 1 elsewhere.
float floor_occlusion() {
    float open = 1.0;
    if (FLOOR == 1) {
        vec3 p = (u_floor_frame * vec4(g_position, 1.0)).xyz;
        vec2 s = (p.xz - u_floor_grid.xy) / u_floor_grid.z;
        float n = u_floor_grid.w;
        float value = textureLod(u_floor, ((s + 1.0) * 0.5 * (n - 1.0) + 0.5) / n, 0.0).r;
        float rim = smoothstep(0.0, 1.0, (1.0 - max(abs(s.x), abs(s.y))) / u_floor_fade.z);
        float height = smoothstep(0.0, 1.0, 1.0 - (p.y - u_floor_fade.x) / u_floor_fade.y);
        open = 1.0 - (1.0 - value) * rim * height;
    }
    return open;
}

// Beckmann roughness of each lobe: the film's, or the substrate's (index MAX_LAYERS; from its map where there is one).
void lobe_roughness(out float m[MAX_LAYERS + 1]) {
    for (int k = 0; k < MAX_LAYERS; ++k) m[k] = u_roughness[k];
    m[MAX_LAYERS] = u_roughness[MAX_LAYERS];
#if ROUGHNESS_MAP
    m[MAX_LAYERS] = max(textureLod(u_roughness_map, g_uv, 0.0).r, 0.02);
#endif
}

// Kelemen / Szirmay-Kalos lobe f_spec (1/sr) of lobe `k` (a film's bottom-up index, or MAX_LAYERS: the substrate)
// of roughness m.
float kelemen(int k, float m, vec3 n, vec3 l, vec3 v) {
    vec3 h_sum = l + v;
    float h_length2 = dot(h_sum, h_sum);  // = 2 (1 + L.V)
    if (h_length2 < 1e-12) return 0.0;
    vec3 h = h_sum * inversesqrt(h_length2);
    float cos_a = dot(n, h);
    if (cos_a <= 0.0) return 0.0;
    float m2 = m * m;
    float cos2 = cos_a * cos_a;
    float tan2 = (1.0 - cos2) / cos2;
    float distribution = exp(-tan2 / m2) / (PI * m2 * cos2 * cos2);
    float c = 1.0 - clamp(dot(h, l), 0.0, 1.0);
    float fresnel = u_f0[k] + (1.0 - u_f0[k]) * c * c * c * c * c;
    return distribution * fresnel / h_length2;
}

// Texture coordinates of a world direction in the equirectangular environment (u wraps, v = 1 at the zenith).
vec2 equirect(vec3 d) {
    vec3 e = u_env_rotation * d;
    return vec2(0.5 + atan(e.x, -e.z) / (2.0 * PI), 1.0 - acos(clamp(e.y, -1.0, 1.0)) / PI);
}

// The prefiltered environment for roughness m at equirectangular coordinates `at`.
vec3 environment_specular(vec2 at, float m) {
    int last = u_env_level_count - 1;
    if (m >= u_env_level_m[last]) return textureLod(u_env_specular, vec3(at, float(last)), 0.0).rgb;
    int level = 0;
    while (level < last - 1 && u_env_level_m[level + 1] <= m) ++level;
    float w = clamp((m - u_env_level_m[level]) / (u_env_level_m[level + 1] - u_env_level_m[level]), 0.0, 1.0);
    return mix(textureLod(u_env_specular, vec3(at, float(level)), 0.0).rgb,
               textureLod(u_env_specular, vec3(at, float(level + 1)), 0.0).rgb, w);
}

// The lobe's directional albedo F0 a + b at mu = cos(view angle) for lobe k of roughness m.
float lobe_albedo(int k, float m, float mu) {
    vec2 size = vec2(textureSize(u_env_lobe, 0));
    float s = clamp((sqrt(m) - u_env_lobe_range.x) / (u_env_lobe_range.y - u_env_lobe_range.x), 0.0, 1.0);
    vec2 at = (vec2(mu, s) * (size - 1.0) + 0.5) / size;
    vec2 ab = textureLod(u_env_lobe, at, 0.0).rg;
    return u_f0[k] * ab.x + ab.y;
}

// The outputs of the sample in v_*: colour, skin light (alpha: the skin mask) and view depth.
void shade(out vec4 out_colour, out vec4 out_skin, out vec4 out_depth) {
    vec3 reflectance;
    vec3 over_black;
    vec3 attenuation[MAX_LAYERS + 1];
    float thickness[MAX_LAYERS];
    for (int layer = 0; layer < MAX_LAYERS; ++layer) {
        thickness[layer] = 0.0;
        if (PRECOMPOSED == 0 && layer < LAYER_COUNT) thickness[layer] = layer_thickness(layer);
    }
    stack_optics(thickness, reflectance, over_black, attenuation);
    if (PRECOMPOSED == 0) {  // (precomposed stacks come with their films' cover applied)
        for (int layer = 0; layer < LAYER_COUNT; ++layer) {
            attenuation[layer] *= clamp(thickness[layer] / u_lobe_cover_mm, 0.0, 1.0);
        }
    }
    float m[MAX_LAYERS + 1];
    lobe_roughness(m);
    vec3 geometric = normalize(g_normal);
    vec3 n = g_shading;
    vec3 v = ORTHOGRAPHIC == 1 ? u_view_vector : normalize(u_view_vector - g_position);
    bool split = SKIN_SPLIT == 1;
    vec3 surface = split ? over_black : reflectance;
    vec3 colour = vec3(0.0);
    vec3 skin = vec3(0.0);
    vec4 soft = vec4(-1.0);
#if SOFT_LIGHTS != 0
    soft = upsampled_visibility(ivec2(gl_FragCoord.xy), g_position, geometric, g_view_depth);
#endif
    for (int light = 0; light < LIGHT_COUNT; ++light) {
        vec3 l;
        vec3 e = u_light_radiance[light];
        if (BIT(POINT_LIGHTS, light) == 1) {
            vec3 to_light = u_light_vector[light] - g_position;
            float d = length(to_light);
            l = to_light / d;
            e *= (u_light_reference[light] * u_light_reference[light]) / (d * d);
        } else {
            l = u_light_vector[light];
        }
        float cos_theta = dot(n, l);
        if (cos_theta <= 0.0) continue;
        vec3 specular = vec3(0.0);
        for (int k = 0; k <= MAX_LAYERS; ++k) {
            if (BIT(LOBES, k) == 1 && (k < LAYER_COUNT || k == MAX_LAYERS)) {
                specular += attenuation[k] * kelemen(k, m[k], n, l, v);
            }
        }
        vec3 point = shadow_point(light, g_position, geometric, l);
        vec3 incident = e * light_visibility(light, point, soft[light]) * cos_theta;
        colour += incident * (surface + PI * specular);
        skin += incident * (reflectance - over_black);
    }
    if (ENVIRONMENT == 1) {
        float open_sky = u_env_intensity * g_occlusion * floor_occlusion();
        vec3 irradiance = textureLod(u_env_irradiance, equirect(n), 0.0).rgb * open_sky;
        colour += irradiance * surface;
        skin += irradiance * (reflectance - over_black);
        if (LOBES != 0) {
            vec2 mirror = equirect(reflect(-v, n));
            float mu = clamp(dot(n, v), 0.0, 1.0);
            for (int k = 0; k <= MAX_LAYERS; ++k) {
                if (BIT(LOBES, k) == 1 && (k < LAYER_COUNT || k == MAX_LAYERS)) {
                    colour += attenuation[k] * lobe_albedo(k, m[k], mu) * environment_specular(mirror, m[k]) * open_sky;
                }
            }
        }
    }
    out_colour = vec4(colour, 1.0);
    out_skin = split ? vec4(skin, 1.0) : vec4(0.0);  // alpha: the skin mask
    out_depth = vec4(g_view_depth, 0.0, 0.0, 1.0);
}

// Sample s of the surface attributes, target t (0 .. 3).
vec4 fetch_attribute(int t, ivec2 pixel, int s) {
#if SAMPLES > 1
    if (t == 0) return texelFetch(u_attributes0, pixel, s);
    if (t == 1) return texelFetch(u_attributes1, pixel, s);
    if (t == 2) return texelFetch(u_attributes2, pixel, s);
    return texelFetch(u_attributes3, pixel, s);
#else
    if (t == 0) return texelFetch(u_attributes0, pixel, 0);
    if (t == 1) return texelFetch(u_attributes1, pixel, 0);
    if (t == 2) return texelFetch(u_attributes2, pixel, 0);
    return texelFetch(u_attributes3, pixel, 0);
#endif
}

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    int pending = 0;  // the samples of this mesh not shaded yet, one bit each
    for (int s = 0; s < SAMPLES; ++s) {
        if (fetch_attribute(2, pixel, s).w == u_object) pending |= 1 << s;
    }
    vec4 colour = vec4(0.0);
    vec4 skin = vec4(0.0);
    vec4 depth = vec4(0.0);
    // (a loop whose trip count llvmpipe cannot know: a block of pixels that each hold one group runs it once)
    while (pending != 0) {
        int first = findLSB(pending);
        vec4 a0 = fetch_attribute(0, pixel, first);
        vec4 a1 = fetch_attribute(1, pixel, first);
        vec4 a2 = fetch_attribute(2, pixel, first);
        g_position = a0.xyz;
        g_view_depth = a0.w;
        g_normal = a1.xyz;
        g_occlusion = a1.w;
        g_shading = a2.xyz;
        g_uv = fetch_attribute(3, pixel, first).xy;
        int group = 1 << first;
#if SAMPLES > 1
        vec3 normal = normalize(a1.xyz);
        vec3 view = ORTHOGRAPHIC == 1 ? u_view_vector : normalize(u_view_vector - a0.xyz);
        float reach = SAME_PIXELS * (u_footprint.x + u_footprint.y * a0.w) / max(abs(dot(normal, view)), 0.25);
        for (int s = first + 1; s < SAMPLES; ++s) {
            if ((pending & (1 << s)) != 0 && abs(fetch_attribute(0, pixel, s).w - a0.w) <= reach
                && dot(normalize(fetch_attribute(1, pixel, s).xyz), normal) >= SAME_COS) group |= 1 << s;
        }
#endif
        pending &= ~group;
        vec4 c;
        vec4 k;
        vec4 d;
        shade(c, k, d);
        float count = float(bitCount(group));
        colour += count * c;
        skin += count * k;
        depth += count * d;
    }
    f_colour = colour / float(SAMPLES);
    f_skin = skin / float(SAMPLES);
    f_depth = depth / float(SAMPLES);
}
