#version 330
// Single-pass, ray-guided ray casting through the selection's cut (see clipvol/render/action.py).
// One viewport triangle under the scissor rectangle of the volume's box is drawn; each pixel's ray marches front to back over the cut using
// a per-level page table (clipvol/scene/page_table.py): from the coarsest level down, an entry says
// EMPTY (skip the node's box in one step), REFINED (look at the next finer level) or DRAWN (sample
// this node's box from the toroidal texture of data level Ld: the node's own brick or a resident
// ancestor). Within a node's box the samples lie on the constant-distance lattice
// t = off + k * delta_Ld of the data level, exactly as the per-brick path samples that box, so the
// two paths draw the same image; the ray stops early per pixel with no framebuffer copies.
// Variants: MODE_MIP, MODE_MINIP, MODE_AVERAGE, MODE_ISO, MODE_GLSL, HAS_NAN, SHADING, EMPTY_SKIP (volume_common.glsl); NUM_LEVELS: levels of the pyramid (<= 16);
// PT_WIDTH_LOG2: log2 of the page table's entries per row;
// LEVEL_LO..LEVEL_HI: the data levels the table draws from. Only those get a march in the level
// chain below: a SIMD rasteriser (llvmpipe) runs every branch of a per-pixel `if` with its lanes
// masked, so each level in the chain costs every pixel its set-up and one masked sample per node.
#ifndef LEVEL_LO
#define LEVEL_LO 0
#endif
#ifndef PT_WIDTH_LOG2
#define PT_WIDTH_LOG2 10
#endif
#ifndef LEVEL_HI
#define LEVEL_HI 15
#endif
#if LEVEL_LO == 0
#define LEVEL_TEX u_level0
#endif
#if LEVEL_LO == 1
#define LEVEL_TEX u_level1
#endif
#if LEVEL_LO == 2
#define LEVEL_TEX u_level2
#endif
#if LEVEL_LO == 3
#define LEVEL_TEX u_level3
#endif
#if LEVEL_LO == 4
#define LEVEL_TEX u_level4
#endif
#if LEVEL_LO == 5
#define LEVEL_TEX u_level5
#endif
#if LEVEL_LO == 6
#define LEVEL_TEX u_level6
#endif
#if LEVEL_LO == 7
#define LEVEL_TEX u_level7
#endif
#if LEVEL_LO == 8
#define LEVEL_TEX u_level8
#endif
#if LEVEL_LO == 9
#define LEVEL_TEX u_level9
#endif
#if LEVEL_LO == 10
#define LEVEL_TEX u_level10
#endif
#if LEVEL_LO == 11
#define LEVEL_TEX u_level11
#endif
#if LEVEL_LO == 12
#define LEVEL_TEX u_level12
#endif
#if LEVEL_LO == 13
#define LEVEL_TEX u_level13
#endif
#if LEVEL_LO == 14
#define LEVEL_TEX u_level14
#endif
#if LEVEL_LO == 15
#define LEVEL_TEX u_level15
#endif
#include "volume_common.glsl"

#define PT_EMPTY 0u
#define PT_REFINED 1u
#define PT_DRAWN 2u

