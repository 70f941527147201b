// Shared by the volume shaders (brick.frag.glsl, raymarch.frag.glsl): rays, the sample lattice,
// sampling and the transfer function. Compiled as variants (see clipvol/render/glsl.py):
//   MODE_MIP  maximum intensity projection (none of the MODE_*: composite, front to back)
//   MODE_MINIP minimum intensity projection
//   MODE_AVERAGE the mean along the ray: (sum of sample * step, sum of steps), divided on read-back
//   MODE_ISO  the first sample >= u_iso, refined between it and the sample before, lit from its gradient
//   MODE_GLSL a registered mode's own code (clipvol/render/modes), inserted at "#include MODE_GLSL":
//             it defines STATE, STATE_ARGS, STATE_INIT, STATE_OUT and MODE_TAKE(texel); a reduction
//   HAS_NAN   the data may hold NaN/Inf: trilinear over the finite neighbours only
//   SHADING   composite only: Blinn-Phong lighting from central-difference gradients, light at the eye
//   OVERLAY   composite only: the number (1..3) of co-registered overlay volumes sampled at each sample
//             (OVERLAYk_LABELS: overlay k nearest through its id table; OVERLAYk_CLASSIFIED: its 8
//             voxels classified, then interpolated; neither: interpolated, then classified)
//   EMPTY_SKIP composite without overlays: leap over cells the transfer function makes transparent
//   DISTRIB   composite, finite data: the level textures hold (mean, spread) per voxel (.rg; a level
//             without spread reads 0 there) and a sample is classified by the transfer function
//             pre-integrated over that distribution, u_dist (clipvol/scene/consistent.py); DISTRIB is
//             the number of spread rows per level
uniform vec2 u_viewport;
uniform vec2 u_frag_origin;     // the pass's viewport origin in its target (a coarse pass spread over tiles)
uniform bool u_ortho;
uniform vec3 u_forward;         // camera basis (unit) and half extents of the view
uniform vec3 u_right;           // (at depth 1 for perspective, world units for orthographic)
uniform vec3 u_up;
uniform vec2 u_half;
uniform vec3 u_center_rel;      // ortho: a point of the lattice's plane t = 0, relative to O

uniform vec3 u_shape_lo;        // region of interest relative to O (+-1e30 without a box)
uniform vec3 u_shape_hi;
uniform vec4 u_planes[6];       // clip planes (n, d) relative to O: keep n.p + d >= 0
uniform bool u_has_box;
uniform int u_n_planes;

uniform float u_t_scale;        // transfer-function coordinate t = texel * scale + offset
uniform float u_t_offset;       // (raw = a * texel + b folded in, in float64 on the CPU)
uniform float u_jitter;         // 1: the lattice starts at a per-pixel offset hash * delta; 0: at 0
uniform float u_opaque;         // early ray termination
uniform sampler2D u_tf;         // row L: the table with opacity corrected for level L's step
#if defined(MODE_MIP) || defined(MODE_MINIP) || defined(MODE_AVERAGE) || defined(MODE_GLSL)
#define MODE_REDUCE             // a per-pixel reduction of the samples, mapped on read-back; no early stop
#endif
#ifdef MODE_ISO
uniform float u_iso;            // the iso-value as a texel (raw = a * texel + b, a > 0: the same order)
#endif

// The pixel's ray: origin relative to O and unit direction.
void pixel_ray(out vec3 origin, out vec3 dir) {
    vec2 ndc = (gl_FragCoord.xy - u_frag_origin) / u_viewport * 2.0 - 1.0;
    vec3 off = (ndc.x * u_half.x) * u_right + (ndc.y * u_half.y) * u_up;
    if (u_ortho) {              // rays start on the plane through the camera centre
        dir = u_forward;
        origin = u_center_rel + off;
    } else {                    // rays start at the eye (O itself)
        dir = normalize(u_forward + off);
        origin = vec3(0.0);
    }
}

vec3 safe_inverse(vec3 dir) {
    return 1.0 / mix(dir, vec3(1e-30), equal(dir, vec3(0.0)));
}

// [t0, t1] of the ray with a box (t1 < t0: missed)
vec2 box_interval(vec3 origin, vec3 inv, vec3 lo, vec3 hi) {
    vec3 ta = (lo - origin) * inv;
    vec3 tb = (hi - origin) * inv;
    vec3 tmin = min(ta, tb);
    vec3 tmax = max(ta, tb);
    return vec2(max(max(tmin.x, tmin.y), tmin.z), min(min(tmax.x, tmax.y), tmax.z));
}

// Narrow [t.x, t.y] to the shape (its box, then its planes) and to the eye's front; false: empty.
bool clip_to_shape(vec3 origin, vec3 dir, vec3 inv, inout vec2 t) {
    if (u_has_box) {
        vec2 s = box_interval(origin, inv, u_shape_lo, u_shape_hi);
        t = vec2(max(t.x, s.x), min(t.y, s.y));
    }
    for (int i = 0; i < u_n_planes; ++i) {
        float nd = dot(u_planes[i].xyz, dir);
        float no = dot(u_planes[i].xyz, origin) + u_planes[i].w;
        if (nd == 0.0) {
            if (no < 0.0) return false;
        } else if (nd > 0.0) {
            t.x = max(t.x, -no / nd);
        } else {
            t.y = min(t.y, -no / nd);
        }
    }
    if (!u_ortho) t.x = max(t.x, 0.0);
    return t.y > t.x;
}

