"""Which mask predicts the pixels a refined frame's blend gets wrong: a channel spread or a perceptual one?

A refined frame (:mod:`clipvol.render.refine`) blends a pixel from the four coarser rays around it
where they agree to within the tolerance in every premultiplied RGBA channel. The error that
decides is perceptual (% of pixels with CIELUV Delta E >= 6 against the converged picture,
:mod:`clipvol.scene.metrics`, the image composited over its background), so this benchmark asks, in
numpy on read-back passes (no GL change), which spread of the four coarse colours leaves fewer wrong
pixels for the same number of refined rays:

* ``channel`` - the mask's spread today: max over RGBA of (max - min) of the four premultiplied colours;
* ``rgb`` - the same over the four colours composited over the background (alpha counts only through
  what it does to the composited colour);
* ``delta_e`` - the four colours composited over the background as the metric does, in CIELUV,
  their largest pairwise Delta E;
* ``delta_e_blend`` - the largest Delta E of the four composited colours to the pixel's blend.

Per view it draws, at each setting (``--settings``: bench_mission's names), one refined frame at a
tolerance of 1e-7 and reads back its three passes: the 1/4 pass's rays, and the 1/2 and image passes
with a ray at every pixel whose four coarser rays differ at all (the rest are blends of equal
colours: what any mask draws there). A mask at tolerance ``t`` is then replayed in numpy: the 1/2
pass blends where the spread of the 1/4 pass's four rays is at most ``t`` and takes the ray
elsewhere, the image pass likewise from the replayed 1/2 pass (:func:`replay`, the shader's
arithmetic: texel ``floor(x / 2 - 1/4)`` clamped, weights 3/4 and 1/4). Each tolerance gives the rays
cast (1/2 + image pass) and the error of the replayed image against the converged picture; the
replay at the setting's own tolerance is checked against the frame the renderer draws at it.
Rows: ``tools/bench/results/bench_refine_metric.csv`` (``--out``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_mission  # noqa: E402
import common  # noqa: E402

CHANNEL_TOLS = (0.01, 0.02, 0.04, 0.06, 0.08, 0.12, 0.16, 0.24, 0.3, 0.4, 0.5, 0.7)
#: the Delta E tolerance whose replay casts about the rays of each setting's own channel tolerance
DE_AT = {"step=2 refine=0.16": 25.0, "L1 step=1 refine=0.08 dist": 12.0}
#: the Delta E tolerance of a pixel the metric counts as right
DE_VISIBLE = 6.0
DE_TOLS = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 12.0, 16.0, 20.0, 25.0, 30.0, 40.0, 60.0)


def _pass(setup, k: int, camera) -> np.ndarray:
    """Pass ``k``'s premultiplied float image (rows bottom first, GL's order) cropped to its viewport."""
    from clipvol.render.refine import Refine, pass_origin

    w, h = Refine.coarse_size(camera, k)
    target = setup.refine.target(k) if k else setup.target
    ox, oy = pass_origin((w, h)) if k else (0, 0)
    return target.read()[::-1][oy:oy + h, ox:ox + w].astype(np.float64)


def corners(coarse: np.ndarray, h: int, w: int):
    """The four coarse texels around each pixel of an ``h x w`` pass and the bilinear weights, as the
    mask shader fetches them (``c = x / 2 - 1/4``, clamped to the coarse pass)."""
    ch, cw = coarse.shape[:2]
    y = np.arange(h) * 0.5 - 0.25
    x = np.arange(w) * 0.5 - 0.25
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = (y - y0)[:, None, None], (x - x0)[None, :, None]
    ya, yb = np.clip(y0, 0, ch - 1), np.clip(y0 + 1, 0, ch - 1)
    xa, xb = np.clip(x0, 0, cw - 1), np.clip(x0 + 1, 0, cw - 1)
    a, b = coarse[ya][:, xa], coarse[ya][:, xb]
    d, e = coarse[yb][:, xa], coarse[yb][:, xb]
    return (a, b, d, e), (fx, fy)


def _blend(four, weights) -> np.ndarray:
    """The mask's bilinear blend of the four coarse colours (``mix(mix(a, b, fx), mix(d, e, fx), fy)``)."""
    (a, b, d, e), (fx, fy) = four, weights
    return (a * (1 - fx) + b * fx) * (1 - fy) + (d * (1 - fx) + e * fx) * fy


