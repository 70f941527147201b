"""Coarse rays that carry an uncertainty: does flagging what lies between them cut a refined frame's rays?

A refined frame (:mod:`clipvol.render.refine`) blends a pixel from the four coarser rays around it
where their colours agree; half of the pixels such a blend gets wrong and a ray would fix lie
between four rays that agree (``bench_refine_metric.py``): a thin structure no coarse ray passed
through. This benchmark asks, in numpy on the passes of one read-back frame (no GL change), whether
an *uncertainty* carried by each coarse ray finds them: ``u = sum_i T_i D_i`` along the ray, ``T_i``
the ray's transmittance before sample ``i`` and ``D_i`` the largest change of the transfer
function's opacity (corrected for the step) over the range of values the ray's footprint holds at
that sample. Two ways of knowing that range, both evaluated along the renderer's rays in numpy
(level 0 read whole, trilinear, the setting's step in level-0 voxels):

* ``lateral`` - the values of the ray and of eight lateral sub-rays at the same distance from the
  eye, offset by half the pass's ray spacing (``2**(k - 1)`` pixels for pass ``k``) in x and y: what
  the footprint between this ray and its neighbours holds at that depth;
* ``minmax`` - the value range of the level-0 voxels within a cube of about the footprint's width
  around the sample (``scipy.ndimage`` minimum / maximum filters: a view-independent table, as a
  min/max volume beside each level would be).

Each gives four ``u``: ``sum`` (``sum_i T_i D_i``), ``max`` (``max_i T_i D_i``: the one sample
that could change the pixel most), and ``excess sum`` / ``excess max``, with ``D_i`` replaced by
the range beyond what the ray itself holds within about a footprint in depth (an oblique surface
the ray crosses a little earlier or later is no surprise; a sheet it never reaches is).

The combined mask casts a ray where the four coarser colours differ by more than ``t`` in a
premultiplied channel (today's mask) **or** the largest ``u`` of the four coarser rays exceeds
``tu``; a pixel the 1/2 pass blends carries the blend of its four coarse rays' ``u``, a pixel it
casts its own. It is replayed over ``t`` x ``tu`` exactly as ``bench_refine_metric.replay`` replays
the channel mask (checked against the drawn frame), and each pair gives the rays cast (1/2 + image
pass) and the error against the converged picture (% of pixels CIELUV Delta E >= 6). Printed per
view: the channel mask's curve, the combined mask's lower envelope, the rays each needs for 4 % and
5 %, and what share of the fixable pixels the channel mask blends between agreeing rays (the
oracle's ``missed_spread_under_quarter_tol``) the uncertainty flags. Beside them, the bound of
any mask that knows what lies between the coarse rays (``perfect``: a pixel takes its ray where
that ray differs from its blend by more than ``t`` in a channel, read from the ray itself). The
numpy rays are checked against the frame: their opacity against the read-back 1/4 pass's. The cost of computing ``u`` in
the coarse passes is not counted (the rays are): a mask that does not cut the rays by a quarter
does not pay for any.
Rows: ``tools/bench/results/bench_refine_uncertainty.csv`` (``--out``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_mission  # noqa: E402
import bench_refine_metric as brm  # noqa: E402
import common  # noqa: E402

TOLS = (0.04, 0.08, 0.12, 0.16, 0.24, 0.3, 0.4, 0.5, 0.7, 1.01)
#: the uncertainty tolerances: quantiles of the 1/4 pass's u (the share of coarse rays flagged: 1-50 %)
U_QUANTILES = (0.5, 0.7, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.98, 0.99)
#: the table's bins over the transfer function's window
BINS = 256
RAYS_PER_CHUNK = 1024


def range_table(tf, window, step: float) -> np.ndarray:
    """``R[a, b]`` (``a <= b``, bins of the window): the largest minus the smallest step-corrected
    opacity of the table over bins ``a..b`` (a 2D lookup, what a shader would read)."""
    from clipvol.scene.probe import opacity_of

    lo, hi = (float(v) for v in window)
    vals = lo + (np.arange(BINS) + 0.5) / BINS * (hi - lo)
    a = 1.0 - (1.0 - opacity_of(tf, vals, window)) ** step
    R = np.zeros((BINS, BINS))
    for i in range(BINS):
        R[i, i:] = np.maximum.accumulate(a[i:]) - np.minimum.accumulate(a[i:])
    return R


def _bin(values, window) -> np.ndarray:
    lo, hi = (float(v) for v in window)
    return np.clip(((values - lo) / (hi - lo) * BINS).astype(np.int64), 0, BINS - 1)


def pass_rays(cam, k: int, dx: float = 0.0, dy: float = 0.0):
    """``(origins, unit directions)``, ``(ch, cw, 3)`` rows bottom first: pass ``k``'s rays
    (:meth:`clipvol.render.refine.Refine.coarse_uniforms`: ray ``(i, j)`` through image point
    ``((i + 1/2) 2**k, (j + 1/2) 2**k)`` from the bottom-left corner), shifted by ``(dx, dy)`` pixels."""
    from clipvol.render.refine import Refine

    w, h = (int(v) for v in cam.size)
    cw, ch = Refine.coarse_size(cam, k)
    x = (np.arange(cw) + 0.5) * 2**k + dx
    y = (np.arange(ch) + 0.5) * 2**k + dy
    nx, ny = np.meshgrid(x / w * 2.0 - 1.0, y / h * 2.0 - 1.0)
    f, u, r = (np.asarray(v, dtype=np.float64) for v in cam._fur)
    sx, sy = cam._half_extents()
    off = (nx * sx)[..., None] * r + (ny * sy)[..., None] * u
    if cam.ortho:
        return np.asarray(cam.eye, dtype=np.float64) + off, np.broadcast_to(f, off.shape).copy()
    d = f + off
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.broadcast_to(np.asarray(cam.eye, dtype=np.float64), d.shape).copy(), d


class Uncertainty:
    """``u`` of every ray of a pass, from level 0 of ``pyr`` held whole as ``volume`` (z, y, x)."""

    def __init__(self, volume: np.ndarray, pyr, tf) -> None:
        self.vol = np.asarray(volume, dtype=np.float32)
        self.pyr, self.tf = pyr, tf
        self.window = tf.window(pyr.value_range)
        info = pyr.levels[0]
        self.scale = np.array(info.scale[::-1], dtype=np.float64)
        self.trans = np.array(info.translation[::-1], dtype=np.float64)
        self.box = pyr.volume_box()
        self._minmax: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _sample(self, vol, pts) -> np.ndarray:
        from scipy.ndimage import map_coordinates

        c = ((pts - self.trans) / self.scale)[..., ::-1]  # z, y, x voxel coordinates, centres at integers
        return map_coordinates(vol, c.reshape(-1, 3).T, order=1, mode="nearest").reshape(pts.shape[:-1])

    def minmax(self, width: int):
        if width not in self._minmax:
            from scipy.ndimage import maximum_filter, minimum_filter

            self._minmax[width] = (minimum_filter(self.vol, size=width), maximum_filter(self.vol, size=width))
        return self._minmax[width]

    def footprint_voxels(self, cam, k: int) -> int:
        """About the width in level-0 voxels of pass ``k``'s ray spacing at the volume's centre (odd, >= 3)."""
        lo, hi = self.box
        c = (lo + hi) / 2.0
        px = float(cam.pixels_per_unit(np.array([np.linalg.norm(c - np.asarray(cam.eye))]))[0])
        w = 2**k / max(px, 1e-9) / float(self.scale.min())
        return max(3, 2 * int(round(w / 2)) + 1)

    def of_pass(self, cam, k: int, step: float, how: str) -> dict:
        """``u`` per ray of pass ``k`` (``(ch, cw)``, rows bottom first) at ``step`` level-0 voxels:
        ``{"sum": sum_i T_i D_i, "max": max_i T_i D_i}``, the same of the excess ``E_i`` (the
        footprint's range beyond what the ray itself holds within about a footprint in depth), and
        ``"alpha"``: the ray's own opacity, checked against the read-back pass."""
        o, d = pass_rays(cam, k)
        ch, cw = o.shape[:2]
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        s = 2.0 ** (k - 1)
        subs = [pass_rays(cam, k, dx, dy)[1].reshape(-1, 3) for dx in (-s, 0.0, s) for dy in (-s, 0.0, s)
                if (dx, dy) != (0.0, 0.0)] if how == "lateral" else []
        R = range_table(self.tf, self.window, step)
        from clipvol.scene.probe import opacity_of

        lo, hi = self.box
        dt = step * float(self.scale.min())
        mm = self.minmax(self.footprint_voxels(cam, k)) if how == "minmax" else None
        out = {key: np.zeros(len(o)) for key in ("sum", "max", "excess sum", "excess max", "alpha")}
        # the centre ray's own values within about a footprint in depth: what it already saw nearby
        from scipy.ndimage import maximum_filter1d, minimum_filter1d

        m = 2 * max(1, int(round(self.footprint_voxels(cam, k) / 2 / step))) + 1
        for a in range(0, len(o), RAYS_PER_CHUNK):
            b = min(a + RAYS_PER_CHUNK, len(o))
            oo, dd = o[a:b], d[a:b]
            with np.errstate(divide="ignore", invalid="ignore"):
                ta, tb = (lo - oo) / dd, (hi - oo) / dd
            t0 = np.maximum(np.nanmax(np.minimum(ta, tb), axis=1), 0.0)
            t1 = np.nanmin(np.maximum(ta, tb), axis=1)
            n = np.where(t1 > t0, np.ceil((t1 - t0) / dt), 0).astype(int)
            if n.max() <= 0:
                continue
            i = np.arange(n.max())
            ts = t0[:, None] + (i[None, :] + 0.5) * dt  # (rays, samples)
            inside = i[None, :] < n[:, None]
            pts = oo[:, None, :] + ts[..., None] * dd[:, None, :]
            v = self._sample(self.vol, pts)
            alpha = np.where(inside, 1.0 - (1.0 - opacity_of(self.tf, v, self.window)) ** step, 0.0)
            T = np.cumprod(np.concatenate([np.ones((len(alpha), 1)), 1.0 - alpha[:, :-1]], axis=1), axis=1)
            if how == "lateral":
                vlo, vhi = v.copy(), v.copy()
                for sd in subs:
                    # the sub-ray's point at the same distance from the eye (perspective) or the same depth
                    q = (oo[:, None, :] + ts[..., None] * sd[a:b][:, None, :]) if not cam.ortho else pts
                    vs = self._sample(self.vol, q)
                    vlo, vhi = np.minimum(vlo, vs), np.maximum(vhi, vs)
            else:
                vlo, vhi = self._sample(mm[0], pts), self._sample(mm[1], pts)
            D = R[_bin(vlo, self.window), _bin(vhi, self.window)]
            out["alpha"][a:b] = 1.0 - T[:, -1] * (1.0 - alpha[:, -1])  # the ray's opacity (the check)
            TD = np.where(inside, T * D, 0.0)
            out["sum"][a:b] = TD.sum(axis=1)
            out["max"][a:b] = TD.max(axis=1)
            # the excess: the footprint's range beyond what the centre ray holds within +-m/2 samples
            clo, chi = minimum_filter1d(v, m, axis=1), maximum_filter1d(v, m, axis=1)
            blo, bhi = np.minimum(vlo, clo), np.maximum(vhi, chi)
            E = R[_bin(blo, self.window), _bin(bhi, self.window)] - R[_bin(clo, self.window), _bin(chi, self.window)]
            TE = np.where(inside, T * E, 0.0)
            out["excess sum"][a:b] = TE.sum(axis=1)
            out["excess max"][a:b] = TE.max(axis=1)
        return {key: v.reshape(ch, cw) for key, v in out.items()}


def replay_u(passes, us, tol: float, utol: float):
    """The image the combined mask at ``(tol, utol)`` gives from ``passes`` (1/4, 1/2, image pass
    rays) and ``us`` (``u`` of the 1/4 and 1/2 passes' rays): ``(image, rays per pass, ray masks)``."""
    img, u = passes[0], us[0]
    rays, masks = [], []
    for p, full in enumerate(passes[1:]):
        h, w = full.shape[:2]
        four, weights = brm.corners(img, h, w)
        blend = brm._blend(four, weights)
        (ua, ub, ud, ue), _ = brm.corners(u[..., None], h, w)
        umax = np.maximum(np.maximum(ua, ub), np.maximum(ud, ue))[..., 0]
        ray = (brm.spread("channel", four, None) > tol) | (umax > utol)
        rays.append(int(ray.sum()))
        masks.append(ray)
        img = np.where(ray[..., None], full, blend)
        if p == 0:
            ublend = brm._blend((ua, ub, ud, ue), weights)[..., 0]
            u = np.where(ray, us[1], ublend)
    return img, rays, masks


def replay_perfect(passes, tol: float):
    """The bound of any mask that knows what lies between the coarse rays: a pixel takes its ray
    where the ray differs from the pixel's blend by more than ``tol`` in a premultiplied channel
    (read from the ray itself, which no coarse pass has): ``(image, rays per pass)``."""
    img, rays = passes[0], []
    for full in passes[1:]:
        h, w = full.shape[:2]
        blend = brm._blend(*brm.corners(img, h, w))
        ray = np.abs(full - blend).max(axis=-1) > tol
        rays.append(int(ray.sum()))
        img = np.where(ray[..., None], full, blend)
    return img, rays


PERFECT_TOLS = (0.02, 0.04, 0.06, 0.08, 0.12, 0.16, 0.24, 0.3, 0.4, 0.5, 0.7)


def _envelope(pts) -> np.ndarray:
    """The lower envelope of (rays, error) points: sorted by rays, each point's error the least at
    that many rays or fewer."""
    pts = np.array(sorted(pts))
    return np.column_stack([pts[:, 0], np.minimum.accumulate(pts[:, 1])])


def rays_for(env: np.ndarray, err: float) -> float:
    """The fewest rays of an envelope at which the error is <= ``err`` (linear between its points)."""
    return brm._rays_at(env, err)


def _finite(v: float):
    return round(v) if np.isfinite(v) else ""


def _sweep(passes, us, truth, how: str, ctx: dict, perfect: dict, rows: list, log) -> dict:
    """Replay the combined mask with ``us`` over the tolerances, append its rows to ``rows``, log its
    envelope against the channel mask's, and return the view's summary cells."""
    log(f"  u {how}: 1/4 pass quantiles 50/90/99 %: "
        + ", ".join(f"{q:.3f}" for q in np.quantile(us[0], [0.5, 0.9, 0.99])))
    pts_c, pts_u, own = [], [], []
    for t in TOLS:
        for q, tu in [(q, float(np.quantile(us[0], q))) for q in U_QUANTILES] + [(1.0, np.inf)]:
            out, rays, masks = replay_u(passes, us, t, tu)
            e = brm.pct(out, truth)
            row = dict(date=time.strftime("%Y-%m-%d"), image=ctx["image"], view=ctx["view"], setting=ctx["setting"],
                       how=how, tolerance=t, u_quantile=q, u_tolerance=round(tu, 4), rays_half=rays[0],
                       rays_image=rays[1], rays=sum(rays), pct_de6=round(e, 3),
                       replay_agrees_pct=round(100 * ctx["agree"], 2))
            if t == ctx["tol0"]:
                # the between-agreeing fixable pixels this mask casts (its 1/2 pass may differ)
                row["between_fixable"] = int(ctx["between"].sum())
                row["between_flagged"] = int((ctx["between"] & masks[1]).sum())
                own.append(row)
            rows.append(row)
            if tu == np.inf:
                pts_c.append((sum(rays), e))
            pts_u.append((sum(rays), e))
    env_c, env_u = _envelope(pts_c), _envelope(pts_u)
    line = {err: (rays_for(env_c, err), rays_for(env_u, err)) for err in (3.0, 4.0, 4.5, 5.0)}
    log(f"  {how}: rays for <= 3 / 4 / 4.5 / 5 %: channel " + " / ".join(f"{v[0]:.0f}" for v in line.values())
        + "; combined " + " / ".join(f"{v[1]:.0f}" for v in line.values())
        + "; combined / channel " + " / ".join(f"{v[1] / v[0]:.2f}" for v in line.values()))
    fc, fu = env_c[np.argmin(env_c[:, 1])], env_u[np.argmin(env_u[:, 1])]
    log(f"  {how}: least error: channel {fc[1]:.2f} % at {fc[0]:.0f} rays; combined {fu[1]:.2f} % at {fu[0]:.0f} rays")
    for r in own:
        log(f"    t={r['tolerance']:g} tu={r['u_tolerance']:g} (q {r['u_quantile']:g}): {r['rays']} rays, "
            f"{r['pct_de6']:.2f} %, flags {r['between_flagged']} of {r['between_fixable']} between-agreeing fixable")
    return dict(**{f"channel_rays_{e:g}": _finite(v[0]) for e, v in line.items()},
                **{f"perfect_rays_{e:g}": _finite(v) for e, v in perfect.items()},
                least_channel_pct=round(float(fc[1]), 3), least_channel_rays=int(fc[0]),
                least_combined_pct=round(float(fu[1]), 3), least_combined_rays=int(fu[0]),
                **{f"combined_rays_{e:g}": _finite(v[1]) for e, v in line.items()})


def run(store: Path, images, view_names, names, hows, log=print) -> tuple[list[dict], list[dict]]:
    """Per setting, image size and view: the replay check, the perfect mask's rows, and each
    uncertainty's rows over the tolerances; ``(rows, summary rows)``."""
    from clipvol.scene.metrics import delta_e_luv

    scene = common.WarmScene(store)
    pyr, tf = scene.pyramid, scene.tf
    vol = common.WholeVolume(scene.loader).read_brick(0, (0, 0, 0))
    unc = Uncertainty(vol, pyr, tf)
    conv = scene.converged_pictures()
    rows, summ = [], []
    try:
        for name, kw, tol0, image, view, cam, truth, passes, agree, bg in brm.cases(scene, conv, names, images,
                                                                                    view_names, log):
            level = int(kw.get("level", 0))
            step0 = float(kw["step"]) * 2**level  # in level-0 voxels
            # fixable pixels of the image pass the channel mask blends between agreeing rays
            half, _ = brm.replay(passes[:2], "channel", tol0, bg)
            h, w = passes[2].shape[:2]
            four, weights = brm.corners(half, h, w)
            blend = brm._blend(four, weights)
            de_b = delta_e_luv(brm._u8(blend), truth, premultiplied=False)[::-1]
            de_r = delta_e_luv(brm._u8(passes[2]), truth, premultiplied=False)[::-1]
            fixable = (de_b >= brm.DE_VISIBLE) & (de_r < brm.DE_VISIBLE)
            chan = brm.spread("channel", four, bg)
            between = fixable & (chan <= tol0 / 4)
            pts_p = []
            for t in PERFECT_TOLS:
                out, rays = replay_perfect(passes, t)
                e = brm.pct(out, truth)
                pts_p.append((sum(rays), e))
                rows.append(dict(date=time.strftime("%Y-%m-%d"), image=image, view=view, setting=name,
                                 how="perfect", tolerance=t, rays_half=rays[0], rays_image=rays[1],
                                 rays=sum(rays), pct_de6=round(e, 3), replay_agrees_pct=round(100 * agree, 2)))
            env_p = _envelope(pts_p)
            perfect = {err: rays_for(env_p, err) for err in (3.0, 4.0, 4.5, 5.0)}
            log("  perfect (the ray's own deviation from its blend): rays for <= 3 / 4 / 4.5 / 5 %: "
                + " / ".join(f"{v:.0f}" for v in perfect.values()))
            ctx = dict(image=image, view=view, setting=name, agree=agree, tol0=tol0, between=between)
            for how in hows:
                t_start = time.perf_counter()
                per = [unc.of_pass(cam, k, step0, how) for k in (2, 1)]
                ga = passes[0][..., 3]
                corr = np.corrcoef(per[0]["alpha"].ravel(), ga.ravel())[0, 1]
                log(f"  u {how}: {time.perf_counter() - t_start:.1f} s; the numpy rays against the read-back "
                    f"1/4 pass: opacity correlation {corr:.5f}, mean |difference| "
                    f"{np.abs(per[0]['alpha'] - ga).mean():.4f}")
                for agg in per[0]:
                    if agg != "alpha":
                        us = [p[agg] for p in per]
                        summ.append(dict(image=image, view=view, setting=name, how=f"{how} {agg}",
                                         **_sweep(passes, us, truth, f"{how} {agg}", ctx, perfect, rows, log)))
    finally:
        scene.close()
    return rows, summ


def main(argv: list[str] | None = None) -> int:
    ap = brm.parser(__doc__, "bench_refine_uncertainty.csv")
    ap.add_argument("--how", default="lateral,minmax", help="uncertainty estimates, comma-separated")
    a = ap.parse_args(argv)
    rows, summ = run(a.store, [int(v) for v in a.images.split(",")], a.views.split(","), a.settings.split(","),
                     a.how.split(","))
    brm.write_results(a.out, rows, "summary", summ)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
