#version 330
// Single-pass, ray-guided ray casting through the selection's cut (see clipvol/render/action.py).
// One proxy box (the volume's) is drawn; each pixel's ray marches front to back over the cut using
// a per-level page table (clipvol/scene/page_table.py): from the coarsest level down, an entry says
// EMPTY (skip the node's box in one step), REFINED (look at the next finer level) or DRAWN (sample
// this node's box from the toroidal texture of data level Ld: the node's own brick or a resident
// ancestor). Within a node's box the samples lie on the constant-distance lattice
// t = off + k * delta_Ld of the data level, exactly as the per-brick path samples that box, so the
// two paths draw the same image; the ray stops early per pixel with no framebuffer copies.
// Variants: MODE_MIP, HAS_NAN, SHADING (volume_common.glsl); NUM_LEVELS: levels of the pyramid (<= 16).
#include "volume_common.glsl"

#define PT_EMPTY 0u
#define PT_REFINED 1u
#define PT_DRAWN 2u

uniform vec3 u_vol_lo;              // volume box relative to O
uniform vec3 u_vol_hi;
uniform usampler2D u_page_table;    // all levels' entries, flattened, PT_WIDTH per row
uniform int u_pt_width;
uniform int u_pt_base[NUM_LEVELS];  // first entry of each level's box of cells
uniform ivec3 u_pt_size[NUM_LEVELS];// cells of the box (x, y, z); 0: nothing at this level
uniform vec3 u_pt_origin[NUM_LEVELS]; // world corner of the box's first cell, relative to O
uniform vec3 u_pt_ext[NUM_LEVELS];  // world extent of one cell (node) of the level
uniform ivec3 u_pt_c0[NUM_LEVELS];  // grid index of the box's first cell (x, y, z)
uniform vec3 u_lv_vox0[NUM_LEVELS]; // centre of the first voxel of brick u_pt_c0, relative to O
uniform vec3 u_lv_inv_scale[NUM_LEVELS];
uniform ivec3 u_lv_win[NUM_LEVELS]; // toroidal window of the level texture, in bricks (x, y, z)
uniform vec3 u_lv_inv_tex_size[NUM_LEVELS];
uniform float u_lv_delta[NUM_LEVELS];
uniform vec3 u_brick;               // brick shape (x, y, z) in voxels
uniform int u_top;                  // coarsest level
uniform float u_nudge;              // world length past a node face where the next node is looked up
uniform int u_max_regions;
uniform int u_max_steps;
#if NUM_LEVELS > 0
uniform sampler3D u_level0;
#endif
#if NUM_LEVELS > 1
uniform sampler3D u_level1;
#endif
#if NUM_LEVELS > 2
uniform sampler3D u_level2;
#endif
#if NUM_LEVELS > 3
uniform sampler3D u_level3;
#endif
#if NUM_LEVELS > 4
uniform sampler3D u_level4;
#endif
#if NUM_LEVELS > 5
uniform sampler3D u_level5;
#endif
#if NUM_LEVELS > 6
uniform sampler3D u_level6;
#endif
#if NUM_LEVELS > 7
uniform sampler3D u_level7;
#endif
#if NUM_LEVELS > 8
uniform sampler3D u_level8;
#endif
#if NUM_LEVELS > 9
uniform sampler3D u_level9;
#endif
#if NUM_LEVELS > 10
uniform sampler3D u_level10;
#endif
#if NUM_LEVELS > 11
uniform sampler3D u_level11;
#endif
#if NUM_LEVELS > 12
uniform sampler3D u_level12;
#endif
#if NUM_LEVELS > 13
uniform sampler3D u_level13;
#endif
#if NUM_LEVELS > 14
uniform sampler3D u_level14;
#endif
#if NUM_LEVELS > 15
uniform sampler3D u_level15;
#endif

out vec4 f_color;

uint pt_fetch(int L, ivec3 cell) {
    ivec3 s = u_pt_size[L];
    if (any(lessThan(cell, ivec3(0))) || any(greaterThanEqual(cell, s))) return PT_EMPTY;
    int i = u_pt_base[L] + (cell.z * s.y + cell.y) * s.x + cell.x;
    return texelFetch(u_page_table, ivec2(i % u_pt_width, i / u_pt_width), 0).r;
}