// The pixel's ray (origin relative to O, unit direction, its safe inverse) and its interval in the
// box [lo, hi] narrowed to the shape; false: the ray misses.
bool pixel_ray_in_box(vec3 lo, vec3 hi, out vec3 origin, out vec3 dir, out vec3 inv, out vec2 t) {
    pixel_ray(origin, dir);
    inv = safe_inverse(dir);
    t = box_interval(origin, inv, lo, hi);
    return clip_to_shape(origin, dir, inv, t);
}

// Stable per-pixel offset in [0, 1) (a 2-D integer hash of the pixel; the same every frame).
float pixel_hash() {
    uvec2 p = uvec2(gl_FragCoord.xy - u_frag_origin);
    uint h = p.x * 1597334677u ^ p.y * 3812015801u;
    h = (h ^ (h >> 16)) * 2246822519u;
    h = (h ^ (h >> 13)) * 3266489917u;
    h ^= h >> 16;
    return float(h >> 8) * (1.0 / 16777216.0);
}

// Lattice indices [k0, k1] of t = off + k * delta inside the half-open [t0, t1).
vec2 lattice_range(float t0, float t1, float off, float delta) {
    float k0 = ceil((t0 - off) / delta);
    if (off + k0 * delta < t0) k0 += 1.0;
    float k1 = ceil((t1 - off) / delta) - 1.0;
    if (off + (k1 + 1.0) * delta < t1) k1 += 1.0;
    return vec2(k0, k1);
}

#ifdef HAS_NAN
// Trilinear over the finite neighbours only, weights renormalised: a sample is non-finite only
// where every neighbour of non-zero weight is. Fractions within 1/4096 of a voxel centre snap to
// it (float32 positions meant to be on a centre are a few 1e-6 off; a renormalised weight of 1e-6
// would otherwise give a NaN voxel's centre its neighbour's value). p: texel coordinates (centres
// at integers); the texture is toroidal (wrapped by hand, as REPEAT would).
float sample_texels(sampler3D tex, vec3 p, vec3 inv_size) {
    ivec3 size = textureSize(tex, 0);
    vec3 fl = floor(p);
    vec3 f = p - fl;
    f = mix(f, vec3(0.0), lessThan(f, vec3(1.0 / 4096.0)));
    f = mix(f, vec3(1.0), greaterThan(f, vec3(1.0 - 1.0 / 4096.0)));
    ivec3 i0 = ivec3(fl);
    float s = 0.0;
    float w = 0.0;
    for (int c = 0; c < 8; ++c) {
        ivec3 o = ivec3(c & 1, (c >> 1) & 1, (c >> 2) & 1);
        vec3 wv = mix(1.0 - f, f, vec3(o));
        float wt = wv.x * wv.y * wv.z;
        ivec3 q = (i0 + o) % size;
        q += size * ivec3(lessThan(q, ivec3(0)));
        float v = texelFetch(tex, q, 0).r;
        if (wt > 0.0 && !isnan(v) && !isinf(v)) {
            s += wt * v;
            w += wt;
        }
    }
    return w > 0.0 ? s / w : uintBitsToFloat(0x7fc00000u);
}
#define SAMPLE_OK(v) (!isnan(v) && !isinf(v))
#else
float sample_texels(sampler3D tex, vec3 p, vec3 inv_size) {
    return texture(tex, (p + 0.5) * inv_size).r;
}
#define SAMPLE_OK(v) true
#endif

#ifdef DISTRIB
uniform sampler2D u_dist;       // per level DISTRIB rows of spread: the table pre-integrated over N(mean, spread)
uniform float u_dist_inv_h;     // 1 / the table's height in texels
uniform float u_sigma_scale;    // spread texel -> spread in table coordinates over SPREAD_MAX
#endif

// The straight colour and corrected opacity of a sample of mean `texel` and spread `spread` (texels)
// in the level of table row `row`: the plain table row, or with DISTRIB the table's expectation
// over the distribution (row coordinate sqrt(spread / SPREAD_MAX) * (DISTRIB - 1), interpolated).
vec4 classify(float texel, float spread, float row) {
#ifdef DISTRIB
    float u = sqrt(clamp(spread * u_sigma_scale, 0.0, 1.0)) * float(DISTRIB - 1);
    return texture(u_dist, vec2(texel * u_t_scale + u_t_offset, row + (u + 0.5 - 0.5 * float(DISTRIB)) * u_dist_inv_h));
#else
    return texture(u_tf, vec2(texel * u_t_scale + u_t_offset, row));
#endif
}

// Front-to-back "under" of one sample (colour straight, opacity already corrected in the table row)
void composite_sample(inout vec4 acc, float texel, float spread, float row) {
    vec4 c = classify(texel, spread, row);
    float w = (1.0 - acc.a) * c.a;
    acc.rgb += w * c.rgb;
    acc.a += w;
}