def spread(metric: str, four, background, blend=None) -> np.ndarray:
    """The spread of the four colours per pixel under ``metric``: ``channel`` (premultiplied RGBA),
    ``rgb`` (the composited colour's channels), ``delta_e`` (largest pairwise Delta E of the
    composited colours) or ``delta_e_blend`` (largest Delta E of a composited colour to the blend's)."""
    from clipvol.scene.metrics import composite, rgb_to_luv

    if metric in ("channel", "rgb"):
        s = np.stack(four if metric == "channel" else [composite(c, background[:3]) for c in four])
        return (s.max(axis=0) - s.min(axis=0)).max(axis=-1)
    luv = [rgb_to_luv(composite(c, background[:3], premultiplied=True)) for c in four]
    if metric == "delta_e_blend":
        lb = rgb_to_luv(composite(blend, background[:3], premultiplied=True))
        return np.max([np.linalg.norm(v - lb, axis=-1) for v in luv], axis=0)
    out = np.zeros(four[0].shape[:2])
    for i in range(4):
        for j in range(i + 1, 4):
            out = np.maximum(out, np.linalg.norm(luv[i] - luv[j], axis=-1))
    return out


def replay(passes, metric: str, tol: float, background):
    """The image a mask of ``metric`` at ``tol`` would give from ``passes`` (the 1/4 pass's rays, then
    the 1/2 and image passes' rays everywhere): ``(image, rays cast per pass)``."""
    img = passes[0]
    rays = []
    for full in passes[1:]:
        h, w = full.shape[:2]
        (a, b, d, e), (fx, fy) = corners(img, h, w)
        blend = _blend((a, b, d, e), (fx, fy))
        ray = spread(metric, (a, b, d, e), background, blend) > tol
        rays.append(int(ray.sum()))
        img = np.where(ray[..., None], full, blend)
    return img, rays


def _u8(img_prem: np.ndarray) -> np.ndarray:
    """A replayed pass (premultiplied float, rows bottom first) as a frame returns it: straight RGBA
    uint8, rows top first."""
    from clipvol.render.paths.setup import premultiplied_to_uint8

    return premultiplied_to_uint8(img_prem[::-1].astype(np.float32))


def oracle(passes, tol: float, background, truth: np.ndarray, masks=(("channel", "channel", None),)) -> dict:
    """How well each mask picks the image pass's pixels a ray fixes, the 1/2 pass replayed with the
    channel spread at ``tol``: ``fixable`` pixels have their blend at Delta E >= 6 from the converged
    picture and their ray under 6; the *oracle* casts exactly those rays (its error: ``oracle_pct``,
    the least any mask of the image pass can leave over this 1/2 pass); ``missed``: the fixable
    pixels the channel mask at ``tol`` blends (and how many of them lie between four coarse rays
    that agree to a quarter of ``tol``). For each mask ``(label, metric, t)`` (t None: ``tol``): the image pass's
    rays, how many of them are fixable, and the image's error."""
    from clipvol.scene.metrics import delta_e_luv

    half, _ = replay(passes[:2], "channel", tol, background)
    full = passes[2]
    h, w = full.shape[:2]
    (a, b, d, e), (fx, fy) = corners(half, h, w)
    blend = _blend((a, b, d, e), (fx, fy))
    de_blend = delta_e_luv(_u8(blend), truth, premultiplied=False)[::-1]
    de_ray = delta_e_luv(_u8(full), truth, premultiplied=False)[::-1]
    fixable = (de_blend >= DE_VISIBLE) & (de_ray < DE_VISIBLE)
    chan = spread("channel", (a, b, d, e), background)
    missed = fixable & (chan <= tol)  # a ray would fix them; the channel mask blends them
    out = {"fixable": int(fixable.sum()), "missed": int(missed.sum()),
           "missed_spread_under_quarter_tol": int((missed & (chan <= tol / 4)).sum()),
           "ray_wrong_blend_right": int(((de_ray >= DE_VISIBLE) & (de_blend < DE_VISIBLE)).sum()),
           "oracle_pct": round(pct(np.where(fixable[..., None], full, blend), truth), 3)}
    for label, metric, t in masks:
        t = tol if t is None else t
        ray = spread(metric, (a, b, d, e), background, blend) > t
        out.update({f"{label}_tolerance": t, f"{label}_rays": int(ray.sum()),
                    f"{label}_fixable": int((ray & fixable).sum()),
                    f"{label}_pct": round(pct(np.where(ray[..., None], full, blend), truth), 3)})
    return out


