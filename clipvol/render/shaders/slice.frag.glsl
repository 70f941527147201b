#version 330
// Resample one tile of a cutting plane (see clipvol/render/slice_action.py for the technique).
// The pixel's world point is rebuilt from gl_FragCoord relative to the brick's first voxel centre
// (float64 on the CPU, so huge volumes stay precise), sampled trilinearly in the node's level
// ("high tile") and, where the node's blend ratio is > 0, in its parent's level ("low tile"); the
// ratio is the trilinear interpolation of the node's eight corner ratios (LaMar, Hamann & Joy).
// Output: r = the blended texel, g = 1 (covered), b = the node's level, a = the ratio.

uniform vec2 u_viewport;        // (w, h) pixels
uniform float u_pixel;          // pixel size (world)
uniform vec3 u_right;           // plane frame (unit)
uniform vec3 u_up;

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

void main() {
    float col = gl_FragCoord.x - 0.5 * u_viewport.x;
    float row = gl_FragCoord.y - 0.5 * u_viewport.y;   // towards up (row 0 is the top)
    vec3 rel = (col * u_pixel) * u_right + (row * u_pixel) * u_up;   // point - plane origin
    vec3 u = clamp((rel + u_o_minus_b) * u_inv_scale, u_clamp_lo, u_clamp_hi);
    float high = texture(u_volume, (u_slot_origin + u + 0.5) * u_inv_tex_size).r;
    float r = 0.0;
    float value = high;
    if (u_blend) {
        vec3 s = clamp((rel - u_node_lo) * u_node_inv_ext, 0.0, 1.0);
        float c00 = mix(u_ratio[0], u_ratio[1], s.x);
        float c10 = mix(u_ratio[2], u_ratio[3], s.x);
        float c01 = mix(u_ratio[4], u_ratio[5], s.x);
        float c11 = mix(u_ratio[6], u_ratio[7], s.x);
        r = mix(mix(c00, c10, s.y), mix(c01, c11, s.y), s.z);
        if (r > 0.0) {
            vec3 ul = clamp((rel + u_o_minus_b_low) * u_inv_scale_low, u_clamp_lo_low, u_clamp_hi_low);
            float low = texture(u_volume_low, (u_slot_origin_low + ul + 0.5) * u_inv_tex_size_low).r;
            value = r >= 1.0 ? low : mix(high, low, r);
        }
    }
    f_color = vec4(value, 1.0, u_level, r);
}