#ifdef OVERLAY
// Overlays of co-registered volumes (clipvol/scene/overlay.py): each one whole level in one float32
// texture with its own transfer-function table (rows per primary level, opacity corrected for the
// primary's step). At each sample of the primary, every overlay is sampled at the same point (its
// texture coordinate is affine in the position relative to O: c = a * p + b, a 3x3 matrix holding
// the overlay's inverse affine, so flipped, permuted, rotated or sheared overlays land in place) and composited under
// the ray before the primary's sample: the overlays' colours over the primary's, the first on top.
// An overlay is sampled at least as finely as the primary samples its own voxels: where the primary's
// step delta (its drawn level's voxel times the step fraction) exceeds the overlay's own step
// u_ovk_step (the same fraction of the overlay's smallest voxel), the sample at t takes n sub-samples
// at t + j * delta / n (j = 0 .. n - 1, n = ceil(delta / u_ovk_step), at most OV_MAX_SUB): the primary's
// constant-distance lattice refined n times, each sub-sample's opacity corrected for delta / n. Without
// it a primary drawn from a coarse level samples a finer map every few of its voxels, and a saturated
// blob shows stair-step rings one step apart.
vec3 g_ov_origin;               // the pixel ray's origin relative to O (set by the fragment's main)
uniform sampler3D u_ov0_tex;
uniform sampler2D u_ov0_tf;
uniform mat3 u_ov0_a;           // texture coordinate c = a * p + b (p relative to O): the overlay's inverse affine
uniform vec3 u_ov0_b;
uniform vec2 u_ov0_t;           // table coordinate t = value * t.x + t.y
uniform float u_ov0_step;       // the overlay's own sample spacing (world units): its smallest voxel times the step
#if OVERLAY > 1
uniform sampler3D u_ov1_tex;
uniform sampler2D u_ov1_tf;
uniform mat3 u_ov1_a;
uniform vec3 u_ov1_b;
uniform vec2 u_ov1_t;
uniform float u_ov1_step;
#endif
#if OVERLAY > 2
uniform sampler3D u_ov2_tex;
uniform sampler2D u_ov2_tf;
uniform mat3 u_ov2_a;
uniform vec3 u_ov2_b;
uniform vec2 u_ov2_t;
uniform float u_ov2_step;
#endif

#define OV_MAX_SUB 16

// The number of sub-samples of an overlay whose own step is `own` at a primary sample of step delta.
int overlay_subs(float delta, float own) {
    return int(clamp(ceil(delta / max(own, 1e-30) - 1e-3), 1.0, float(OV_MAX_SUB)));
}

// One overlay's sample at p: straight colour and opacity (0 outside its box or where not finite), the
// opacity of the table row (corrected for the primary's step) corrected for 1/n of that step.
vec4 overlay_one(sampler3D tex, sampler2D tf, mat3 a, vec3 b, vec2 tm, vec3 p, float row, float n) {
    vec3 c = a * p + b;
    if (any(lessThan(c, vec3(0.0))) || any(greaterThan(c, vec3(1.0)))) return vec4(0.0);   // outside its box
    float v = texture(tex, c).r;
    if (isnan(v) || isinf(v)) return vec4(0.0);
    vec4 s = texture(tf, vec2(v * tm.x + tm.y, row));
    if (n > 1.0) s.a = 1.0 - pow(1.0 - s.a, 1.0 / n);
    return s;
}

