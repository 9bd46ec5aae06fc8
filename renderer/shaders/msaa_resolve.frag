#version 330 core
// Resolve of a multisampled frame (renderer.multisample): each output is the mean of its pixel's samples in the
// matching multisampled attachment, summed as a balanced tree in a fixed order, ((s0 + s1) + (s2 + s3)) / 4 for 4
// samples, so that a pixel whose samples are equal resolves to exactly that value (a + a = 2a and 2a + 2a = 4a are
// exact in float, and so is the division by a power of two) and a silhouette's pixel to the share of each side.

uniform sampler2DMS u_source0;
uniform sampler2DMS u_source1;
uniform sampler2DMS u_source2;
uniform int u_samples;  // 2 or 4
uniform int u_targets;  // attachments to resolve, 1 .. 3

layout(location = 0) out vec4 f_target0;
layout(location = 1) out vec4 f_target1;
layout(location = 2) out vec4 f_target2;

vec4 mean(sampler2DMS source, ivec2 at) {
    vec4 pair = texelFetch(source, at, 0) + texelFetch(source, at, 1);
    if (u_samples == 2) return pair * 0.5;
    return (pair + (texelFetch(source, at, 2) + texelFetch(source, at, 3))) * 0.25;
}

void main() {
    ivec2 at = ivec2(gl_FragCoord.xy);
    f_target0 = mean(u_source0, at);
    f_target1 = u_targets > 1 ? mean(u_source1, at) : vec4(0.0);
    f_target2 = u_targets > 2 ? mean(u_source2, at) : vec4(0.0);
}