def pct(img_prem: np.ndarray, truth: np.ndarray) -> float:
    """% of pixels at Delta E >= 6 of a replayed pass against ``truth`` (8-bit straight RGBA, rows
    top first), after the 8-bit read-back a frame gets (:func:`_u8`)."""
    from clipvol.scene.metrics import percent_delta_e

    return float(percent_delta_e(_u8(img_prem), truth, threshold=DE_VISIBLE, premultiplied=False))


def setting(name: str) -> tuple[dict, float]:
    """``(action keywords, tolerance)`` of a refined ``bench_mission`` setting (``' dist'``:
    ``classify='distribution'``); the keywords leave the tolerance out."""
    kw = dict(bench_mission.settings()[name.replace(" dist", "")])
    kw.setdefault("step", 0.5)
    if name.endswith(" dist"):
        kw["classify"] = "distribution"
    return kw, float(kw.pop("refine_tolerance"))


def read_passes(probe, own, cam, tf, tolerance: float, bg) -> tuple[list, float]:
    """The three passes of ``probe`` (a tolerance of 1e-7: a ray wherever the coarser rays differ
    at all) read back at ``cam``, and the share of pixels on which the channel mask replayed at
    ``tolerance`` matches the frame ``own`` draws at it (within 2 levels)."""
    own_img = own.render(cam, tf, wait=True, timeout=600)
    probe.render(cam, tf, wait=True, timeout=600)
    passes = [_pass(probe.setup, k, cam) for k in (2, 1, 0)]
    img, _ = replay(passes, "channel", tolerance, bg)
    return passes, float(np.mean(np.abs(_u8(img).astype(int) - own_img.astype(int)).max(axis=-1) <= 2))


def cases(scene, conv, names, images, view_names, log=print):
    """Each setting of ``names`` at each image size and view (of ``view_names``; all where empty),
    its passes read back and replay-checked (:func:`read_passes`): ``(name, kwargs, tolerance,
    image, view, camera, converged picture, passes, agreement, background)``, what the refine
    benchmarks measure over."""
    for name in names:
        kw, tol0 = setting(name)
        probe = scene.action(**kw, refine_tolerance=1e-7)
        own = scene.action(**kw, refine_tolerance=tol0)
        bg = tuple(probe.params.background)
        for image in images:
            for view, cam in bench_mission.views(scene.pyramid, image).items():
                if view_names and view not in view_names:
                    continue
                truth = conv.get(cam, key=(image, view))
                passes, agree = read_passes(probe, own, cam, scene.tf, tol0, bg)
                log(f"{image}^2 {view} {name}: channel replay at {tol0:g} matches the drawn frame on "
                    f"{100 * agree:.2f} % of pixels (within 2 levels)")
                yield name, kw, tol0, image, view, cam, truth, passes, agree, bg


def run(store: Path, images, view_names, names, log=print) -> tuple[list[dict], list[dict]]:
    """Per setting, image size and view: the replay check, the oracle row and each mask's rows."""
    scene = common.WarmScene(store)
    conv = scene.converged_pictures()
    rows, orows = [], []
    try:
        for name, kw, tol0, image, view, cam, truth, passes, agree, bg in cases(scene, conv, names, images,
                                                                                view_names, log):
            o = oracle(passes, tol0, bg, truth,
                       (("channel", "channel", None), ("delta_e", "delta_e", DE_AT.get(name, 16.0)),
                        ("delta_e_six", "delta_e", DE_VISIBLE)))
            log(f"  image pass, 1/2 pass at {tol0:g}: {o}")
            orows.append(dict(image=image, view=view, setting=name, **o))
            for metric, tols in (("channel", CHANNEL_TOLS), ("rgb", CHANNEL_TOLS), ("delta_e", DE_TOLS),
                                 ("delta_e_blend", DE_TOLS)):
                for t in tols:
                    img, rays = replay(passes, metric, t, bg)
                    row = dict(date=time.strftime("%Y-%m-%d"), image=image, view=view, setting=name,
                               metric=metric, tolerance=t, rays_half=rays[0], rays_image=rays[1],
                               rays=sum(rays), pct_de6=round(pct(img, truth), 3),
                               replay_agrees_pct=round(100 * agree, 2))
                    rows.append(row)
                    log(f"  {metric:13} {t:6g}: {row['rays']:6d} rays ({rays[0]} + {rays[1]}), "
                        f"{row['pct_de6']:6.2f} % dE>=6")
    finally:
        scene.close()
    return rows, orows


