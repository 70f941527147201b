#version 330
// The mask of a refined frame (clipvol/render/refine.py), drawn before its fine pass: where the four
// coarse rays around a pixel agree to within u_refine_tol in every premultiplied channel, the pixel
// becomes their bilinear blend and its depth 0, so the fine pass's fragments there (depth 0.5, test
// "<=") are rejected before they are shaded; elsewhere nothing is written and the fine pass casts the
// pixel's ray. Coarse ray (i, j) went through the corner shared by pixels 2i, 2i + 1 (and 2j, 2j + 1),
// so pixel centre x + 0.5 lies at coarse texel coordinate (x + 0.5) / 2 - 0.5.
uniform sampler2D u_coarse;     // the coarse pass: premultiplied RGBA, ceil(w / 2) x ceil(h / 2)
uniform float u_refine_tol;     // the largest spread of a channel over the four coarse rays that is "smooth"
uniform vec2 u_origin;          // this pass's viewport origin in its target
uniform ivec2 u_coarse_lo;      // the coarse pass's first and last texel in its target
uniform ivec2 u_coarse_hi;
out vec4 f_color;

void main() {
    vec2 c = (gl_FragCoord.xy - u_origin) * 0.5 - 0.5;
    vec2 c0 = floor(c);
    vec2 f = c - c0;
    ivec2 i0 = ivec2(c0) + u_coarse_lo;
    ivec2 top = u_coarse_hi;
    vec4 a = texelFetch(u_coarse, clamp(i0, u_coarse_lo, top), 0);
    vec4 b = texelFetch(u_coarse, clamp(i0 + ivec2(1, 0), u_coarse_lo, top), 0);
    vec4 d = texelFetch(u_coarse, clamp(i0 + ivec2(0, 1), u_coarse_lo, top), 0);
    vec4 e = texelFetch(u_coarse, clamp(i0 + ivec2(1, 1), u_coarse_lo, top), 0);
    vec4 spread = max(max(a, b), max(d, e)) - min(min(a, b), min(d, e));
    if (max(max(spread.r, spread.g), max(spread.b, spread.a)) > u_refine_tol) discard;
    f_color = mix(mix(a, b, f.x), mix(d, e, f.x), f.y);
    gl_FragDepth = 0.0;
}