// One overlay's sample at p, classified before it is interpolated (OVERLAYk_CLASSIFIED, the default
// for maps): the 8 voxels around c (texelFetch at the clamped integer corners of the trilinear cell,
// the clamp-to-edge addressing texture() uses) each looked up in the table, their premultiplied
// colours blended with the trilinear weights, straight colour back out. Between a saturated voxel and a
// zero one lies a half-transparent saturated colour, never the pale middle of the table that the
// interpolated value would pick (the "circuit-board" lines in a clipped, masked statistical map).
// A non-finite voxel weighs in as transparent. Each voxel's opacity is corrected for the sub-step
// (1/n of the table row's step) before the blend, so the colour does not depend on the primary's
// drawn level. Where the 8 values are equal one lookup serves.
vec4 overlay_classified(sampler3D tex, sampler2D tf, mat3 a, vec3 b, vec2 tm, vec3 p, float row, float n) {
    vec3 c = a * p + b;
    if (any(lessThan(c, vec3(0.0))) || any(greaterThan(c, vec3(1.0)))) return vec4(0.0);   // outside its box
    ivec3 size = textureSize(tex, 0);
    vec3 u = c * vec3(size) - 0.5;
    vec3 fl = floor(u);
    vec3 f = u - fl;
    ivec3 i0 = clamp(ivec3(fl), ivec3(0), size - 1);
    ivec3 i1 = clamp(ivec3(fl) + 1, ivec3(0), size - 1);
    float v[8];
    v[0] = texelFetch(tex, ivec3(i0.x, i0.y, i0.z), 0).r;
    v[1] = texelFetch(tex, ivec3(i1.x, i0.y, i0.z), 0).r;
    v[2] = texelFetch(tex, ivec3(i0.x, i1.y, i0.z), 0).r;
    v[3] = texelFetch(tex, ivec3(i1.x, i1.y, i0.z), 0).r;
    v[4] = texelFetch(tex, ivec3(i0.x, i0.y, i1.z), 0).r;
    v[5] = texelFetch(tex, ivec3(i1.x, i0.y, i1.z), 0).r;
    v[6] = texelFetch(tex, ivec3(i0.x, i1.y, i1.z), 0).r;
    v[7] = texelFetch(tex, ivec3(i1.x, i1.y, i1.z), 0).r;
    vec4 s;
    if (v[0] == v[1] && v[0] == v[2] && v[0] == v[3] && v[0] == v[4] && v[0] == v[5] && v[0] == v[6] && v[0] == v[7]) {
        if (isnan(v[0]) || isinf(v[0])) return vec4(0.0);
        s = texture(tf, vec2(v[0] * tm.x + tm.y, row));
    } else {
        vec4 acc = vec4(0.0);
        for (int k = 0; k < 8; ++k) {
            if (isnan(v[k]) || isinf(v[k])) continue;
            vec3 w3 = mix(1.0 - f, f, vec3(ivec3(k & 1, (k >> 1) & 1, (k >> 2) & 1)));
            vec4 q = texture(tf, vec2(v[k] * tm.x + tm.y, row));
            if (n > 1.0) q.a = 1.0 - pow(1.0 - q.a, 1.0 / n);   // each voxel's opacity for the sub-step
            acc += (w3.x * w3.y * w3.z * q.a) * vec4(q.rgb, 1.0);
        }
        if (acc.a <= 0.0) return vec4(0.0);
        return vec4(acc.rgb / acc.a, acc.a);
    }
    if (n > 1.0) s.a = 1.0 - pow(1.0 - s.a, 1.0 / n);
    return s;
}

// A label overlay (OVERLAYk_LABELS): the texture holds per voxel the index of its id among the
// ids present; the id's colour is texel (k % w, k / w) of the table (straight RGBA, opacity per the
// primary's level-0 voxel, corrected here for the step delta). Nearest: the voxel whose cell holds p.
uniform float u_ov_inv_ref;     // 1 / the primary's smallest level-0 voxel size

vec4 overlay_label(sampler3D tex, sampler2D tab, mat3 a, vec3 b, vec3 p, float delta) {
    vec3 c = a * p + b;
    if (any(lessThan(c, vec3(0.0))) || any(greaterThan(c, vec3(1.0)))) return vec4(0.0);
    ivec3 size = textureSize(tex, 0);
    ivec3 q = min(ivec3(c * vec3(size)), size - 1);
    int k = int(texelFetch(tex, q, 0).r + 0.5);
    int w = textureSize(tab, 0).x;
    vec4 s = texelFetch(tab, ivec2(k % w, k / w), 0);
    return vec4(s.rgb, 1.0 - pow(1.0 - s.a, delta * u_ov_inv_ref));
}

#ifdef OVERLAY0_LABELS
#define OVERLAY0(p, row, delta, n) overlay_label(u_ov0_tex, u_ov0_tf, u_ov0_a, u_ov0_b, p, delta / n)
#elif defined(OVERLAY0_CLASSIFIED)
#define OVERLAY0(p, row, delta, n) overlay_classified(u_ov0_tex, u_ov0_tf, u_ov0_a, u_ov0_b, u_ov0_t, p, row, n)
#else
#define OVERLAY0(p, row, delta, n) overlay_one(u_ov0_tex, u_ov0_tf, u_ov0_a, u_ov0_b, u_ov0_t, p, row, n)
#endif
#ifdef OVERLAY1_LABELS
#define OVERLAY1(p, row, delta, n) overlay_label(u_ov1_tex, u_ov1_tf, u_ov1_a, u_ov1_b, p, delta / n)
#elif defined(OVERLAY1_CLASSIFIED)
#define OVERLAY1(p, row, delta, n) overlay_classified(u_ov1_tex, u_ov1_tf, u_ov1_a, u_ov1_b, u_ov1_t, p, row, n)
#else
#define OVERLAY1(p, row, delta, n) overlay_one(u_ov1_tex, u_ov1_tf, u_ov1_a, u_ov1_b, u_ov1_t, p, row, n)
#endif
#ifdef OVERLAY2_LABELS
#define OVERLAY2(p, row, delta, n) overlay_label(u_ov2_tex, u_ov2_tf, u_ov2_a, u_ov2_b, p, delta / n)
#elif defined(OVERLAY2_CLASSIFIED)
#define OVERLAY2(p, row, delta, n) overlay_classified(u_ov2_tex, u_ov2_tf, u_ov2_a, u_ov2_b, u_ov2_t, p, row, n)
#else
#define OVERLAY2(p, row, delta, n) overlay_one(u_ov2_tex, u_ov2_tf, u_ov2_a, u_ov2_b, u_ov2_t, p, row, n)
#endif

