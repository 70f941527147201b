#version 330
// The mask of a refined frame (clipvol/render/refine.py), drawn before its fine pass: where the four
// coarse rays around a pixel agree to within u_refine_tol in every premultiplied channel, the pixel
// becomes their bilinear blend and its depth 0, so the fine pass's fragments there (depth 0.5, test
// "<=") are rejected before they are shaded; elsewhere nothing is written and the fine pass casts the
// pixel's ray. Coarse ray (i, j) went through the corner shared by pixels 2i, 2i + 1 (and 2j, 2j + 1),
// so pixel centre x + 0.5 lies at coarse texel coordinate (x + 0.5) / 2 - 0.5.
// u_block > 1 (RenderParams.refine_block): the decision is the block's, u_block x u_block pixels from
// the pass's origin: a block where any pixel's four coarse rays differ casts every pixel's ray (the
// rasteriser shades a block of lanes until its longest ray ends anyway), else every pixel is a blend.
uniform sampler2D u_coarse;     // the coarse pass: premultiplied RGBA, ceil(w / 2) x ceil(h / 2)
uniform float u_refine_tol;     // the largest spread of a channel over the four coarse rays that is "smooth"
uniform vec2 u_origin;          // this pass's viewport origin in its target
uniform ivec2 u_coarse_lo;      // the coarse pass's first and last texel in its target
uniform ivec2 u_coarse_hi;
uniform int u_block;            // 1: a pixel's own decision; 2, 4 or 8: its block's
out vec4 f_color;

const int MAX_SPAN = 6;         // texels a block of 8 pixels spans along an axis (8 / 2 + 2)

float spread4(vec4 a, vec4 b, vec4 d, vec4 e) {
    vec4 s = max(max(a, b), max(d, e)) - min(min(a, b), min(d, e));
    return max(max(s.r, s.g), max(s.b, s.a));
}

vec4 tap(ivec2 i) {
    return texelFetch(u_coarse, clamp(i + u_coarse_lo, u_coarse_lo, u_coarse_hi), 0);
}

void main() {
    vec2 p = gl_FragCoord.xy - u_origin;
    vec2 c = p * 0.5 - 0.5;
    vec2 c0 = floor(c);
    vec2 f = c - c0;
    ivec2 i0 = ivec2(c0);
    vec4 a = tap(i0);
    vec4 b = tap(i0 + ivec2(1, 0));
    vec4 d = tap(i0 + ivec2(0, 1));
    vec4 e = tap(i0 + ivec2(1, 1));
    if (u_block <= 1) {
        if (spread4(a, b, d, e) > u_refine_tol) discard;
    } else {
        // pixels x0 .. x0 + B - 1 of the block (x0 even) use the 2 x 2 windows of coarse texels starting
        // at x0 / 2 - 1 .. x0 / 2 + B / 2 - 1: B / 2 + 2 texels a side; any window over the tolerance
        // makes the block live
        ivec2 first = (ivec2(floor(p)) / u_block) * u_block / 2 - 1;
        int n = u_block / 2 + 2;
        vec4 lo[MAX_SPAN], hi[MAX_SPAN];  // per column pair of the previous row: min and max
        for (int y = 0; y < MAX_SPAN; ++y) {
            if (y >= n) break;
            vec4 left = tap(first + ivec2(0, y));
            for (int x = 1; x < MAX_SPAN; ++x) {
                if (x >= n) break;
                vec4 right = tap(first + ivec2(x, y));
                vec4 mn = min(left, right), mx = max(left, right);
                if (y > 0) {
                    vec4 s = max(mx, hi[x]) - min(mn, lo[x]);
                    if (max(max(s.r, s.g), max(s.b, s.a)) > u_refine_tol) discard;
                }
                lo[x] = mn;
                hi[x] = mx;
                left = right;
            }
        }
    }
    f_color = mix(mix(a, b, f.x), mix(d, e, f.x), f.y);
    gl_FragDepth = 0.0;
}
