#version 330 core
// Shadow-map depth pass: no colour output. The rasteriser writes the window depth, 0 at the light's near plane and
// 1 at its far plane, plus the polygon offset set by renderer.shadows.ShadowMap.render.

void main() {
}