// "over" (default): each overlay's sample under the ray, then the primary's (the overlays' colours
// over the primary's). OVERLAY_ADDITIVE (channels): the sample's premultiplied colours add up,
// c = sum(a_k * rgb_k), opacity 1 - prod(1 - a_k), the primary's sample included; the whole
// sample then goes under the ray, and the primary's own compositing is skipped (the hook continues).
#ifdef OVERLAY_ADDITIVE
#define OVERLAY_TAKE(s) { vec4 s_ = (s); sum_c += s_.a * s_.rgb; sum_t *= 1.0 - s_.a; }
#else
#define OVERLAY_TAKE(s) { vec4 s_ = (s); float w_ = (1.0 - acc.a) * s_.a; acc.rgb += w_ * s_.rgb; acc.a += w_; }
#endif

// overlay k's n sub-samples of the primary's sample at ts, front to back
#define OVERLAY_SUBS(OV, STEP) { int n_ = overlay_subs(delta, STEP); float fn_ = float(n_); for (int j_ = 0; j_ < n_; ++j_) OVERLAY_TAKE(OV(p + (float(j_) * delta / fn_) * dir, row, delta, fn_)); }

void overlay_under(inout vec4 acc, float ts, vec3 dir, float row, float delta, float texel) {
    vec3 p = g_ov_origin + ts * dir;
#ifdef OVERLAY_ADDITIVE
    vec3 sum_c = vec3(0.0);
    float sum_t = 1.0;
#endif
    OVERLAY_SUBS(OVERLAY0, u_ov0_step);
#if OVERLAY > 1
    OVERLAY_SUBS(OVERLAY1, u_ov1_step);
#endif
#if OVERLAY > 2
    OVERLAY_SUBS(OVERLAY2, u_ov2_step);
#endif
#ifdef OVERLAY_ADDITIVE
    if (SAMPLE_OK(texel)) OVERLAY_TAKE(texture(u_tf, vec2(texel * u_t_scale + u_t_offset, row)));
    acc.rgb += (1.0 - acc.a) * sum_c;
    acc.a += (1.0 - acc.a) * (1.0 - sum_t);
#endif
}
#ifdef OVERLAY_ADDITIVE
#define OVERLAY_UNDER(acc, ts, dir, row, delta, texel) { overlay_under(acc, ts, dir, row, delta, texel); if (acc.a >= u_opaque) break; continue; }
#else
#define OVERLAY_UNDER(acc, ts, dir, row, delta, texel) overlay_under(acc, ts, dir, row, delta, texel)
#endif
#else
#define OVERLAY_UNDER(acc, ts, dir, row, delta, texel)
#endif

#if defined(SHADING) || defined(MODE_ISO)
// Gradient lighting (Blinn-Phong, light fixed to the camera: light, view and half vector all equal
// -dir, two-sided so the sign of the gradient does not matter). The gradient is a central
// difference of the interpolated data one voxel either side along each brick-local axis, read from
// the same toroidal level texture (neighbour bricks of an open face are on the GPU: gpu_cache.py),
// divided by the voxel size of the level (anisotropic spacing). The difference positions are
// clamped like the samples, widened by one voxel on open faces: on a closed face (the volume's
// edge, a missing neighbour, a level change) the data is clamped to the brick's own voxel centres,
// so the gradient there is one-sided - the documented seam at level changes.
uniform vec4 u_light;           // ambient, diffuse, specular, shininess

// clamp bounds of the gradient positions: one voxel further on open faces (x.5 bounds)
void gradient_bounds(vec3 clo, vec3 chi, out vec3 glo, out vec3 ghi) {
    glo = clo - vec3(notEqual(fract(clo), vec3(0.0)));
    ghi = chi + vec3(notEqual(fract(chi), vec3(0.0)));
}

// gradient of the texel value per world unit at brick-local texel position u (already clamped)
vec3 gradient_at(sampler3D tex, vec3 slot, vec3 u, vec3 glo, vec3 ghi, vec3 its, vec3 inv_scale, float centre) {
    vec3 g;
    for (int a = 0; a < 3; ++a) {
        vec3 e = vec3(0.0);
        e[a] = 1.0;
        float hi = sample_texels(tex, slot + clamp(u + e, glo, ghi), its);
        float lo = sample_texels(tex, slot + clamp(u - e, glo, ghi), its);
        if (!SAMPLE_OK(hi)) hi = centre;    // non-finite neighbours: one-sided difference
        if (!SAMPLE_OK(lo)) lo = centre;
        g[a] = 0.5 * (hi - lo) * inv_scale[a];
    }
    return g;
}

#ifdef SHADING
void composite_lit(inout vec4 acc, float texel, float spread, float row, vec3 g, vec3 dir) {
    vec4 c = classify(texel, spread, row);
    float gl = length(g);
    float d = gl > 0.0 ? abs(dot(g, dir)) / gl : 0.0;
    vec3 rgb = min(c.rgb * (u_light.x + u_light.y * d) + u_light.z * pow(d, u_light.w), vec3(1.0));
    float w = (1.0 - acc.a) * c.a;
    acc.rgb += w * rgb;
    acc.a += w;
}
#endif
#endif

