"""An independent numpy ray caster: the reference the GL renderer is tested against.

It shares nothing with ``clipvol.render`` but the camera's rays (``Camera.rays``) and the
transfer function's table: its own box intersection, sample lattice, trilinear sampling of a
plain array with clamp-to-edge, table lookup (``GL_LINEAR`` with texel centres at
``(i + 0.5) / n``), opacity correction and front-to-back premultiplied compositing.

Lattice (the renderer's contract): samples at ``t = k * delta`` along each ray, ``k`` integer,
inside the half-open interval ``[t_entry, t_exit)`` of the ray with the volume box; ``t`` is the
distance from the eye (perspective, ``t >= 0``) or from the plane through the camera centre
perpendicular to the view (orthographic, any sign). Trilinear sampling is over the finite voxels
only (weights renormalised); a sample with no finite voxel of non-zero weight is transparent.
"""

from __future__ import annotations

import numpy as np

__all__ = ["trilinear", "gradient_field", "light", "tf_lookup", "correct_opacity", "raycast", "raycast_levels",
           "raycast_overlays", "to_uint8"]


#: per-axis fraction within which a sample counts as on a voxel centre (NaN-aware filtering)
SNAP = 1.0 / 4096.0


def trilinear(vol: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Sample ``vol`` ``(z, y, x)`` at voxel coordinates ``u`` ``(..., 3)`` ``(x, y, z)`` (centres at integers).

    Clamp-to-edge outside ``[0, n - 1]``; computed in float64. NaN-aware: non-finite voxels are
    left out and the weights of the finite ones renormalised, so a sample is NaN only where every
    voxel of non-zero weight is non-finite. Fractions within ``SNAP`` of a voxel centre snap to it
    (the renderer's contract: float32 positions of a sample meant to be at a centre are a few
    1e-6 voxel off, and a renormalised weight of 1e-6 would otherwise hand a NaN voxel's centre
    its neighbour's value).
    """
    v = np.asarray(vol, dtype=np.float64)
    n = np.array(v.shape[::-1], dtype=np.float64)  # (x, y, z)
    u = np.clip(u, 0.0, n - 1.0)
    i0 = np.minimum(np.floor(u), np.maximum(n - 2.0, 0.0)).astype(np.int64)
    f = u - i0
    f = np.where(f < SNAP, 0.0, np.where(f > 1.0 - SNAP, 1.0, f))  # a centre sample stays one
    i1 = np.minimum(i0 + 1, (n - 1).astype(np.int64))
    total = 0.0
    weight = 0.0
    for dz in (0, 1):
        wz = f[..., 2] if dz else 1.0 - f[..., 2]
        iz = i1[..., 2] if dz else i0[..., 2]
        for dy in (0, 1):
            wy = f[..., 1] if dy else 1.0 - f[..., 1]
            iy = i1[..., 1] if dy else i0[..., 1]
            for dx in (0, 1):
                wx = f[..., 0] if dx else 1.0 - f[..., 0]
                ix = i1[..., 0] if dx else i0[..., 0]
                x = v[iz, iy, ix]
                w = np.where(np.isfinite(x) & (wz * wy * wx > 0), wz * wy * wx, 0.0)
                total = total + w * np.where(w > 0, x, 0.0)
                weight = weight + w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight > 0, total / np.where(weight > 0, weight, 1.0), np.nan)


def tf_lookup(table: np.ndarray, t: np.ndarray) -> np.ndarray:
    """RGBA of a table ``(n, 4)`` at ``t`` (clamped to [0, 1]) as a ``GL_LINEAR`` texture gives it."""
    tab = np.asarray(table, dtype=np.float64)
    n = len(tab)
    x = np.clip(t, 0.0, 1.0) * n - 0.5
    i = np.floor(x)
    f = (x - i)[..., None]
    i0 = np.clip(i, 0, n - 1).astype(np.int64)
    i1 = np.clip(i + 1, 0, n - 1).astype(np.int64)
    return tab[i0] * (1.0 - f) + tab[i1] * f


def correct_opacity(a: np.ndarray, ratio: float) -> np.ndarray:
    """``1 - (1 - a) ** ratio``, written with log1p/expm1."""
    a = np.clip(a, 0.0, 1.0)
    with np.errstate(divide="ignore"):
        return np.where(a >= 1.0, 1.0, -np.expm1(ratio * np.log1p(-np.minimum(a, 1.0 - 1e-300))))


def _rays(camera):
    o, d = camera.rays()
    o = o.reshape(-1, 3).astype(np.float64)
    d = d.reshape(-1, 3).astype(np.float64)
    if camera.orthographic:  # lattice origin: the plane through the centre
        c = np.asarray(camera.center, dtype=np.float64)
        o = o + d * ((c - o) * d).sum(axis=1, keepdims=True)
    return o, d


def _box_interval(o, d, lo, hi, ortho):
    with np.errstate(divide="ignore", invalid="ignore"):
        dd = np.where(d == 0, 1e-300, d)
        ta = (lo - o) / dd
        tb = (hi - o) / dd
    t0 = np.minimum(ta, tb).max(axis=1)
    t1 = np.maximum(ta, tb).min(axis=1)
    if not ortho:
        t0 = np.maximum(t0, 0.0)
    return t0, t1


def _clip_to_shape(o, d, t0, t1, shape):
    """Narrow ``[t0, t1)`` to a shape ``(box_lo, box_hi, planes)`` (box may be None; planes ``(a, b, c, d)``)."""
    if shape is None:
        return t0, t1
    box_lo, box_hi, planes = shape
    if box_lo is not None:
        s0, s1 = _box_interval(o, d, np.asarray(box_lo, float), np.asarray(box_hi, float), True)
        t0, t1 = np.maximum(t0, s0), np.minimum(t1, s1)
    for a, b, c, e in planes:
        n = np.array([a, b, c], dtype=np.float64)
        nd = d @ n
        no = o @ n + e
        with np.errstate(divide="ignore", invalid="ignore"):
            th = -no / nd
        t0 = np.where(nd > 0, np.maximum(t0, th), t0)
        t1 = np.where(nd < 0, np.minimum(t1, th), t1)
        t1 = np.where((nd == 0) & (no < 0), -np.inf, t1)
    return t0, t1


def raycast(vol, spacing, camera, table, value_range, step: float = 0.5, mode: str = "composite", shape=None,
            origin=(0.0, 0.0, 0.0), lighting=None):
    """Reference render of a level-0 volume; returns premultiplied float RGBA ``(h, w, 4)``.

    ``spacing`` ``(z, y, x)``; ``value_range`` the transfer function's window ``(lo, hi)``;
    ``step`` in level-0 smallest voxels. ``mode`` ``"mip"`` returns the TF of the maximum.
    ``shape``: ``(box_lo, box_hi, planes)`` clipping the rays. ``origin``: world ``(x, y, z)`` of
    ``vol``'s first voxel (a sub-volume of a larger one); the drawn box is then ``vol``'s own cells.
    ``lighting``: ``(ambient, diffuse, specular, shininess)`` for gradient lighting (see
    :func:`gradient_field`, :func:`light`), or None.
    """
    sp = np.asarray(spacing, dtype=np.float64)[::-1]
    n = np.array(vol.shape[::-1], dtype=np.float64)
    org = np.asarray(origin, dtype=np.float64)
    return raycast_levels([(vol, sp, org)], [(0, org - 0.5 * sp, org + (n - 0.5) * sp)], camera, table,
                          value_range, step, mode, float(sp.min()), shape, lighting)


def gradient_field(vol: np.ndarray, scale) -> np.ndarray:
    """World gradient ``(z, y, x, 3)`` ``(gx, gy, gz)`` of ``vol`` at its voxels: central differences
    over the whole array, edges replicated (``np.pad(mode="edge")``), divided by the voxel size
    ``scale`` ``(x, y, z)``. Trilinear interpolation of this field at ``u`` equals the difference
    of the clamped-trilinear data at ``u`` +- one voxel, halved (interpolation commutes with
    integer shifts), which is how the renderer defines a sample's gradient."""
    v = np.pad(np.asarray(vol, dtype=np.float64), 1, mode="edge")
    gx = (v[1:-1, 1:-1, 2:] - v[1:-1, 1:-1, :-2]) / (2.0 * scale[0])
    gy = (v[1:-1, 2:, 1:-1] - v[1:-1, :-2, 1:-1]) / (2.0 * scale[1])
    gz = (v[2:, 1:-1, 1:-1] - v[:-2, 1:-1, 1:-1]) / (2.0 * scale[2])
    return np.stack([gx, gy, gz], axis=-1)


def light(rgb: np.ndarray, g: np.ndarray, d: np.ndarray, lighting) -> np.ndarray:
    """Blinn-Phong with the light at the eye (light = view = half vector = -d), two-sided:
    ``min(rgb * (ka + kd * c) + ks * c ** n, 1)`` with ``c = |g . d| / |g|`` (0 where g = 0)."""
    ka, kd, ks, n = lighting
    gl = np.linalg.norm(g, axis=-1)
    c = np.where(gl > 0, np.abs((g * d).sum(-1)) / np.where(gl > 0, gl, 1.0), 0.0)
    return np.minimum(rgb * (ka + kd * c)[:, None] + (ks * c**n)[:, None], 1.0)


def raycast_levels(levels, regions, camera, table, value_range, step, mode="composite", ref_spacing=None, shape=None,
                   lighting=None):
    """Reference render of a multi-level cut.

    ``levels``: per level ``(array (z, y, x), scale (x, y, z), translation (x, y, z))``;
    ``regions``: ``(level, lo, hi)`` world boxes tiling the drawn space (no overlaps). Each
    region is sampled from its level with that level's spacing ``step * min(scale)``; samples of
    all regions are sorted by ``t`` per pixel and composited front to back.
    """
    w, h = camera.size
    o, d = _rays(camera)
    npix = len(o)
    lo_v, hi_v = value_range
    pix_l, t_l, val_l, grad_l, dir_l = [], [], [], [], []
    ratio_of = {}
    for L, lo, hi in regions:
        arr, scale, trans = levels[L]
        delta = step * float(np.min(scale))
        ratio_of[L] = delta / (ref_spacing if ref_spacing else float(np.min(levels[0][1])))
        t0, t1 = _box_interval(o, d, np.asarray(lo, float), np.asarray(hi, float), camera.orthographic)
        t0, t1 = _clip_to_shape(o, d, t0, t1, shape)
        k0 = np.ceil(t0 / delta)
        k1 = np.ceil(t1 / delta) - 1
        hit = np.nonzero(k1 >= k0)[0]
        if not len(hit):
            continue
        cnt = (k1[hit] - k0[hit] + 1).astype(np.int64)
        pix = np.repeat(hit, cnt)
        start = np.repeat(np.cumsum(cnt) - cnt, cnt)
        k = np.repeat(k0[hit], cnt) + (np.arange(cnt.sum()) - start)
        t = k * delta
        p = o[pix] + t[:, None] * d[pix]
        u = (p - np.asarray(trans)) / np.asarray(scale)
        pix_l.append(pix)
        t_l.append(t)
        val_l.append((trilinear(arr, u), np.full(len(t), L)))
        if lighting is not None:
            gf = gradient_field(arr, scale)
            grad_l.append(np.stack([trilinear(gf[..., a], u) for a in range(3)], axis=-1))
            dir_l.append(d[pix])
    img = np.zeros((npix, 4))
    if not pix_l:
        return img.reshape(h, w, 4)
    pix = np.concatenate(pix_l)
    t = np.concatenate(t_l)
    val = np.concatenate([v for v, _ in val_l])
    lev = np.concatenate([lv for _, lv in val_l])
    ok = np.isfinite(val)
    pix, t, val, lev = pix[ok], t[ok], val[ok], lev[ok]
    if lighting is not None and mode != "mip":
        grad = np.concatenate(grad_l)[ok]
        dirs = np.concatenate(dir_l)[ok]
    if mode == "mip":
        m = np.full(npix, -np.inf)
        np.maximum.at(m, pix, val)
        hit = np.isfinite(m)
        tt = (m[hit] - lo_v) / (hi_v - lo_v) if hi_v > lo_v else np.full(hit.sum(), 0.5)
        rgba = tf_lookup(table, tt)
        img[hit, :3] = rgba[:, :3] * rgba[:, 3:4]
        img[hit, 3] = rgba[:, 3]
        return img.reshape(h, w, 4)
    order = np.lexsort((t, pix))
    pix, t, val, lev = pix[order], t[order], val[order], lev[order]
    tt = (val - lo_v) / (hi_v - lo_v) if hi_v > lo_v else np.full(len(val), 0.5)
    rgba = tf_lookup(table, tt)
    if lighting is not None:
        rgba[:, :3] = light(rgba[:, :3], grad[order], dirs[order], lighting)
    ratio = np.vectorize(ratio_of.get)(lev) if len(lev) else lev
    a = correct_opacity(rgba[:, 3], ratio)
    # transmittance before each sample, per pixel: exclusive cumulative product within the pixel's run
    log1m = np.log1p(-np.minimum(a, 1.0 - 1e-15))
    cs = np.cumsum(log1m)
    first = np.r_[True, pix[1:] != pix[:-1]]
    run_start = np.maximum.accumulate(np.where(first, np.arange(len(pix)), 0))
    before = cs - log1m - np.where(run_start > 0, cs[run_start - 1], 0.0)
    T = np.exp(before)
    contrib = T * a
    np.add.at(img[:, 3], pix, contrib)
    for c in range(3):
        np.add.at(img[:, c], pix, contrib * rgba[:, c])
    return img.reshape(h, w, 4)


def classified_overlay(m, spacing, origin, table, value_range):
    """A map sampled classified first, as a ``("rgba", fn)`` layer of :func:`raycast_overlays`: per
    voxel its table colour (opacity corrected for the step, non-finite voxels transparent),
    premultiplied, each channel interpolated by scipy's ``map_coordinates`` (linear, edge values
    beyond the outer voxel centres) at the samples, the straight colour divided back out;
    transparent outside the cells ``[-0.5, n - 0.5]``. ``spacing``, ``origin``: (z, y, x), as the
    overlays of :func:`raycast_overlays`."""
    from scipy.ndimage import map_coordinates

    lo, hi = value_range
    m = np.asarray(m, dtype=np.float64)
    osp = np.asarray(spacing, dtype=np.float64)[::-1]
    org = np.asarray(origin, dtype=np.float64)[::-1]
    n = np.array(m.shape[::-1], dtype=np.float64)

    def fn(p, ratio):
        rgba = tf_lookup(table, (np.nan_to_num(m) - lo) / (hi - lo))
        a = np.where(np.isfinite(m), correct_opacity(rgba[..., 3], ratio), 0.0)
        u = (p - org) / osp  # (x, y, z) voxel coordinates
        at = u[:, ::-1].T
        pm = [map_coordinates(rgba[..., c] * a, at, order=1, mode="nearest") for c in range(3)]
        A = map_coordinates(a, at, order=1, mode="nearest")
        rgb = np.stack(pm, axis=1) / np.maximum(A, 1e-300)[:, None]
        return np.concatenate([rgb, A[:, None]], axis=1), np.all((u >= -0.5) & (u <= n - 0.5), axis=1)

    return ("rgba", fn)


def raycast_overlays(vol, spacing, camera, table, value_range, overlays, step: float = 0.5, blend: str = "over"):
    """Reference render of a level-0 volume with co-registered overlays; premultiplied float RGBA ``(h, w, 4)``.

    ``overlays``: ``(array (z, y, x), spacing (z, y, x), origin (z, y, x), table, value_range)``,
    ``origin`` the world position of the overlay's voxel 0 in the primary's frame (the primary's
    voxel 0 at 0). At every sample of the primary's lattice (as :func:`raycast`) each overlay is
    sampled at the same world point with scipy's ``map_coordinates`` (linear, edge values beyond the
    outer voxel centres), transparent outside its cells ``[-0.5, n - 0.5]``; its colour comes from
    its own table and window, its opacity corrected like the primary's (per the primary's smallest
    level-0 voxel). The sample's colour is the overlays' premultiplied colours over the primary's
    (the first overlay on top), composited front to back.

    A label overlay is ``("labels", array (z, y, x) of ints, spacing, origin, rgba)``, ``rgba`` a
    function from an int array of ids to their straight RGBA ``(n, 4)``: each sample takes the id
    of the voxel whose cell holds the point (``floor(u + 0.5)``, never interpolated).

    A sampled overlay is ``("rgba", fn)``: ``fn(p, ratio)`` gives, at the samples ``p`` ``(n, 3)``
    (x, y, z in the primary's frame), their straight RGBA ``(n, 4)`` with the opacity already
    corrected for the step ``ratio``, and a mask of the samples inside it (e.g. a map whose voxels
    are classified first, then interpolated).

    ``blend="additive"`` (channels): a sample's colour is the sum of every layer's premultiplied
    colour (the primary's included), its opacity ``1 - prod(1 - a)``.
    """
    from scipy.ndimage import map_coordinates

    sp = np.asarray(spacing, dtype=np.float64)[::-1]
    n = np.array(vol.shape[::-1], dtype=np.float64)
    lo, hi = -0.5 * sp, (n - 0.5) * sp
    w, h = camera.size
    o, d = _rays(camera)
    npix = len(o)
    delta = step * float(sp.min())
    ratio = delta / float(sp.min())
    t0, t1 = _box_interval(o, d, lo, hi, camera.orthographic)
    k0 = np.ceil(t0 / delta)
    k1 = np.ceil(t1 / delta) - 1
    hit = np.nonzero(k1 >= k0)[0]
    img = np.zeros((npix, 4))
    if not len(hit):
        return img.reshape(h, w, 4)
    cnt = (k1[hit] - k0[hit] + 1).astype(np.int64)
    pix = np.repeat(hit, cnt)
    start = np.repeat(np.cumsum(cnt) - cnt, cnt)
    t = (np.repeat(k0[hit], cnt) + (np.arange(cnt.sum()) - start)) * delta
    p = o[pix] + t[:, None] * d[pix]
    # the layers of each sample, top first: the overlays, then the primary
    layers = []  # (straight RGBA per sample, inside its box)
    corrected = set()  # layers whose opacity their sampler corrected
    for ov in overlays:
        if isinstance(ov[0], str) and ov[0] == "rgba":
            corrected.add(len(layers))
            layers.append(ov[1](p, ratio))
            continue
        labels = isinstance(ov[0], str) and ov[0] == "labels"
        ovol, osp, oorg = ov[1:4] if labels else ov[:3]
        osp = np.asarray(osp, dtype=np.float64)[::-1]
        on = np.array(ovol.shape[::-1], dtype=np.float64)
        u = (p - np.asarray(oorg, dtype=np.float64)[::-1]) / osp  # (x, y, z) voxel coordinates
        inside = np.all((u >= -0.5) & (u <= on - 0.5), axis=1)
        if labels:
            q = np.minimum(np.floor(u + 0.5), on - 1).astype(np.int64)
            q = np.maximum(q, 0)
            ids = np.asarray(ovol)[q[:, 2], q[:, 1], q[:, 0]]
            layers.append((ov[4](ids), inside))
        else:
            otab, (vlo, vhi) = ov[3], ov[4]
            v = map_coordinates(np.asarray(ovol, dtype=np.float64), u[:, ::-1].T, order=1, mode="nearest")
            layers.append((tf_lookup(otab, (v - vlo) / (vhi - vlo)), inside & np.isfinite(v)))
    vlo, vhi = value_range
    v = trilinear(vol, p / sp)
    layers.append((tf_lookup(table, (v - vlo) / (vhi - vlo)), np.isfinite(v)))
    C = np.zeros((len(p), 3))
    A = np.zeros(len(p))
    T = np.ones(len(p))
    for k, (rgba, inside) in enumerate(layers):  # per sample: "under" each layer, top first (or their sum)
        a = np.where(inside, rgba[:, 3] if k in corrected else correct_opacity(rgba[:, 3], ratio), 0.0)
        if blend == "additive":
            C += a[:, None] * rgba[:, :3]
            T *= 1.0 - a
            A = 1.0 - T
        else:
            C += ((1.0 - A) * a)[:, None] * rgba[:, :3]
            A += (1.0 - A) * a
    order = np.lexsort((t, pix))
    pix, C, A = pix[order], C[order], A[order]
    log1m = np.log1p(-np.minimum(A, 1.0 - 1e-15))
    cs = np.cumsum(log1m)
    first = np.r_[True, pix[1:] != pix[:-1]]
    run_start = np.maximum.accumulate(np.where(first, np.arange(len(pix)), 0))
    T = np.exp(cs - log1m - np.where(run_start > 0, cs[run_start - 1], 0.0))
    np.add.at(img[:, 3], pix, T * A)
    for c in range(3):
        np.add.at(img[:, c], pix, T * C[:, c])
    return img.reshape(h, w, 4)


def to_uint8(prem: np.ndarray) -> np.ndarray:
    """Premultiplied float RGBA -> straight RGBA uint8 (colour 0 where the 8-bit alpha is 0)."""
    a = np.clip(prem[..., 3], 0.0, 1.0)
    rgb = np.where(np.rint(a[..., None] * 255.0) > 0, prem[..., :3] / np.maximum(a[..., None], 1e-300), 0.0)
    return np.rint(np.concatenate([np.clip(rgb, 0, 1), a[..., None]], axis=-1) * 255.0).astype(np.uint8)
