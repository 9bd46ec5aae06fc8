#version 330 core
// Where a mesh shows (renderer.layers): drawn over the whole frame with the stencil set to take the mesh's bit,
// it lets through the pixels with at least one sample whose surface attributes (surface_attributes.frag, target 2)
// name the mesh, and discards the others, so that the mesh's shading pass (km_layers.frag) runs only there.
// SAMPLES: samples a pixel of the attributes (1, 2 or 4), defined by renderer.layers.

#if SAMPLES > 1
uniform sampler2DMS u_attributes2;
#else
uniform sampler2D u_attributes2;
#endif
uniform float u_object;  // the mesh's index

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    bool shown = false;
#if SAMPLES > 1
    for (int s = 0; s < SAMPLES; ++s) shown = shown || texelFetch(u_attributes2, pixel, s).w == u_object;
#else
    shown = texelFetch(u_attributes2, pixel, 0).w == u_object;
#endif
    if (!shown) discard;
}