uniform vec3 u_vol_lo;              // volume box relative to O
uniform vec3 u_vol_hi;
uniform usampler2D u_page_table;    // all levels' entries, flattened, 1 << PT_WIDTH_LOG2 per row
uniform int u_pt_base[NUM_LEVELS];  // first entry of each level's box of cells
uniform ivec3 u_pt_size[NUM_LEVELS];// cells of the box (x, y, z); 0: nothing at this level
uniform vec3 u_pt_origin[NUM_LEVELS]; // world corner of the box's first cell, relative to O
uniform vec3 u_pt_ext[NUM_LEVELS];  // world extent of one cell (node) of the level
uniform ivec3 u_pt_c0[NUM_LEVELS];  // grid index of the box's first cell (x, y, z)
uniform ivec3 u_lv_d0[NUM_LEVELS];  // a brick of the level near its data (x, y, z)
uniform vec3 u_lv_vox0[NUM_LEVELS]; // centre of the first voxel of brick u_lv_d0, relative to O
uniform vec3 u_lv_inv_scale[NUM_LEVELS];
uniform ivec3 u_lv_win[NUM_LEVELS]; // toroidal window of the level texture, in bricks (x, y, z)
uniform ivec3 u_lv_grid[NUM_LEVELS]; // the level's grid of bricks (x, y, z)
uniform vec3 u_lv_inv_tex_size[NUM_LEVELS];
uniform float u_lv_delta[NUM_LEVELS];
#ifdef EMPTY_SKIP
uniform vec3 u_lv_occ_size[NUM_LEVELS]; // the level's cells per axis (x, y, z) in u_occ
uniform float u_lv_occ_z0[NUM_LEVELS];  // and its first z there
#endif
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
    // row and column by a shift and a mask (i >= 0): a division by a uniform is one integer
    // division per lane on a SIMD rasteriser (llvmpipe scalarises it), two per level looked up
    return texelFetch(u_page_table, ivec2(i & ((1 << PT_WIDTH_LOG2) - 1), i >> PT_WIDTH_LOG2), 0).r;
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
#ifdef EMPTY_SKIP
    g_occ_size = u_lv_occ_size[L];
    g_occ_z0 = u_lv_occ_z0[L];
#endif
    march_segment(tex, base, dir, off, k.x, n, delta, isc, its, slot, clo, chi, row, STATE_ARGS);
#if defined(MODE_REDUCE)
    return true;
#elif defined(MODE_ISO)
    return acc.a <= 0.0;
#else
    return acc.a < u_opaque;
#endif
}