def _err_at(pts: np.ndarray, n: float) -> float:
    """The error of a (rays, error) curve at ``n`` rays, linear between its tolerances."""
    return float(np.interp(n, pts[:, 0], pts[:, 1]))


def _rays_at(pts: np.ndarray, e: float) -> float:
    """The fewest rays at which a (rays, error) curve, followed from few rays up, reaches error ``e``."""
    for (n0, e0), (n1, e1) in zip(pts[:-1], pts[1:]):
        if e0 <= e:
            return float(n0)
        if e1 <= e:
            return float(n0 + (e0 - e) / (e0 - e1) * (n1 - n0))
    return float("nan")


def summary(rows: list[dict], log=print) -> None:
    """Per image, view and setting, at the rays the channel mask casts at tolerances 0.08-0.24: each
    other mask's error at the same rays, and the fewest rays it needs for the channel mask's error
    over the fewest the channel mask needs for it."""
    for key in sorted({(int(r["image"]), r["view"], r["setting"]) for r in rows}):
        rs = [r for r in rows if (int(r["image"]), r["view"], r["setting"]) == key]
        metrics = list(dict.fromkeys(r["metric"] for r in rs))
        curve = {m: np.array(sorted((int(r["rays"]), float(r["pct_de6"])) for r in rs if r["metric"] == m))
                 for m in metrics}
        log(f"{key[0]}^2 {key[1]} {key[2]}: at the channel mask's rays, each mask's error / rays for its error")
        for r in rs:
            if r["metric"] != "channel" or float(r["tolerance"]) not in (0.08, 0.12, 0.16, 0.24):
                continue
            n, e = int(r["rays"]), float(r["pct_de6"])
            own = _rays_at(curve["channel"], e)  # the error falls and rises again with the rays at step 2
            cells = [f"{m} {_err_at(curve[m], n):.2f} % / {_rays_at(curve[m], e) / own:.2f}x" for m in metrics[1:]]
            log(f"  channel {float(r['tolerance']):g}: {n} rays, {e:.2f} % | " + "; ".join(cells))


def parser(doc: str, out: str) -> argparse.ArgumentParser:
    """The refine benchmarks' flags: ``--store``, ``--images``, ``--views``, ``--settings``, and
    ``--out`` (default ``results/OUT``)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--store", type=Path, required=True, help="a clipvol store (e.g. the MNI template at 32^3 bricks)")
    ap.add_argument("--images", default="256", help="image sizes, comma-separated (default 256)")
    ap.add_argument("--views", default="iso,face", help="views of bench_mission, comma-separated (default iso,face)")
    ap.add_argument("--settings", default="step=2 refine=0.16,L1 step=1 refine=0.08 dist",
                    help="bench_mission refined settings, comma-separated (' dist': classify='distribution')")
    ap.add_argument("--out", type=Path, default=HERE / "results" / out)
    return ap


def write_results(out: Path, rows: list[dict], beside: str, more: list[dict]) -> None:
    """The refine benchmarks' rows to ``out`` and a second table to ``<out>_<beside>.csv``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    common.write_rows(out, rows)
    common.write_rows(out.with_name(f"{out.stem}_{beside}.csv"), more)
    print(f"rows: {out}")


def main(argv: list[str] | None = None) -> int:
    a = parser(__doc__, "bench_refine_metric.csv").parse_args(argv)
    rows, orows = run(a.store, [int(v) for v in a.images.split(",")], a.views.split(","), a.settings.split(","))
    summary(rows)
    write_results(a.out, rows, "oracle", orows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
