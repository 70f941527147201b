"""The benchmark that decides: how much faster than full resolution at <= 5 % of pixels visibly
different, on scan-like data with air and soft tissue.

Data: the CT-like head in 12-bit words (:func:`common.ct_volume`, ``N``³ uint16: air of exactly 0
around the head, soft tissue, bone; bricked once into ``bench-data/`` with its summary tables,
:func:`common.ct_store`), the ``bone`` table, an iso view and a face view, 256² and 512² images.
No real scan ships in a package clipvol depends on (nibabel's and pydicom's test files are a few
slices or a few voxels across); ``--store`` takes any clipvol store with summary tables (a T1 MRI
bricked with ``clipvol brick``; docs/benchmarks.md measures the MNI ICBM152 T1 template from the
nilearn wheel this way), and then the raw caster is given the store's level 0 read whole.

Per image size and view (``iso`` and ``face``: overviews, the whole head in the image; ``close``:
from a third of the distance, a part of the head filling the image), in one process, every
configuration warm (every brick on the GPU, one converged frame of each first) and timed in
interleaved rounds (forward order on even rounds, reverse on odd), median of ``--repeat`` (>= 5)
rounds:

* ``raw``  - :class:`common.RawCaster`: one 3D texture, one table lookup per sample, the table
  corrected for the step, stopping where clipvol stops (``clipvol.render.paths.setup.OPAQUE``); the
  reference outside clipvol's render path;
* ``full`` - clipvol's full-resolution frame (``policy="fixed", level=0``, empty-space skipping on);
* each setting: level 0 sampled at ``step`` 1, 2 and 3 voxels (the opacity corrected for the
  step, as always); fixed levels 1 and 2; projected size at ``lod_threshold`` 2, 4, 8; the image policy at block budgets
  32, 64, 128; the image policy under the error budgets ``max_error`` 10 %, 5 %, 2 %; adaptive image
  sampling (``refine_tolerance``, :mod:`clipvol.render.refine`) with level 0 at step 2 (tolerances
  0.08 and 0.16), 2.5 (0.3) and 3 (0.16), with the image policy at 5 % (0.16), and with level 1
  at step 0.5, 0.75 (0.16), 1 (0.08, 0.16 and 0.3), 1.5 (0.08, 0.16) and 2 (0.12), and without
  it at step 1, 1.5 and 2; where
  ``RenderParams`` has ``classify`` (consistent coarse levels), every setting again with
  ``classify="distribution"`` (rows ``... dist``; else the rows say ``classify n/a``).

Errors are against the **converged picture** of the view (:mod:`clipvol.app.converged`: level 0 at
step ``--converged-step`` 0.25, drawn at ``--supersample`` (2) times the width and height and
box-filtered down; once per view, untimed), the full-resolution frame's own error beside every
row (``full_pct_de6``). Columns: each setting's bricks, % of pixels with CIELUV Delta E >= 6
against the converged picture (:func:`clipvol.scene.metrics.percent_delta_e`), the image policy's
own prediction of that figure and its ratio to the measurement, its median frame time, its
**speed-up** (the median over rounds of ``full``'s time over the setting's, both drawn in the same
round) and its time over ``raw``'s. The last line per view names the fastest setting at <= 5 %
(the target is >= 5x). Rows go to ``tools/bench/results/bench_mission.csv``.

On a machine with a GPU: ``--images 256,512,1024 --supersample 4`` (nothing assumes llvmpipe).

Runs on whatever GL the context gets: Mesa llvmpipe on a machine without a GPU (the figures in
docs/rendering.md were measured on a shared 2-core machine), a GPU's driver where there is one.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import common  # noqa: E402  (tools/bench/common.py, beside this script)

#: the target: at most this % of pixels with Delta E >= 6 ...
TARGET_PCT = 5.0
#: ... at least this many times faster than the full-resolution frame
TARGET_SPEEDUP = 5.0


def settings() -> dict:
    """Name -> RenderParams changes of every setting timed against the full-resolution frame."""
    out = {f"step={st:g}": dict(policy="fixed", level=0, step=st) for st in (1.0, 2.0, 3.0)}
    out.update({f"fixed L{L}": dict(policy="fixed", level=L) for L in (1, 2)})
    out.update({f"lod={t:g}": dict(policy="projected-size", lod_threshold=t) for t in (2.0, 4.0, 8.0)})
    out.update({f"image b={b}": dict(policy="image", block_budget=b) for b in (32, 64, 128)})
    out.update({f"max-error={e:g}%": dict(policy="image", max_error=e / 100.0) for e in (10, 5, 2)})
    out.update({f"step={st:g} refine={tol:g}": dict(policy="fixed", level=0, step=st, refine_tolerance=tol)
                for st, tol in ((2.0, 0.08), (2.0, 0.16), (2.5, 0.3), (3.0, 0.16))})
    out["max-error=5% refine=0.16"] = dict(policy="image", max_error=0.05, refine_tolerance=0.16)
    # level 1 (a consistent level with classify="distribution") with adaptive image sampling, at its
    # own step and at 1.5x / 2x it (the step is in voxels of the level drawn: level 1's 1 is 2 of level 0's)
    out.update({f"L1 step={st:g} refine={tol:g}": dict(policy="fixed", level=1, step=st, refine_tolerance=tol)
                for st, tol in ((0.5, 0.16), (0.75, 0.16), (1.0, 0.08), (1.0, 0.16), (1.0, 0.3), (1.5, 0.08),
                                (1.5, 0.16), (2.0, 0.12))})
    out.update({f"L1 step={st:g}": dict(policy="fixed", level=1, step=st) for st in (1.0, 1.5, 2.0)})
    return out


def views(pyr, image: int) -> dict:
    """The overview views ``iso`` and ``face`` (the whole volume in view) and the ``close`` view (from
    a third of the distance along the iso direction, aimed a quarter of the way from the centre to
    the near corner: a part of the head fills the image, its bricks large on screen)."""
    from clipvol.scene.camera import Camera

    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    dist = 1.05 * float(np.linalg.norm(hi - lo))
    iso = np.array([0.55, 0.45, 0.7])
    iso /= np.linalg.norm(iso)
    face = np.array([0.0, 0.0, 1.0])  # the head's face is at low z (ct_head)
    out = {name: Camera.perspective(tuple(c - d * dist), tuple(c), up=(0, -1, 0), fov_y=35, size=(image, image))
           for name, d in (("iso", iso), ("face", face))}
    aim = c - 0.25 * iso * 0.5 * float(np.linalg.norm(hi - lo))
    out["close"] = Camera.perspective(tuple(aim - iso * dist / 3.0), tuple(aim), up=(0, -1, 0), fov_y=35,
                                      size=(image, image))
    return out


def classify_modes() -> tuple:
    """``("mean", "distribution")`` when ``RenderParams`` has the ``classify`` field (consistent coarse
    levels: the transfer function applied to each coarse voxel's distribution), else ``(None,)``:
    the rows say ``classify n/a``."""
    import dataclasses

    from clipvol.scene.params import RenderParams

    return ("mean", "distribution") if "classify" in {f.name for f in dataclasses.fields(RenderParams)} else (None,)


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def run(store: Path, volume: np.ndarray, label: str, images, repeat: int, step: float, log=print,
        supersample: int = 2, converged_step: float = 0.25, view_names=None, only=None) -> list[dict]:
    from clipvol.app.converged import ConvergedPictures
    from clipvol.render.paths.setup import OPAQUE
    from clipvol.scene.metrics import percent_delta_e
    from clipvol.scene.params import RenderParams

    scene = common.WarmScene(store)
    pyr, tf = scene.pyramid, scene.tf
    raw = scene.raw_caster(volume)
    conf = {"full": dict(policy="fixed", level=0)}
    for mode in classify_modes():
        extra = {} if mode is None else {"classify": mode}
        tag = "" if mode in (None, "mean") else " dist"
        conf.update({k + tag: {**kw, **extra} for k, kw in settings().items() if only is None or k in only})
    actions = {k: scene.action(**{"step": step, **kw}) for k, kw in conf.items()}
    draw = scene.converged_drawer(timeout=600)

    conv = ConvergedPictures(draw, RenderParams(step=step), supersample=supersample, step=converged_step)
    log(f"errors against the converged picture: {conv.describe()}")
    rows = []
    try:
        for image in images:
            for view, cam in views(pyr, image).items():
                if view_names and view not in view_names:
                    continue
                truth = conv.get(cam, key=(image, view))
                imgs = {k: a.render(cam, tf, wait=True, timeout=600) for k, a in actions.items()}
                for k, a in actions.items():
                    if not a.last_frame_stats.converged:
                        raise RuntimeError(f"{k}: the frame did not converge in 600 s ({image}^2 {view})")
                fc = actions["full"]._selection_camera(cam)
                raw.render(fc, tf, step, OPAQUE)
                names = ["raw", *actions]
                times = {k: [] for k in names}
                for r in range(repeat):
                    for k in (names if r % 2 == 0 else names[::-1]):
                        if k == "raw":
                            times[k].append(_timed(lambda: raw.render(fc, tf, step, OPAQUE)))
                        else:
                            times[k].append(_timed(lambda: actions[k].render(cam, tf)))
                med = {k: statistics.median(v) for k, v in times.items()}

                def pct_of(img):
                    return float(percent_delta_e(img, truth, threshold=6.0, premultiplied=False))

                full_pct = pct_of(imgs["full"])
                base = {"date": time.strftime("%Y-%m-%d"), "volume": label, "image": image, "view": view,
                        "step": step, "rounds": repeat, "converged": conv.describe(),
                        "raw_ms": round(1e3 * med["raw"], 1),
                        "full_ms": round(1e3 * med["full"], 1), "full_over_raw": round(med["full"] / med["raw"], 3),
                        "full_bricks": actions["full"].last_frame_stats.bricks_distinct,
                        "full_pct_de6": round(full_pct, 3)}
                best = None
                for k in conf:
                    if k == "full":
                        continue
                    a = actions[k]
                    pct = pct_of(imgs[k])
                    speed = statistics.median(f / s for f, s in zip(times["full"], times[k]))
                    est = getattr(a.last_policy, "estimated_error", float("nan")) if conf[k]["policy"] == "image" else ""
                    row = dict(base, setting=k, classify=conf[k].get("classify", "n/a"),
                               bricks=a.last_frame_stats.bricks_distinct, pct_de6=round(pct, 3),
                               predicted_pct_de6=round(100 * est, 3) if est != "" else "",
                               predicted_over_measured=round(100 * est / pct, 3) if est != "" and pct > 0 else "",
                               ms=round(1e3 * med[k], 1), speedup=round(speed, 3),
                               over_raw=round(med[k] / med["raw"], 3))
                    rows.append(row)
                    if pct <= TARGET_PCT and (best is None or speed > best["speedup"]):
                        best = row
                    log(f"{image}^2 {view:5} {k:>24}: {row['bricks']:4d} bricks, {pct:6.2f} % dE>=6 "
                        f"(predicted {row['predicted_pct_de6'] if est != '' else '-'}), {row['ms']:7.1f} ms, "
                        f"{speed:5.2f}x full, {row['over_raw']:.2f}x raw")
                log(f"{image}^2 {view}: full {base['full_ms']} ms ({base['full_bricks']} bricks, {full_pct:.2f} % dE>=6 "
                    f"against the converged picture) = {base['full_over_raw']}x raw ({base['raw_ms']} ms); " +
                    (f"fastest at <= {TARGET_PCT:g} %: {best['setting']}, {best['speedup']:.2f}x full at "
                     f"{best['pct_de6']:.2f} % (target {TARGET_SPEEDUP:g}x: "
                     f"{'reached' if best['speedup'] >= TARGET_SPEEDUP else 'not reached'})"
                     if best else f"no setting at <= {TARGET_PCT:g} %"))
    finally:
        scene.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="256x256x256", help="head shape ZxYxX in voxels (default 256x256x256)")
    ap.add_argument("--brick", type=int, default=32, help="brick edge (default 32)")
    ap.add_argument("--store", type=Path, default=None,
                    help="a clipvol store with summary tables to measure instead of the head")
    ap.add_argument("--images", default="256,512", help="image edges, comma separated (default 256,512)")
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds, medians taken (>= 5)")
    ap.add_argument("--step", type=float, default=0.5, help="sample spacing in voxels of each level (default 0.5)")
    ap.add_argument("--supersample", type=int, default=2,
                    help="rays per pixel along each axis of the converged picture (default 2; 4 on a GPU)")
    ap.add_argument("--converged-step", type=float, default=0.25,
                    help="sample spacing of the converged picture in voxels (default 0.25)")
    ap.add_argument("--views", default=None, help="views to measure, comma separated (default iso,face,close)")
    ap.add_argument("--settings", default=None,
                    help="settings to time, comma separated names as printed (default: all; on a loaded CPU a few)")
    ap.add_argument("--dev", action="store_true", help="allow fewer than 5 rounds (while developing; not for the docs)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_mission.csv")
    a = ap.parse_args(argv)
    if a.repeat < 5 and not a.dev:
        ap.error(f"--repeat: expected at least 5 rounds, got {a.repeat}")
    if a.settings is not None and set(a.settings.split(",")) - set(settings()):
        ap.error(f"--settings: unknown {sorted(set(a.settings.split(',')) - set(settings()))}; "
                 f"known: {', '.join(settings())}")
    if a.supersample < 1:
        ap.error(f"--supersample: expected an integer >= 1, got {a.supersample}")
    store, volume, label = common.store_or_ct(a.store, a.size, a.brick)
    rows = run(store, volume, label, [int(v) for v in a.images.split(",")], a.repeat, a.step,
               supersample=a.supersample, converged_step=a.converged_step,
               view_names=None if a.views is None else a.views.split(","),
               only=None if a.settings is None else a.settings.split(","))
    return common.save_rows(a.out, rows)


if __name__ == "__main__":
    sys.exit(main())
