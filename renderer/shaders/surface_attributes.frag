#version 330 core
// The surface attributes of the layer pass (renderer.layers): what a sample shows, for the shading pass
// (km_layers.frag) to shade. Drawn with km_layers.vert, one mesh at a time, into four RGBA32F targets (multisampled
// or not): the interpolated attributes at the pixel's centre of the triangle nearest at the sample, exactly as a
// forward pass would shade them:
//   target 0: world position (mm), view depth (mm, along the camera's axis)
//   target 1: interpolated normal (not normalised), baked ambient occlusion
//   target 2: shading normal (unit), the mesh's index (0: the product, 1 ..: the props; -1 where nothing is drawn)
//   target 3: texture coordinates, 0, 0
//
// The shading normal is the only attribute that needs screen-space derivatives, so it is made here: the normal map's
// detail d over the normalised interpolated normal n in the surface's tangent frame (T along +u, B along +v, from the
// screen-space derivatives of position and uv: Schueler's cotangent frame), the detail's tilt scaled by
// k = exp(-t / u_fill_mm), t the films' total thickness here (a film fills fine lines):
//   n' = normalize(T d.x k + B d.y k + n d.z).

in vec3 v_position;
in vec3 v_normal;
in vec2 v_uv;
in float v_occlusion;
in float v_view_depth;

// NORMAL_MAP (0 or 1, defined by renderer.layers): fine detail from a tangent-space normal map over uv.

uniform float u_object;                      // the mesh's index (0: the product)
uniform sampler2D u_normal_map;              // unit vectors: x along +u, y along +v, z out of the surface
uniform sampler2D u_film_total;              // total film thickness over uv (mm, red), which smooths the detail
uniform float u_fill_mm;                     // film thickness that smooths the detail by 1/e

layout(location = 0) out vec4 f_position;
layout(location = 1) out vec4 f_normal;
layout(location = 2) out vec4 f_shading;
layout(location = 3) out vec4 f_uv;

vec3 shading_normal(vec3 n, vec2 uv) {
    vec3 shaded = n;
#if NORMAL_MAP
    {
        vec3 dp1 = dFdx(v_position);
        vec3 dp2 = dFdy(v_position);
        vec2 duv1 = dFdx(v_uv);
        vec2 duv2 = dFdy(v_uv);
        vec3 dp2perp = cross(dp2, n);
        vec3 dp1perp = cross(n, dp1);
        vec3 t = dp2perp * duv1.x + dp1perp * duv2.x;
        vec3 b = dp2perp * duv1.y + dp1perp * duv2.y;
        float longest = max(dot(t, t), dot(b, b));
        if (longest > 1e-30) {  // else uv does not change here: no frame
            float scale = inversesqrt(longest);
            vec3 d = texture(u_normal_map, uv).xyz;
            float k = exp(-max(texture(u_film_total, uv).r, 0.0) / u_fill_mm);
            vec3 tilted = (t * scale) * (d.x * k) + (b * scale) * (d.y * k) + n * d.z;
            float length2 = dot(tilted, tilted);
            if (length2 > 1e-12) shaded = tilted * inversesqrt(length2);
        }
    }
#endif
    return shaded;
}

void main() {
    f_position = vec4(v_position, v_view_depth);
    f_normal = vec4(v_normal, v_occlusion);
    f_shading = vec4(shading_normal(normalize(v_normal), v_uv), u_object);
    f_uv = vec4(v_uv, 0.0, 0.0);
}
