#version 330
// Resample one tile of a cutting plane (see clipvol/render/slice_action.py for the technique).
// The pixel's world point is rebuilt from gl_FragCoord relative to the brick's first voxel centre
// (float64 on the CPU, so huge volumes stay precise), sampled trilinearly in the node's level
// ("high tile") and, where the node's blend ratio is > 0, in its parent's level ("low tile"); the
// ratio is the trilinear interpolation of the node's eight corner ratios (LaMar, Hamann & Joy).
// Output: r = the blended texel, g = 1 + the blended spread in texels (covered; a level without a
// spread reads 0 there: clipvol/bricking/spread.py), b = the node's level, a = the ratio.

uniform vec2 u_viewport;        // (w, h) pixels
uniform float u_pixel;          // pixel size (world)
uniform vec3 u_right;           // plane frame (unit)
uniform vec3 u_up;
// a 3D view instead of the slice's own pixel grid: the pixel's ray meets the plane
uniform bool u_in_view;
uniform bool u_ortho;
uniform vec3 u_normal;          // plane normal (unit)
uniform vec3 u_eye_rel;         // camera eye (perspective) or centre (orthographic) - plane origin
uniform vec3 u_cam_forward;
uniform vec3 u_cam_right;
uniform vec3 u_cam_up;
uniform vec2 u_cam_half;        // half extents at depth 1 (perspective) or in world units (orthographic)

uniform float u_level;
// high tile: the node's own brick
uniform vec3 u_o_minus_b;       // plane origin - centre of the brick's first voxel (world)
uniform vec3 u_inv_scale;       // 1 / voxel size of the level (x, y, z)
uniform vec3 u_slot_origin;     // first texel of the brick's slot (x, y, z)
uniform vec3 u_inv_tex_size;
uniform vec3 u_clamp_lo;        // brick-local voxel bounds (half a voxel beyond open faces)
uniform vec3 u_clamp_hi;
uniform sampler3D u_volume;
// low tile: the parent's brick over the same region
uniform bool u_blend;
uniform vec3 u_o_minus_b_low;
uniform vec3 u_inv_scale_low;
uniform vec3 u_slot_origin_low;
uniform vec3 u_inv_tex_size_low;
uniform vec3 u_clamp_lo_low;
uniform vec3 u_clamp_hi_low;
uniform sampler3D u_volume_low;
// corner ratios over the node box, relative to the plane origin
uniform vec3 u_node_lo;
uniform vec3 u_node_inv_ext;
uniform float u_ratio[8];       // index cx + 2 * cy + 4 * cz

out vec4 f_color;

// Trilinear sample at brick-local voxel coordinate u of the brick whose slot starts at texel slot.
// A point within 1e-4 voxel of a voxel centre reads that texel exactly (texelFetch, wrapped
// toroidally): the normalised coordinate (slot + u + 0.5) / size carries a float32 rounding error
// of ~1e-6 texel, which filtering would turn into a visible error on 16-bit data.
// (.r the value, .g the spread; 0 for a one-channel level)
vec2 sample_brick(sampler3D tex, vec3 slot, vec3 u, vec3 inv_size) {
    vec3 p = slot + u;
    vec3 c = floor(p + 0.5);
    if (all(lessThan(abs(p - c), vec3(1e-4)))) {
        vec3 size = floor(1.0 / inv_size + 0.5);
        return texelFetch(tex, ivec3(mod(c, size)), 0).rg;
    }
    return texture(tex, (p + 0.5) * inv_size).rg;
}

void main() {
    vec3 rel;                   // the pixel's point of the plane - plane origin
    if (u_in_view) {
        vec2 ndc = gl_FragCoord.xy / u_viewport * 2.0 - 1.0;
        vec3 off = (ndc.x * u_cam_half.x) * u_cam_right + (ndc.y * u_cam_half.y) * u_cam_up;
        vec3 o = u_ortho ? u_eye_rel + off : u_eye_rel;
        vec3 d = u_ortho ? u_cam_forward : normalize(u_cam_forward + off);
        float nd = dot(u_normal, d);
        if (nd == 0.0) discard;
        rel = o - (dot(u_normal, o) / nd) * d;
    } else {
        float col = gl_FragCoord.x - 0.5 * u_viewport.x;
        float row = gl_FragCoord.y - 0.5 * u_viewport.y;   // towards up (row 0 is the top)
        rel = (col * u_pixel) * u_right + (row * u_pixel) * u_up;
    }
    vec3 u = clamp((rel + u_o_minus_b) * u_inv_scale, u_clamp_lo, u_clamp_hi);
    vec2 hs = sample_brick(u_volume, u_slot_origin, u, u_inv_tex_size);
    float high = hs.x;
    float r = 0.0;
    float value = high;
    float spread = hs.y;
    if (u_blend) {
        vec3 s = clamp((rel - u_node_lo) * u_node_inv_ext, 0.0, 1.0);
        float c00 = mix(u_ratio[0], u_ratio[1], s.x);
        float c10 = mix(u_ratio[2], u_ratio[3], s.x);
        float c01 = mix(u_ratio[4], u_ratio[5], s.x);
        float c11 = mix(u_ratio[6], u_ratio[7], s.x);
        r = mix(mix(c00, c10, s.y), mix(c01, c11, s.y), s.z);
        if (r > 0.0) {
            vec3 ul = clamp((rel + u_o_minus_b_low) * u_inv_scale_low, u_clamp_lo_low, u_clamp_hi_low);
            vec2 ls = sample_brick(u_volume_low, u_slot_origin_low, ul, u_inv_tex_size_low);
            float low = ls.x;
            value = r >= 1.0 ? low : mix(high, low, r);
            spread = r >= 1.0 ? ls.y : mix(hs.y, ls.y, r);   // blended like the value
        }
    }
    f_color = vec4(value, 1.0 + spread, u_level, r);
}
