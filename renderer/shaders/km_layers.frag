#version 330 core
// Kubelka-Munk layer compositing under one directional light (linear, per channel).
//
// Up to 4 layers, listed bottom-up (layer 0 lies on the substrate). For each layer the fragment looks up the
// reflectance R0 and transmittance T of the film at its thickness X (mm) in an optical table, interpolating
// linearly between thickness samples and clamping at the ends, then composes it onto the reflectance Rg of
// everything beneath it (thesis eq. 3.13):  Rg <- R0 + T^2 Rg / (1 - R0 Rg).
// Channels are rgb (3) or spectral bands (up to MAX_CHANNELS), processed four at a time as vec4 groups; the
// composite is converted to linear RGB with u_to_rgb and multiplied by E * max(cos theta, 0).
//
// Table texture layout (RGBA32F, read with texelFetch, one texel column per thickness sample):
//   rows 0 .. G-1      R0 of channel group g (channels 4g .. 4g+3)
//   rows G .. 2G-1     T of channel group g
//   row  2G            thickness of the sample in mm (red)
// Padding channels hold R0 = T = 0 and a zero row of u_to_rgb, so they contribute nothing.

#define MAX_LAYERS 4
#define MAX_GROUPS 8
#define MAX_CHANNELS 32

in vec3 v_normal;
in vec2 v_uv;

uniform int u_layer_count;                   // number of layers, 0 .. MAX_LAYERS
uniform int u_group_count;                   // G = ceil(channels / 4), 1 .. MAX_GROUPS
uniform int u_sample_count[MAX_LAYERS];      // thickness samples per layer table (>= 1)
uniform int u_use_map[MAX_LAYERS];           // 1: thickness from the layer's map texture; 0: u_thickness
uniform float u_thickness[MAX_LAYERS];       // uniform layer thickness, mm
uniform sampler2D u_table0;                  // optical tables of layers 0 .. 3 (layout above)
uniform sampler2D u_table1;
uniform sampler2D u_table2;
uniform sampler2D u_table3;
uniform sampler2D u_map0;                    // thickness maps over uv, mm in the red channel
uniform sampler2D u_map1;
uniform sampler2D u_map2;
uniform sampler2D u_map3;
uniform vec4 u_substrate[MAX_GROUPS];        // substrate albedo per channel, in [0, 1]
uniform vec3 u_to_rgb[MAX_CHANNELS];         // row c: linear RGB contributed by unit reflectance in channel c
uniform vec3 u_light_radiance;               // E: value rendered for a white Lambert surface facing the light
uniform vec3 u_to_light;                     // unit world-space vector from the surface towards the light

layout(location = 0) out vec4 f_colour;

float layer_thickness(int layer) {
    if (u_use_map[layer] == 0) return u_thickness[layer];
    if (layer == 0) return texture(u_map0, v_uv).r;
    if (layer == 1) return texture(u_map1, v_uv).r;
    if (layer == 2) return texture(u_map2, v_uv).r;
    return texture(u_map3, v_uv).r;
}

// Composes one layer, whose table is `table` with `n` samples, onto the reflectance groups `ground`.
void compose(sampler2D table, int n, float x, inout vec4 ground[MAX_GROUPS]) {
    int rows = 2 * u_group_count;
    // Segment [j0, j1] holding x and the weight w of sample j1; clamped at both ends.
    int j0 = 0;
    int j1 = 0;
    float w = 0.0;
    if (n > 1) {
        float first = texelFetch(table, ivec2(0, rows), 0).r;
        float last = texelFetch(table, ivec2(n - 1, rows), 0).r;
        if (x >= last) {
            j0 = n - 1;
            j1 = n - 1;
        } else if (x > first) {
            j0 = 0;
            for (int j = 1; j < n - 1; ++j) {
                if (texelFetch(table, ivec2(j, rows), 0).r <= x) j0 = j;
            }
            j1 = j0 + 1;
            float x0 = texelFetch(table, ivec2(j0, rows), 0).r;
            float x1 = texelFetch(table, ivec2(j1, rows), 0).r;
            w = (x - x0) / (x1 - x0);
        }
    }
    for (int g = 0; g < u_group_count; ++g) {
        vec4 r0 = mix(texelFetch(table, ivec2(j0, g), 0), texelFetch(table, ivec2(j1, g), 0), w);
        int gt = g + u_group_count;
        vec4 t = mix(texelFetch(table, ivec2(j0, gt), 0), texelFetch(table, ivec2(j1, gt), 0), w);
        vec4 rg = ground[g];
        vec4 denominator = vec4(1.0) - r0 * rg;
        // Padding channels (r0 = t = rg = 0) and a lossless white over a white ground (denominator 0) stay finite.
        vec4 safe = max(denominator, vec4(1e-30));
        ground[g] = r0 + t * t * rg / safe;
    }
}

void main() {
    vec4 reflectance[MAX_GROUPS];
    for (int g = 0; g < MAX_GROUPS; ++g) reflectance[g] = u_substrate[g];
    for (int layer = 0; layer < u_layer_count; ++layer) {
        float x = layer_thickness(layer);
        int n = u_sample_count[layer];
        if (layer == 0) compose(u_table0, n, x, reflectance);
        else if (layer == 1) compose(u_table1, n, x, reflectance);
        else if (layer == 2) compose(u_table2, n, x, reflectance);
        else compose(u_table3, n, x, reflectance);
    }
    vec3 rgb = vec3(0.0);
    for (int g = 0; g < u_group_count; ++g) {
        for (int k = 0; k < 4; ++k) rgb += reflectance[g][k] * u_to_rgb[4 * g + k];
    }
    float cos_theta = max(dot(normalize(v_normal), u_to_light), 0.0);
    f_colour = vec4(rgb * u_light_radiance * cos_theta, 1.0);
}
