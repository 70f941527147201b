#version 330
// Ray-cast one brick's box (see clipvol/render/action.py for the technique).
// Drawn as one viewport triangle under the box's scissor rectangle (screen.vert.glsl): the ray is
// intersected with the box here, so the camera may be inside it. The ray is
// rebuilt from gl_FragCoord with per-frame uniforms only, so every box of a pixel sees bit-identical
// rays, and samples lie on the lattice t = off + k * delta (spherical shells around the eye, or
// planes parallel to the view plane through the camera centre for orthographic views; off is the
// pixel's jitter, the same for every box): half-open [t_entry, t_exit) intervals of adjacent
// boxes share no sample and skip none.
#include "volume_common.glsl"

uniform vec3 u_box_lo;          // item box relative to O
uniform vec3 u_box_hi;
uniform vec3 u_o_minus_b;       // O - centre of the brick's first voxel (world)
uniform vec3 u_inv_scale;       // 1 / voxel size of the brick's level (x, y, z)
uniform vec3 u_slot_origin;     // first texel of the brick's slot (x, y, z)
uniform vec3 u_inv_tex_size;
uniform vec3 u_clamp_lo;        // brick-local voxel coordinate bounds (-0.5 .. B-0.5, or 0 .. B-1 on closed faces)
uniform vec3 u_clamp_hi;

uniform float u_delta;          // sample spacing (world)
uniform float u_tf_row;         // row of this level in u_tf
uniform int u_max_steps;

uniform sampler3D u_volume;
uniform sampler2D u_acc;        // composite: copy of the target after the previous batch of boxes
uniform bool u_use_acc;
#ifdef EMPTY_SKIP
uniform vec3 u_occ_size;        // the level's cells per axis (x, y, z) in u_occ, and its first z there
uniform float u_occ_z0;
#endif

out vec4 f_color;

void main() {
    // early ray termination across boxes (front-to-back order): the pixel is already opaque
    if (u_use_acc && texelFetch(u_acc, ivec2(gl_FragCoord.xy), 0).a >= u_opaque) discard;
    vec3 origin;
    vec3 dir;
    vec3 inv;
    vec2 t;
    if (!pixel_ray_in_box(u_box_lo, u_box_hi, origin, dir, inv, t)) discard;
    float off = pixel_hash() * u_jitter * u_delta;
    vec2 k = lattice_range(t.x, t.y, off, u_delta);
    int n = int(min(k.y - k.x + 1.0, float(u_max_steps)));
    if (n <= 0) discard;

#ifdef OVERLAY
    g_ov_origin = origin;
#endif
#ifdef EMPTY_SKIP
    g_occ_size = u_occ_size;
    g_occ_z0 = u_occ_z0;
#endif
    vec3 base = origin + u_o_minus_b;   // ray origin relative to the brick's first voxel centre
    STATE_INIT
    march_segment(u_volume, base, dir, off, k.x, n, u_delta, u_inv_scale, u_inv_tex_size, u_slot_origin,
                  u_clamp_lo, u_clamp_hi, u_tf_row, STATE_ARGS);
    STATE_OUT
}
