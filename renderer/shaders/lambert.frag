#version 330 core
// Lambert shading under one directional light: colour = albedo * E * max(cos theta, 0), linear RGB.

in vec3 v_normal;

uniform vec3 u_albedo;           // diffuse albedo, linear RGB in [0, 1]
uniform vec3 u_light_radiance;   // E: value rendered for albedo 1 facing the light, linear RGB
uniform vec3 u_to_light;         // unit world-space vector from the surface towards the light

layout(location = 0) out vec4 f_colour;

void main() {
    float cos_theta = max(dot(normalize(v_normal), u_to_light), 0.0);
    f_colour = vec4(u_albedo * u_light_radiance * cos_theta, 1.0);
}
