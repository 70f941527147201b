#version 330
// The scatter of a compacted pass (clipvol/render/refine.py, Compaction): vertex i is entry i of the
// compact list, drawn as one point at its pixel in the pass's target and carrying the colour its
// ray left in the compact target. Entry i lies at texel (4 (b mod W/4) + j mod 4, 4 (b div W/4) +
// j div 4) of the compact target, b = i div 16, j = i mod 16 (blocks of 4 x 4 entries, row by row).
uniform sampler2D u_pixels;     // per compact texel: its pixel's centre in the target
uniform sampler2D u_compact;    // the compact pass's colours
uniform int u_width;            // the compact target's width (a multiple of 4)
uniform vec2 u_target;          // the target's size in pixels (the viewport)
flat out vec4 v_color;

void main() {
    int b = gl_VertexID / 16;
    int j = gl_VertexID - 16 * b;
    int per_row = u_width / 4;
    ivec2 c = ivec2(4 * (b % per_row) + (j & 3), 4 * (b / per_row) + (j >> 2));
    vec2 p = texelFetch(u_pixels, c, 0).xy;
    v_color = texelFetch(u_compact, c, 0);
    gl_Position = vec4(p / u_target * 2.0 - 1.0, 0.0, 1.0);
    gl_PointSize = 1.0;
}