// A ray's state while it marches (STATE: as parameters, STATE_ARGS: as arguments), its start
// (STATE_INIT) and the fragment written from it at the end (STATE_OUT; MIP, minIP, average, iso:
// nothing hit, no fragment). MIP/minIP: the extreme texel (the target blends with MAX / MIN);
// average: (sum of texel * delta, sum of delta), additive blending (each sample weighted by its
// length, so a cut of several levels averages over the ray's length); iso: (t of the hit, lighting
// factor |g.v|/|g|, texel at the hit, 1): opaque, so "under" / "over" blending keeps the nearest.
#if defined(MODE_MIP) || defined(MODE_MINIP)
#ifdef MODE_MIP
#define TAKE_EXT(v) vext = max(vext, v)
#define EXT_INIT -3.0e38
#else
#define TAKE_EXT(v) vext = min(vext, v)
#define EXT_INIT 3.0e38
#endif
#define STATE inout float vext, inout bool hit
#define STATE_ARGS vext, hit
#define STATE_INIT float vext = EXT_INIT; bool hit = false;
#define STATE_OUT { if (!hit) discard; f_color = vec4(vext, 0.0, 0.0, 1.0); }
#elif defined(MODE_AVERAGE)
#define STATE inout vec2 sw
#define STATE_ARGS sw
#define STATE_INIT vec2 sw = vec2(0.0);
#define STATE_OUT { if (!(sw.y > 0.0)) discard; f_color = vec4(sw, 0.0, 0.0); }
#elif defined(MODE_ISO)
#define STATE inout vec4 acc
#define STATE_ARGS acc
#define STATE_INIT vec4 acc = vec4(0.0);
#define STATE_OUT { if (acc.a <= 0.0) discard; f_color = acc; }
#elif defined(MODE_GLSL)
#include MODE_GLSL
#else
#define STATE inout vec4 acc
#define STATE_ARGS acc
#define STATE_INIT vec4 acc = vec4(0.0);
#define STATE_OUT f_color = acc;
#endif

#ifdef EMPTY_SKIP
// Empty-space skipping below the brick (clipvol/scene/occupancy.py, composite without overlays):
// u_occ holds one flag per cell of every level's toroidal texture (0: every sample assigned to the
// cell is transparent under the current table), the levels stacked along z. g_occ_size: the marched
// level's cells per axis, which is also its cells per unit of texture coordinate; g_occ_z0: its
// first z in u_occ (both set by the caller of march_segment). The march looks the flag up at the
// sample that enters a cell and, where it is 0, goes on at the first sample past the cell, so an
// empty cell costs one lookup instead of its samples; the lattice is untouched.
#ifndef SKIP_BLOCK
#define SKIP_BLOCK 8              // samples per lookup (the single pass compiles 2: single_pass.py)
#endif
uniform sampler3D u_occ;
vec3 g_occ_size;
float g_occ_z0;

// The cell holding sample i (at q0 + i * cs in cell units): the first sample index past it (at
// least i + 1, at most n) and whether it may be visible. Only samples at least OCC_MARGIN of a
// cell inside it are leapt (a sample within it of a face is taken), so rounding of positions and of
// the exit index never leaps a sample that reads a voxel beyond what the cell's flag covers.
#define OCC_MARGIN 1e-3
int cell_exit(int i, int n, vec3 q0, vec3 cs, vec3 ics, vec3 side, out bool visible) {
    vec3 q = q0 + float(i) * cs;
    vec3 cf = floor(q);
    vec3 f = q - cf;
    vec3 ex = (cf + mix(vec3(OCC_MARGIN), vec3(1.0 - OCC_MARGIN), side) - q0) * ics;
    int e = int(clamp(ceil(min(min(ex.x, ex.y), ex.z)), float(i + 1), float(n)));
    vec3 w = mod(cf, g_occ_size);     // toroidal, as REPEAT wraps the level texture
    bool flag = texelFetch(u_occ, ivec3(w) + ivec3(0, 0, int(g_occ_z0)), 0).r > 0.5;
    bool near = any(greaterThan(abs(f - 0.5), vec3(0.5 - OCC_MARGIN)));
    visible = flag || near;
    return (flag || !near) ? e : i + 1;     // a visible cell: its samples are taken without a lookup
}
// c0, dc: texture coordinate of sample 0 and its step (cell i of the level holds voxel coordinates
// [e * i, e * (i + 1)), e the cell edge: q = c * size / e - 0.5 / e = c * g_occ_size - u_occ_shift);
// then, at the top of the loop over i (SKIP_CHECK, the lit and NaN-aware march), a sample entering
// an empty cell leaps past it and the run of empty cells after it (break: empty to the end)
uniform vec3 u_occ_shift;       // 0.5 / cell edge (x, y, z)
#define SKIP_SETUP(c0, dc) vec3 q0_ = (c0) * g_occ_size - u_occ_shift; vec3 cs_ = (dc) * g_occ_size; vec3 ics_ = safe_inverse(cs_); vec3 side_ = vec3(greaterThanEqual(cs_, vec3(0.0))); int run_ = 0;
#define SKIP_CHECK(i, n) if ((i) >= run_) { bool vis_; int e_ = cell_exit(i, n, q0_, cs_, ics_, side_, vis_); while (!vis_ && e_ < n) { i = e_; e_ = cell_exit(i, n, q0_, cs_, ics_, side_, vis_); } if (!vis_) break; run_ = e_; }
#endif