// One region of the ray from ta: the node just past ta, marched (DRAWN) or skipped (EMPTY); ta
// moves to where the ray leaves the node. false: the ray is opaque.
bool region(vec3 origin, vec3 dir, vec3 inv, float tend, inout float ta, STATE) {
    // look the node up just past ta (never past the middle of what is left of the ray)
    vec3 q = origin + min(ta + u_nudge + abs(ta) * 1e-6, 0.5 * (ta + tend)) * dir;
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
    float tb = min(min(min(far.x, far.y), far.z), tend);
    // a node left within rounding of the ray's exit is the ray's last: without this its lanes
    // would go round the loop twice more (a sliver, then a nudge), and on a SIMD rasteriser
    // every pixel of the group pays for each round
    if (tb >= tend - (u_nudge + abs(tend) * 1e-6)) tb = tend;
    // Branch-free on purpose: a march inside a per-pixel `if` costs llvmpipe several per cent per
    // sample (the condition's mask joins every store of the loop). A node that is not DRAWN, or no
    // progress (rounding at a face), marches the empty interval [ta, ta) instead.
    bool progress = tb > ta;
    bool drawn = progress && (e & 3u) == PT_DRAWN;
    float tm = drawn ? tb : ta;
    {
        int Ld = clamp(int((e >> 2) & 31u), LEVEL_LO, LEVEL_HI);
        ivec3 gcell = cell + u_pt_c0[L];
        // the data: the node's own brick, a resident ancestor's (Ld > L), or a block of
        // (1 << (L - Ld))^3 bricks of a finer level merged into this node (Ld < L), clipped to the
        // level's grid; its first brick idx and its extent in bricks cnt
        ivec3 idx = (L >= Ld) ? (gcell << (L - Ld)) : (gcell >> (Ld - L));
        ivec3 cnt = min(idx + (1 << max(L - Ld, 0)), u_lv_grid[Ld]) - idx;
        ivec3 rel = idx - u_lv_d0[Ld];
        vec3 vox0 = u_lv_vox0[Ld] + vec3(rel) * u_brick / u_lv_inv_scale[Ld];
        vec3 slot = vec3(idx % u_lv_win[Ld]) * u_brick;
        uint faces = e >> 8;
        vec3 clo = mix(vec3(0.0), vec3(-0.5), bvec3((faces & 1u) != 0u, (faces & 4u) != 0u, (faces & 16u) != 0u));
        vec3 chi = vec3(cnt) * u_brick - mix(vec3(1.0), vec3(0.5), bvec3((faces & 2u) != 0u, (faces & 8u) != 0u, (faces & 32u) != 0u));
        bool go = true;
#if LEVEL_LO == LEVEL_HI
        go = march(LEVEL_TEX, LEVEL_LO, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#else
        if (false) {}
#if NUM_LEVELS > 0 && LEVEL_LO <= 0 && 0 <= LEVEL_HI
        else if (Ld == 0) go = march(u_level0, 0, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 1 && LEVEL_LO <= 1 && 1 <= LEVEL_HI
        else if (Ld == 1) go = march(u_level1, 1, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 2 && LEVEL_LO <= 2 && 2 <= LEVEL_HI
        else if (Ld == 2) go = march(u_level2, 2, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 3 && LEVEL_LO <= 3 && 3 <= LEVEL_HI
        else if (Ld == 3) go = march(u_level3, 3, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 4 && LEVEL_LO <= 4 && 4 <= LEVEL_HI
        else if (Ld == 4) go = march(u_level4, 4, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 5 && LEVEL_LO <= 5 && 5 <= LEVEL_HI
        else if (Ld == 5) go = march(u_level5, 5, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 6 && LEVEL_LO <= 6 && 6 <= LEVEL_HI
        else if (Ld == 6) go = march(u_level6, 6, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 7 && LEVEL_LO <= 7 && 7 <= LEVEL_HI
        else if (Ld == 7) go = march(u_level7, 7, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 8 && LEVEL_LO <= 8 && 8 <= LEVEL_HI
        else if (Ld == 8) go = march(u_level8, 8, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 9 && LEVEL_LO <= 9 && 9 <= LEVEL_HI
        else if (Ld == 9) go = march(u_level9, 9, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 10 && LEVEL_LO <= 10 && 10 <= LEVEL_HI
        else if (Ld == 10) go = march(u_level10, 10, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 11 && LEVEL_LO <= 11 && 11 <= LEVEL_HI
        else if (Ld == 11) go = march(u_level11, 11, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 12 && LEVEL_LO <= 12 && 12 <= LEVEL_HI
        else if (Ld == 12) go = march(u_level12, 12, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 13 && LEVEL_LO <= 13 && 13 <= LEVEL_HI
        else if (Ld == 13) go = march(u_level13, 13, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 14 && LEVEL_LO <= 14 && 14 <= LEVEL_HI
        else if (Ld == 14) go = march(u_level14, 14, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#if NUM_LEVELS > 15 && LEVEL_LO <= 15 && 15 <= LEVEL_HI
        else if (Ld == 15) go = march(u_level15, 15, origin, dir, ta, tm, vox0, slot, clo, chi, STATE_ARGS);
#endif
#endif
        ta = progress ? tb : ta + u_nudge + abs(ta) * 1e-6;
        return go;
    }
}

void main() {
    vec3 origin;
    vec3 dir;
    vec3 inv;
    vec2 t;
    if (!pixel_ray_in_box(u_vol_lo, u_vol_hi, origin, dir, inv, t)) discard;
    STATE_INIT
    float ta = t.x;
    // the first region outside the loop: a march nested in a loop of non-constant count costs
    // llvmpipe a few per cent per sample (its masks), and most rays of a merged full-resolution
    // cut cross one or two nodes
    bool go = region(origin, dir, inv, t.y, ta, STATE_ARGS);
    if (u_max_regions > 1) {            // uniform: a table of one node over the whole volume skips the loop
        for (int r = 1; go && r < u_max_regions && ta < t.y; ++r) go = region(origin, dir, inv, t.y, ta, STATE_ARGS);
    }
    STATE_OUT
}