// Sample [ta, tb) of the ray from level L's texture (data brick origin vox0, slot texel base,
// brick-local clamp [clo, chi]); false: the ray is opaque.
bool march(sampler3D tex, int L, vec3 origin, vec3 dir, float ta, float tb, vec3 vox0, vec3 slot,
           vec3 clo, vec3 chi, STATE) {
    float delta = u_lv_delta[L];
    float off = pixel_hash() * u_jitter * delta;
    vec2 k = lattice_range(ta, tb, off, delta);
    int n = int(min(k.y - k.x + 1.0, float(u_max_steps)));
    vec3 base = origin - vox0;
    vec3 isc = u_lv_inv_scale[L];
    vec3 its = u_lv_inv_tex_size[L];
    float row = (float(L) + 0.5) / float(NUM_LEVELS);
    march_segment(tex, base, dir, off, k.x, n, delta, isc, its, slot, clo, chi, row, STATE_ARGS);
#ifdef MODE_MIP
    return true;
#else
    return acc.a < u_opaque;
#endif
}

void main() {
    vec3 origin;
    vec3 dir;
    pixel_ray(origin, dir);
    vec3 inv = safe_inverse(dir);
    vec2 t = box_interval(origin, inv, u_vol_lo, u_vol_hi);
    if (!clip_to_shape(origin, dir, inv, t)) discard;
#ifdef MODE_MIP
    float vmax = -3.0e38;
    bool hit = false;
#else
    vec4 acc = vec4(0.0);
#endif
    float ta = t.x;
    for (int r = 0; r < u_max_regions && ta < t.y; ++r) {
        // look the node up just past ta (never past the middle of what is left of the ray)
        vec3 q = origin + min(ta + u_nudge + abs(ta) * 1e-6, 0.5 * (ta + t.y)) * dir;
        int L = u_top;
        ivec3 cell = ivec3(floor((q - u_pt_origin[L]) / u_pt_ext[L]));
        uint e = pt_fetch(L, cell);
        while ((e & 3u) == PT_REFINED && L > 0) {
            L -= 1;
            vec3 cq = floor((q - u_pt_origin[L]) / u_pt_ext[L]);
            cell = ivec3(cq);
            e = pt_fetch(L, cell);
        }
        // the node's box at level L, and where the ray leaves it
        vec3 lo = u_pt_origin[L] + vec3(cell) * u_pt_ext[L];
        vec3 hi = lo + u_pt_ext[L];
        vec3 far = (mix(lo, hi, greaterThan(inv, vec3(0.0))) - origin) * inv;  // inv: a zero component counts as +0
        float tb = min(min(min(far.x, far.y), far.z), t.y);
        if (tb <= ta) {                 // no progress (rounding at a face): step past it
            ta += u_nudge + abs(ta) * 1e-6;
            continue;
        }
        if ((e & 3u) == PT_DRAWN) {
            int Ld = int((e >> 2) & 31u);
            ivec3 gcell = cell + u_pt_c0[L];
            ivec3 idx = gcell >> (Ld - L);  // the data brick (the node's own, or a resident ancestor)
            ivec3 rel = idx - u_pt_c0[Ld];
            vec3 vox0 = u_lv_vox0[Ld] + vec3(rel) * u_brick / u_lv_inv_scale[Ld];
            vec3 slot = vec3(idx % u_lv_win[Ld]) * u_brick;
            uint faces = e >> 8;
            vec3 clo = mix(vec3(0.0), vec3(-0.5), bvec3((faces & 1u) != 0u, (faces & 4u) != 0u, (faces & 16u) != 0u));
            vec3 chi = u_brick - mix(vec3(1.0), vec3(0.5), bvec3((faces & 2u) != 0u, (faces & 8u) != 0u, (faces & 32u) != 0u));
            bool go = true;
            if (false) {}
#if NUM_LEVELS > 0
            else if (Ld == 0) go = march(u_level0, 0, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 1
            else if (Ld == 1) go = march(u_level1, 1, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 2
            else if (Ld == 2) go = march(u_level2, 2, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 3
            else if (Ld == 3) go = march(u_level3, 3, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 4
            else if (Ld == 4) go = march(u_level4, 4, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 5
            else if (Ld == 5) go = march(u_level5, 5, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 6
            else if (Ld == 6) go = march(u_level6, 6, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 7
            else if (Ld == 7) go = march(u_level7, 7, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 8
            else if (Ld == 8) go = march(u_level8, 8, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 9
            else if (Ld == 9) go = march(u_level9, 9, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 10
            else if (Ld == 10) go = march(u_level10, 10, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 11
            else if (Ld == 11) go = march(u_level11, 11, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 12
            else if (Ld == 12) go = march(u_level12, 12, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 13
            else if (Ld == 13) go = march(u_level13, 13, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 14
            else if (Ld == 14) go = march(u_level14, 14, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 15
            else if (Ld == 15) go = march(u_level15, 15, origin, dir, ta, tb, vox0, slot, clo, chi, STATE_ARGS);
#endif
            if (!go) break;
        }
        ta = tb;
    }
#ifdef MODE_MIP
    if (!hit) discard;
    f_color = vec4(vmax, 0.0, 0.0, 1.0);
#else
    f_color = acc;
#endif
}
