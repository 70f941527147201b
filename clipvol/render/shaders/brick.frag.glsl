#version 330
// Ray-cast one brick's box (see clipvol/render/action.py for the technique).
// Back faces are rasterised (front-face culling) so the camera may be inside the box; the ray is
// rebuilt from gl_FragCoord with per-frame uniforms only, so every box of a pixel sees bit-identical
// rays, and samples lie on the lattice t = k * delta (spherical shells around the eye, or planes
// parallel to the view plane through the camera centre for orthographic views): half-open
// [t_entry, t_exit) intervals of adjacent boxes share no sample and skip none.

uniform vec2 u_viewport;
uniform bool u_ortho;
uniform vec3 u_forward;         // camera basis (unit) and half extents of the view
uniform vec3 u_right;           // (at depth 1 for perspective, world units for orthographic)
uniform vec3 u_up;
uniform vec2 u_half;
uniform vec3 u_center_rel;      // ortho: a point of the lattice's plane t = 0, relative to O

uniform vec3 u_box_lo;          // item box relative to O
uniform vec3 u_box_hi;
uniform vec3 u_o_minus_b;       // O - centre of the brick's first voxel (world)
uniform vec3 u_inv_scale;       // 1 / voxel size of the brick's level (x, y, z)
uniform vec3 u_slot_origin;     // first texel of the brick's slot (x, y, z)
uniform vec3 u_inv_tex_size;
uniform vec3 u_clamp_lo;        // brick-local voxel coordinate bounds (-0.5 .. B-0.5, or 0 .. B-1 on closed faces)
uniform vec3 u_clamp_hi;

uniform vec3 u_shape_lo;        // region of interest relative to O (+-1e30 without a box)
uniform vec3 u_shape_hi;
uniform vec4 u_planes[6];       // clip planes (n, d) relative to O: keep n.p + d >= 0
uniform bool u_has_box;
uniform int u_n_planes;

uniform float u_delta;          // sample spacing (world)
uniform float u_t_scale;        // transfer-function coordinate t = texel * scale + offset
uniform float u_t_offset;       // (raw = a * texel + b folded in, in float64 on the CPU)
uniform float u_alpha_ratio;    // delta / reference spacing of the transfer function
uniform int u_mode;             // 0 composite, 1 MIP
uniform int u_max_steps;
uniform float u_opaque;         // early ray termination inside a box

uniform sampler3D u_volume;
uniform sampler2D u_tf;
uniform sampler2D u_acc;        // composite: copy of the target after the previous batch of boxes
uniform bool u_use_acc;

out vec4 f_color;

float log1p_(float x) {         // accurate log(1 + x) for small x (Goldberg's trick)
    float u = 1.0 + x;
    if (u == 1.0) return x;
    return log(u) * x / (u - 1.0);
}

float expm1_(float x) {         // accurate exp(x) - 1 for small x
    float u = exp(x);
    if (u == 1.0) return x;
    float um1 = u - 1.0;
    if (um1 == -1.0) return -1.0;
    return um1 * x / log(u);
}

float correct_opacity(float a) {  // 1 - exp(r * log1p(-a)), stable at a -> 0 and a -> 1
    if (a <= 0.0) return 0.0;
    if (a >= 1.0) return 1.0;
    return clamp(-expm1_(u_alpha_ratio * log1p_(-a)), 0.0, 1.0);
}

void main() {
    // early ray termination across boxes (front-to-back order): the pixel is already opaque
    if (u_use_acc && texelFetch(u_acc, ivec2(gl_FragCoord.xy), 0).a >= u_opaque) discard;
    vec2 ndc = gl_FragCoord.xy / u_viewport * 2.0 - 1.0;
    vec3 off = (ndc.x * u_half.x) * u_right + (ndc.y * u_half.y) * u_up;
    vec3 origin;
    vec3 dir;
    if (u_ortho) {              // rays start on the plane through the camera centre
        dir = u_forward;
        origin = u_center_rel + off;
    } else {                    // rays start at the eye (O itself)
        dir = normalize(u_forward + off);
        origin = vec3(0.0);
    }
    vec3 d = dir;
    d = mix(d, vec3(1e-30), equal(d, vec3(0.0)));
    vec3 inv = 1.0 / d;
    vec3 ta = (u_box_lo - origin) * inv;
    vec3 tb = (u_box_hi - origin) * inv;
    vec3 tmin = min(ta, tb);
    vec3 tmax = max(ta, tb);
    float t0 = max(max(tmin.x, tmin.y), tmin.z);
    float t1 = min(min(tmax.x, tmax.y), tmax.z);
    // clip the interval to the shape: its box, then its planes
    if (u_has_box) {
        vec3 sa = (u_shape_lo - origin) * inv;
        vec3 sb = (u_shape_hi - origin) * inv;
        vec3 smin = min(sa, sb);
        vec3 smax = max(sa, sb);
        t0 = max(t0, max(max(smin.x, smin.y), smin.z));
        t1 = min(t1, min(min(smax.x, smax.y), smax.z));
    }
    for (int i = 0; i < u_n_planes; ++i) {
        float nd = dot(u_planes[i].xyz, dir);
        float no = dot(u_planes[i].xyz, origin) + u_planes[i].w;
        if (nd == 0.0) {
            if (no < 0.0) discard;
        } else if (nd > 0.0) {
            t0 = max(t0, -no / nd);
        } else {
            t1 = min(t1, -no / nd);
        }
    }
    if (!u_ortho) t0 = max(t0, 0.0);
    if (!(t1 > t0)) discard;
    float k0 = ceil(t0 / u_delta);
    if (k0 * u_delta < t0) k0 += 1.0;
    float k1 = ceil(t1 / u_delta) - 1.0;
    if ((k1 + 1.0) * u_delta < t1) k1 += 1.0;
    int n = int(min(k1 - k0 + 1.0, float(u_max_steps)));
    if (n <= 0) discard;

    vec3 base = origin + u_o_minus_b;   // ray origin relative to the brick's first voxel centre
    vec4 acc = vec4(0.0);
    float vmax = -3.0e38;
    bool hit = false;
    for (int i = 0; i < n; ++i) {
        float t = (k0 + float(i)) * u_delta;
        vec3 u = (base + t * dir) * u_inv_scale;
        u = clamp(u, u_clamp_lo, u_clamp_hi);
        float texel = texture(u_volume, (u_slot_origin + u + 0.5) * u_inv_tex_size).r;
        if (isnan(texel) || isinf(texel)) continue;   // NaN / Inf data is transparent
        if (u_mode == 1) {          // MIP: the largest texel; mapped to a value on the CPU
            vmax = max(vmax, texel);
            hit = true;
            continue;
        }
        float tt = clamp(texel * u_t_scale + u_t_offset, 0.0, 1.0);
        vec4 c = texture(u_tf, vec2(tt, 0.5));
        float a = correct_opacity(c.a);
        acc.rgb += (1.0 - acc.a) * a * c.rgb;
        acc.a += (1.0 - acc.a) * a;
        if (acc.a >= u_opaque) break;
    }
    if (u_mode == 1) {
        if (!hit) discard;
        f_color = vec4(vmax, 0.0, 0.0, 1.0);
    } else {
        f_color = acc;
    }
}