// Samples k0 .. k0 + n - 1 of the lattice t = off + k * delta along base + t * dir (base: the ray
// origin relative to the centre of the brick's first voxel) in one level's texture: brick-local
// voxel coordinates u = (base + t * dir) * isc clamped to [clo, chi], texel slot + u, colour table
// row `row`. Both volume paths march through this one loop, so they sample, light and composite
// identically. Composite stops once the accumulated opacity reaches u_opaque.
#if defined(HAS_NAN) || defined(SHADING) || defined(OVERLAY) || defined(MODE_ISO)
void march_segment(sampler3D tex, vec3 base, vec3 dir, float off, float k0, int n, float delta, vec3 isc,
                   vec3 its, vec3 slot, vec3 clo, vec3 chi, float row, STATE) {
#if defined(SHADING) || defined(MODE_ISO)
    vec3 glo;
    vec3 ghi;
    gradient_bounds(clo, chi, glo, ghi);
#endif
#if defined(HAS_NAN) || defined(SHADING) || defined(MODE_ISO)
#ifdef EMPTY_SKIP
    SKIP_SETUP((slot + (base + (off + k0 * delta) * dir) * isc + 0.5) * its, dir * (delta * isc * its))
#endif
    for (int i = 0; i < n; ++i) {
#ifdef EMPTY_SKIP
        SKIP_CHECK(i, n)
#endif
        float ts = off + (k0 + float(i)) * delta;
        vec3 u = clamp((base + ts * dir) * isc, clo, chi);
        float texel = sample_texels(tex, slot + u, its);
#ifdef DISTRIB
        float spread = texture(tex, (slot + u + 0.5) * its).g;
#else
        float spread = 0.0;
#endif
#else
    vec3 c0 = (slot + (base + (off + k0 * delta) * dir) * isc + 0.5) * its;
    vec3 dc = dir * (delta * isc * its);
    vec3 clo_t = (slot + clo + 0.5) * its;
    vec3 chi_t = (slot + chi + 0.5) * its;
    for (int i = 0; i < n; ++i) {
        vec2 tv_ = texture(tex, clamp(c0 + float(i) * dc, clo_t, chi_t)).rg;
        float texel = tv_.x;
#ifdef DISTRIB
        float spread = tv_.y;
#else
        float spread = 0.0;
#endif
#endif
        OVERLAY_UNDER(acc, off + (k0 + float(i)) * delta, dir, row, delta, texel);   // overlays at this sample
        if (!SAMPLE_OK(texel)) continue;   // non-finite data is transparent
#if defined(MODE_MIP) || defined(MODE_MINIP)
        TAKE_EXT(texel);               // the largest / smallest texel; mapped to a value on the CPU
        hit = true;
#elif defined(MODE_AVERAGE)
        sw += vec2(texel * delta, delta);
#elif defined(MODE_ISO)
        if (texel >= u_iso) {          // the first sample at or above the iso-value
            // the crossing, linear between the sample before (read again: it may lie in the
            // brick before, half a voxel beyond this one's face, or clamped to the volume's edge)
            float prev = sample_texels(tex, slot + clamp((base + (ts - delta) * dir) * isc, clo, chi), its);
            float th = ts;
            if (SAMPLE_OK(prev) && prev < u_iso) th = ts - delta * clamp((texel - u_iso) / (texel - prev), 0.0, 1.0);
            vec3 uh = clamp((base + th * dir) * isc, clo, chi);
            vec3 g = gradient_at(tex, slot, uh, glo, ghi, its, isc, texel);
            float gl = length(g);
            acc = vec4(th, gl > 0.0 ? abs(dot(g, dir)) / gl : 0.0, texel, 1.0);
            break;
        }
#elif defined(MODE_GLSL)
        MODE_TAKE(texel);
#else
#ifdef SHADING
        composite_lit(acc, texel, spread, row, gradient_at(tex, slot, u, glo, ghi, its, isc, texel), dir);
#else
        composite_sample(acc, texel, spread, row);
#endif
        if (acc.a >= u_opaque) break;
#endif
    }
}
#else
// The plain fast path (finite data, no lighting, no overlays): texture coordinates step linearly
// along the ray (one multiply-add per sample), and the clamp to [clo, chi] - which only bites within
// half a voxel of a closed face (the volume's edge, a missing neighbour, a level change) - is paid
// only on the samples outside [ia, ib): the run of samples that lie inside the clamp box on every
// axis, found once per segment. The middle run is then exactly the raw one-texture caster's loop
// (a sample there is the same texture read, clamped or not), which is what makes this path cost what
// a plain caster costs.
#if defined(MODE_MIP) || defined(MODE_MINIP)
#define FAST_TAKE(c) { TAKE_EXT(texture(tex, c).r); hit = true; }
#elif defined(MODE_AVERAGE)
#define FAST_TAKE(c) { sw += vec2(texture(tex, c).r * delta, delta); }
#elif defined(MODE_GLSL)
#define FAST_TAKE(c) { MODE_TAKE(texture(tex, c).r); }
#elif defined(DISTRIB)
#define FAST_TAKE(c) { vec2 v_ = texture(tex, c).rg; composite_sample(acc, v_.x, v_.y, row); if (acc.a >= u_opaque) break; }
#else
#define FAST_TAKE(c) { composite_sample(acc, texture(tex, c).r, 0.0, row); if (acc.a >= u_opaque) break; }
#endif
void march_segment(sampler3D tex, vec3 base, vec3 dir, float off, float k0, int n, float delta, vec3 isc,
                   vec3 its, vec3 slot, vec3 clo, vec3 chi, float row, STATE) {
    vec3 c0 = (slot + (base + (off + k0 * delta) * dir) * isc + 0.5) * its;
    vec3 dc = dir * (delta * isc * its);
    vec3 clo_t = (slot + clo + 0.5) * its;
    vec3 chi_t = (slot + chi + 0.5) * its;
#ifdef EMPTY_SKIP
    // One loop, one cell lookup per SKIP_BLOCK samples: a SIMD rasteriser (llvmpipe) pays for the
    // lookup on every pass whether a lane needs it or not, so in visible space it is amortised over
    // a block of samples (taking samples past a visible cell's exit is always right); an empty
    // cell is leapt from the block's first sample. Whether a sample needs the clamp is not worth
    // finding once samples are leapt.
    // The test that ends the loop comes after the block (a do-while behind a test of n): a loop
    // whose test comes first runs its body once more with every lane masked off before it
    // leaves (llvmpipe executes a masked body, samples and all), and the single pass enters this
    // loop once per node a ray crosses.
    SKIP_SETUP(c0, dc)
    int i = 0;
    if (n > 0) do {
        bool vis_;
        int e_ = cell_exit(i, n, q0_, cs_, ics_, side_, vis_);
        while (!vis_ && e_ < n) {   // leap over a run of empty cells with lookups only
            i = e_;
            e_ = cell_exit(i, n, q0_, cs_, ics_, side_, vis_);
        }
        if (!vis_) break;           // empty to the end of the segment
        FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t));
#if SKIP_BLOCK > 1
        if (i + 1 < n) FAST_TAKE(clamp(c0 + float(i + 1) * dc, clo_t, chi_t));
#endif
#if SKIP_BLOCK > 2
        if (i + 2 < n) FAST_TAKE(clamp(c0 + float(i + 2) * dc, clo_t, chi_t));
#endif
#if SKIP_BLOCK > 3
        if (i + 3 < n) FAST_TAKE(clamp(c0 + float(i + 3) * dc, clo_t, chi_t));
#endif
#if SKIP_BLOCK > 4
        if (i + 4 < n) FAST_TAKE(clamp(c0 + float(i + 4) * dc, clo_t, chi_t));
#endif
#if SKIP_BLOCK > 5
        if (i + 5 < n) FAST_TAKE(clamp(c0 + float(i + 5) * dc, clo_t, chi_t));
#endif
#if SKIP_BLOCK > 6
        if (i + 6 < n) FAST_TAKE(clamp(c0 + float(i + 6) * dc, clo_t, chi_t));
#endif
#if SKIP_BLOCK > 7
        if (i + 7 < n) FAST_TAKE(clamp(c0 + float(i + 7) * dc, clo_t, chi_t));
#endif
    } while ((i += SKIP_BLOCK) < n);     // (the step in the test: a `continue` takes it too)
