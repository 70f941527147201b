"""Consistent coarse levels (issue 41): error against the converged picture, frame cost, store size.

For a store built by ``clipvol brick`` (which writes each coarse level's spread beside it), under a
sharp transfer function (``bone`` by default), per view:

* the **converged picture**: level 0 at step 0.25, rendered at twice the size and box-filtered 2x2
  (premultiplied colour averaged);
* each fixed level 0, 1, 2 (step 0.5) classified by its mean (``classify="mean"``, what every level
  did before) and by its distribution (``classify="distribution"``, both distribution models of
  :mod:`clipvol.scene.consistent`): % of pixels with CIELUV Delta E >= 6 against the converged picture
  (:func:`clipvol.scene.metrics.percent_delta_e`), and level 0's own error beside them;
* the projected-size policy at ``lod_threshold`` 1, 2 and 4 with either classification: error and
  frame time, to see whether a coarser threshold keeps the error of the default;
* frame cost: ``classify="distribution"`` over ``"mean"`` at the same cut (fixed level 1, and the
  projected-size cut), warm, interleaved rounds, median ratio;
* store size: the spread arrays' bytes against the levels' bytes, per level; build cost: the
  spread's moments over the whole volume against the mean filter's own time (pure numpy, one run).

Usage::

    python tools/bench/bench_consistent.py /tmp/h3/mni.zarr --size 256 --rounds 3

Rows go to ``tools/bench/results/bench_consistent.csv`` (``--out``); a summary is printed.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from clipvol.bricking.pyramid import downsample
from clipvol.bricking.spread import SPREAD_GROUP, moments_down, spread_of
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.open import open_store
from clipvol.render import create_context
from clipvol.render.action import ClipRenderAction
from clipvol.scene import consistent
from clipvol.scene.metrics import percent_delta_e
from clipvol.scene.transfer import TransferFunction
from clipvol.scene.views import view_camera

HERE = Path(__file__).resolve().parent
VIEWS = {"front": None, "side": None, "front-close": 0.9}  # name -> distance in diagonals (None: default)


def _dir_bytes(p: Path) -> int:
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())


def _premultiplied(img: np.ndarray) -> np.ndarray:
    f = img.astype(np.float64) / 255.0
    return np.concatenate([f[..., :3] * f[..., 3:4], f[..., 3:4]], axis=-1)


def _box2(prem: np.ndarray) -> np.ndarray:
    h, w = prem.shape[0] // 2, prem.shape[1] // 2
    return prem[: 2 * h, : 2 * w].reshape(h, 2, w, 2, 4).mean(axis=(1, 3))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("store", help="a store built by clipvol brick (with the spread arrays)")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--tf", default="bone")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--views", default=",".join(VIEWS))
    ap.add_argument("--out", default=str(HERE / "results" / "bench_consistent.csv"))
    ap.add_argument("--build", default=None, metavar="SOURCE",
                    help="also time clipvol's build of SOURCE with and without the spread (interleaved, 2 rounds each)")
    ap.add_argument("--no-render", action="store_true", help="storage and build cost only")
    args = ap.parse_args(argv)
    store = Path(args.store)
    load = os.getloadavg()[0]
    rows: list[dict] = []

    # -- store size and build cost ------------------------------------------------------------
    loader = open_store(store)
    pyr = loader.pyramid
    levels = sum(_dir_bytes(store / str(L)) for L in range(pyr.num_levels))
    spread = _dir_bytes(store / SPREAD_GROUP) if (store / SPREAD_GROUP).is_dir() else 0
    for L in range(pyr.num_levels):
        sp = _dir_bytes(store / SPREAD_GROUP / str(L)) if (store / SPREAD_GROUP / str(L)).is_dir() else 0
        rows.append(dict(kind="storage", view="", level=L, setting="bytes", value=_dir_bytes(store / str(L)), other=sp))
    print(f"store {store}: levels {levels} B, spread {spread} B: +{100.0 * spread / max(levels, 1):.1f} % "
          f"(spread levels {loader.spread_levels})")
    rows.append(dict(kind="storage", view="", level=-1, setting="growth_pct",
                     value=round(100.0 * spread / max(levels, 1), 2), other=spread))
    vol = np.asarray(__import__("zarr").open_array(str(store / "0"), mode="r")[...])
    t0 = time.perf_counter()
    d = vol
    for _ in range(pyr.num_levels - 1):
        d = downsample(d, "mean")
    t_mean = time.perf_counter() - t0
    t0 = time.perf_counter()
    d, m1, m2 = vol, None, None
    for _ in range(pyr.num_levels - 1):
        m1, m2 = moments_down(d, m1, m2)
        spread_of(m1, m2, vol.dtype)
        d = downsample(d, "mean")
    t_both = time.perf_counter() - t0
    print(f"build: mean filter {t_mean * 1e3:.0f} ms, with the spread's moments {t_both * 1e3:.0f} ms "
          f"({t_both / t_mean:.2f}x the mean filter alone)")
    rows.append(dict(kind="build", view="", level=-1, setting="spread_over_mean_filter", value=round(t_both / t_mean, 3),
                     other=round(t_mean, 4)))

    if args.build:
        import tempfile

        from clipvol.bricking import pipeline

        spans: dict[bool, list[float]] = {True: [], False: []}
        keep = pipeline.with_spread
        with tempfile.TemporaryDirectory() as tmp:
            for r in range(2):
                for on in (True, False):
                    pipeline.with_spread = keep if on else (lambda pyramid: False)
                    out = Path(tmp) / f"b{r}{int(on)}.zarr"
                    t0 = time.perf_counter()
                    pipeline.brick_volume(args.build, out, brick=pyr.brick_shape[0], progress=False)
                    spans[on].append(time.perf_counter() - t0)
            pipeline.with_spread = keep
        b_on, b_off = statistics.median(spans[True]), statistics.median(spans[False])
        print(f"build of {args.build}: {b_on:.2f} s with the spread, {b_off:.2f} s without ({b_on / b_off:.2f}x)")
        rows.append(dict(kind="build", view="", level=-1, setting="brick_with_over_without", value=round(b_on / b_off, 3),
                         other=round(b_off, 3)))
    if args.no_render:
        return _save(rows, load, args.out)

    # -- error and frame cost ------------------------------------------------------------------
    ctx = create_context()
    tf = TransferFunction.preset(args.tf)
    size = (args.size, args.size)
    with ClipTexture(loader, "1GB", threads=2) as clip:
        def action(**kw):
            return ClipRenderAction(ctx, clip, texture_budget="1GB", **kw)

        for view in args.views.split(","):
            dist = VIEWS.get(view)
            base = view.replace("-close", "")
            cam = view_camera(pyr, base, size, distance=dist)
            cam2 = view_camera(pyr, base, (2 * size[0], 2 * size[1]), distance=dist)
            a = action(policy="fixed", level=0, step=0.25)
            conv = _box2(_premultiplied(a.render(cam2, tf, wait=True, timeout=120)))
            a.close()

            def err(img):
                return round(percent_delta_e(_premultiplied(img), conv, threshold=6.0), 3)

            settings = [("L0", dict(policy="fixed", level=0), "mean")]
            for L in (1, 2):
                settings += [(f"L{L}", dict(policy="fixed", level=L), c) for c in ("mean", "normal", "two-point")]
            for thr in (1.0, 2.0, 4.0):
                settings += [(f"ps{thr:g}", dict(lod_threshold=thr), c) for c in ("mean", "normal")]
            acts = {}
            for name, kw, c in settings:
                classify = "mean" if c == "mean" else "distribution"
                acts[(name, c)] = (action(classify=classify, **kw), c)
            times: dict = {k: [] for k in acts}
            errs: dict = {}
            for r in range(args.rounds + 1):  # round 0 warms (loads, uploads, compiles)
                for k, (a, c) in acts.items():
                    if c != "mean":
                        consistent.MODEL = c
                    t0 = time.perf_counter()
                    img = a.render(cam, tf, wait=True, timeout=120)
                    dt = time.perf_counter() - t0
                    consistent.MODEL = "normal"
                    if r == 0:
                        errs[k] = err(img)
                    else:
                        times[k].append(a.last_frame_stats.times.get("draw", dt) if hasattr(a.last_frame_stats, "times") else dt)
            for k, (a, c) in acts.items():
                a.close()
            med = {k: statistics.median(v) for k, v in times.items()}
            l0 = errs[("L0", "mean")]
            print(f"\n{view} ({args.size}^2, {args.tf}; load {load:.2f}): level 0's own error {l0:.2f} % pixels dE>=6")
            for (name, c), e in errs.items():
                ref = med.get((name, "mean"))
                ratio = med[(name, c)] / ref if ref else float("nan")
                print(f"  {name:6s} {c:9s} {e:7.2f} %   draw {med[(name, c)] * 1e3:7.1f} ms  x{ratio:.2f} of mean")
                rows.append(dict(kind="error", view=view, level=name, setting=c, value=e,
                                 other=round(med[(name, c)] * 1e3, 2)))
                rows.append(dict(kind="frame_ratio", view=view, level=name, setting=c, value=round(ratio, 3), other=""))
    return _save(rows, load, args.out)


def _save(rows: list[dict], load: float, path) -> int:
    for r in rows:
        r["load"] = round(load, 2)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    import csv

    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