#else
    // [ia, ib): sample indices whose coordinates lie in [clo_t, chi_t] on every axis, with a margin
    // of 1e-3 sample so that rounding never lets an unclamped sample out of the box
    vec3 idc = safe_inverse(dc);
    vec3 ea = (clo_t - c0) * idc;
    vec3 eb = (chi_t - c0) * idc;
    vec3 emin = min(ea, eb);
    vec3 emax = max(ea, eb);
    float fa = max(max(emin.x, emin.y), emin.z) + 1e-3;
    float fb = min(min(emax.x, emax.y), emax.z) - 1e-3;
    int ia = int(clamp(ceil(fa), 0.0, float(n)));
    int ib = int(clamp(floor(fb) + 1.0, float(ia), float(n)));
    // each run's test after its samples, behind a test of its length (see the EMPTY_SKIP loop:
    // a loop whose test comes first costs one masked sample more per run)
    int i = 0;
    if (i < ia) do FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t)) while (++i < ia);
#ifndef MODE_REDUCE
    if (acc.a >= u_opaque) return;
#endif
    if (i < ib) do FAST_TAKE(c0 + float(i) * dc) while (++i < ib);
#ifndef MODE_REDUCE
    if (acc.a >= u_opaque) return;
#endif
    if (i < n) do FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t)) while (++i < n);
#endif
}
#endif
