"""Image-based level of detail benchmark: blocks and frame time at <= 5 % pixels Delta E >= 6.

On a procedural CT-like head (:func:`clipvol.bricking.generators.ct_head`: skull shell, soft
tissue, fine relief on the face, flat background), bricked with its summary tables, every figure is
measured in one run on this machine (Mesa llvmpipe, no GPU):

* **blocks to reach <= 5 % of pixels with CIELUV Delta E >= 6** against the converged picture
  (:mod:`clipvol.app.converged`: level 0 at step 0.25, 2x2 rays per pixel box-filtered) of the
  same view, for the image policy (Wang, Garcia & Shen 2007) and for the
  projected-size policy - the better of its two forms, the ``lod_threshold`` sweep (the default
  policy) and its greedy form under a texel budget. Target: image <= 1/3 of projected size. Every
  form is read at the same resolution: a coarse sweep, then a scan around its 5 % crossing until
  neighbouring points differ by <= 2 bricks (:func:`clipvol.app.lod_sweep.scan_crossing`).
* **frame time at that error**: the image policy's frames (selection - a greedy cut, or the last
  cut replayed while the view turned less than 3 degrees -, visibility estimate when due, draw,
  read-back) against the full-resolution frames of the same cameras by the same renderer, while the
  view turns 0.5 degrees per frame for 12 frames, the two frames of each camera timed one after
  the other; mean and median wall time, and the ratio of process CPU time. Target >= 5x faster.
* **summary tables**: bytes against the compressed bricks, build time against bricking time, and
  the time to recompute every brick's error after a transfer-function change - on the head's
  pyramid, and on a 1024^3 (1 GiB of uint8) pyramid of 32^3 bricks whose tables are drawn from
  the head's (the error's cost depends only on the tables' sizes). Target < 0.5 s for 10^4 bricks.
* Wang, Garcia & Shen's Fig. 6: % pixels against bricks drawn for projected size, distance and image-based
  with and without visibility (``tools/bench/results/bench_lod.png``).

Run ``python tools/bench/bench_lod.py`` (256^3 head, 16^3 bricks, 256^2 images) or ``--quick``.
Writes ``tools/bench/results/bench_lod.csv``, ``tools/bench/results/bench_lod.png`` and ``tools/bench/results/bench_lod.md`` (``--path single-pass``:
``tools/bench/results/bench_lod_single_pass.*``).

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007.
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import RESULTS  # noqa: E402  (tools/bench/common.py)
#: view direction and eye distance in volume diagonals (None: ``--distance``); the face and side views
#: fill the image, the overview shows the whole head from further away
VIEWS = {"face": ((0.3, 0.2, 1.0), None), "side": ((1.0, 0.25, 0.35), None), "overview": ((-0.5, 0.35, 1.0), 1.5)}
THRESHOLDS = (16, 12, 10, 9, 8, 7.5, 7, 6.5, 6, 5.5, 5, 4.5, 4, 3.5, 3, 2.5, 2, 1.5, 1)
BUDGETS = (16, 24, 32, 40, 48, 56, 64, 72, 80, 96, 112, 128, 144, 160, 192, 256, 384, 512)
FINE_STEP = 2  # bricks: the resolution of "bricks needed" around the 5 % crossing, the same for every policy
TURN_FRAMES, TURN_DEG = 12, 0.5  # the timed sequence: the view turns 0.5 degrees per frame about the target


def _turn(cam, target, deg: float):
    """``cam`` with its eye turned by ``deg`` degrees about the vertical axis (0, 1, 0) through ``target``."""
    from clipvol.scene.camera import Camera

    th = np.radians(deg)
    r = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    eye = np.asarray(target) + r @ (np.asarray(cam.eye) - np.asarray(target))
    return Camera.perspective(tuple(eye), tuple(target), up=(0, -1, 0), fov_y=cam.fov_y, size=tuple(cam.size))


def _timed(sess, cam, coi) -> tuple[float, float]:
    """Wall and CPU seconds (this process, llvmpipe's threads included) of one frame."""
    w0, c0 = time.perf_counter(), time.process_time()
    sess.render(cam, coi)
    return time.perf_counter() - w0, time.process_time() - c0


def _dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _big_tables(tables, size: int = 1024, brick: int = 32, seed: int = 0):
    """Summary tables of a ``size``^3 uint8 pyramid of ``brick``^3 bricks, each brick's tables drawn
    at random from the head's level-0/1 bricks (realistic sizes; only the timing is of interest)."""
    from clipvol.bricking.pyramid import Pyramid
    from clipvol.bricking.summary import SummaryTables

    rng = np.random.default_rng(seed)
    pyr = Pyramid.build((size,) * 3, (brick,) * 3, (1.0, 1.0, 1.0), "mean", np.uint8, (0.0, 255.0), 0.0)
    src_h = tables.histogram[0].reshape(-1, 256)
    off, code, cnt = tables.pairs_offsets[0], tables.pairs_code[0], tables.pairs_count[0]
    hist, nanc, offs, codes, counts = [], [], [], [], []
    for L in range(pyr.num_levels):
        n = pyr.num_bricks(L)
        pick = rng.integers(0, len(src_h), n)
        hist.append(src_h[pick].reshape(pyr.grid(L) + (256,)))
        nanc.append(np.zeros(pyr.grid(L), np.int64))
        if L < pyr.num_levels - 1:
            lens = (off[pick + 1] - off[pick]).astype(np.int64)
            o = np.concatenate([[0], np.cumsum(lens)])
            idx = np.concatenate([np.arange(off[p], off[p + 1]) for p in pick]) if n else np.zeros(0, np.int64)
            offs.append(o)
            codes.append(code[idx])
            counts.append(cnt[idx])
        else:
            offs.append(None)
            codes.append(None)
            counts.append(None)
    return SummaryTables(pyr, tables.quantiser, hist, nanc, offs, codes, counts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256, help="head volume edge in voxels (default 256)")
    ap.add_argument("--brick", type=int, default=16, help="brick edge (default 16)")
    ap.add_argument("--image", type=int, default=256, help="image edge in pixels (default 256)")
    ap.add_argument("--distance", type=float, default=0.6,
                    help="eye distance from the centre in volume diagonals of the face and side views")
    ap.add_argument("--quick", action="store_true", help="small smoke run (128^3, 128^2 images)")
    ap.add_argument("--path", choices=("bricks", "single-pass"), default="bricks",
                    help="how the volume action draws every frame of the run (RenderParams.path)")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.image = 128, 128

    from clipvol.app.lod_sweep import (LOD_POLICIES, blocks_to_reach, lod_sweep, plot_lod_sweep, policy_changes,
                                       scan_crossing)
    from clipvol.app.session import RenderSession
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.bricking.summary import build_summary, open_summary, summary_bytes
    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.scene.camera import Camera
    from clipvol.scene.lod_error import lod_errors
    from clipvol.scene.metrics import percent_delta_e
    from clipvol.scene.params import RenderParams
    from clipvol.scene.transfer import TransferFunction

    log = lambda *a: print(*a, file=sys.stderr, flush=True)  # noqa: E731
    tmp = tempfile.TemporaryDirectory(prefix="clipvol-bench-lod-")
    store = Path(tmp.name) / "head.zarr"
    vol = ct_head((args.size,) * 3, seed=0)
    t0 = time.perf_counter()
    brick_volume(vol, store, brick=args.brick, progress=False, summary=False)
    t_brick = time.perf_counter() - t0
    bricks_bytes = _dir_bytes(store)
    t0 = time.perf_counter()
    build_summary(store, progress=False)
    t_summary = time.perf_counter() - t0
    s_bytes = summary_bytes(store)
    overhead = []  # the tables' share of the store for larger bricks (no rendering)
    for b in sorted({16, 32, 64} - {args.brick}):
        other = Path(tmp.name) / f"head-b{b}.zarr"
        brick_volume(vol, other, brick=b, progress=False, summary=False)
        ob = _dir_bytes(other)
        build_summary(other, progress=False)
        overhead.append((b, summary_bytes(other), ob))
    overhead.append((args.brick, s_bytes, bricks_bytes))
    overhead.sort()
    del vol
    tables = open_summary(store)
    pyr = tables.pyramid
    n_bricks = sum(pyr.num_bricks(L) for L in range(pyr.num_levels))
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    tf2 = TransferFunction.preset("viridis", value_range=pyr.value_range)
    eps_head = min(lod_errors(tables, t).seconds for t in (tf2, tf, tf2, tf))
    big = _big_tables(tables)
    n_big = sum(big.pyramid.num_bricks(L) for L in range(big.pyramid.num_levels))
    eps_big = min(lod_errors(big, t).seconds for t in (tf2, tf, tf2))
    log(f"head {args.size}^3 uint8, {args.brick}^3 bricks ({n_bricks} in {pyr.num_levels} levels): bricked in "
        f"{t_brick:.1f} s ({bricks_bytes / 1e6:.1f} MB); summary tables {s_bytes / 1e6:.2f} MB "
        f"({100 * s_bytes / bricks_bytes:.1f} % of the store) in {t_summary:.1f} s")
    log(f"error after a transfer-function change: {eps_head * 1e3:.1f} ms for {n_bricks} bricks; "
        f"{eps_big * 1e3:.0f} ms for a 1024^3 pyramid of 32^3 bricks ({n_big} bricks)")

    loader = open_store(store)
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    diag = float(np.linalg.norm(hi - lo))
    views = []
    for d, dist in VIEWS.values():
        d = np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
        cam = Camera.perspective(tuple(c - d * (dist or args.distance) * diag), tuple(c), up=(0, -1, 0), fov_y=40,
                                 size=(args.image, args.image))
        views.append((cam, tuple(c)))
    budget = int(n_bricks * pyr.brick_nbytes * 1.2) + (64 << 20)
    ctx = create_context()
    rows: list[dict] = []
    full_blocks, refs = [], []
    with RenderSession(loader, ctx, memory_budget=budget, texture_budget=budget, tf=tf,
                       params=RenderParams(policy="fixed", level=0, path=args.path)) as sess:
        from clipvol.app.converged import ConvergedPictures

        for cam, coi in views:
            sess.render(cam, coi, wait=True, timeout=600)
            full_blocks.append(sess.frame_stats.bricks_distinct)
        # errors against the converged picture (level 0, step 0.25, 2x2 rays per pixel box-filtered)
        base = sess.params

        def draw(c, params):
            sess.update(**{f: getattr(params, f) for f in ("policy", "level", "step", "refine_tolerance")})
            return sess.render(c, wait=True, timeout=600)

        conv = ConvergedPictures(draw, base)
        for v, (cam, coi) in enumerate(views):
            sess.set_center(coi)
            refs.append(conv.get(cam, key=v))
        sess.update(step=base.step)
        log(f"full resolution: {full_blocks} bricks; errors against the converged picture: {conv.describe()}")
        sess.update(level=None)
        for t in THRESHOLDS:
            sess.update(policy="projected-size", lod_threshold=t, max_texels_drawn=None, block_budget=None)
            for v, (cam, coi) in enumerate(views):
                img = sess.render(cam, coi, wait=True, timeout=600)
                t0 = time.perf_counter()
                sess.render(cam, coi)
                dt = time.perf_counter() - t0
                rows.append(dict(policy="projected size (threshold)", budget=t, view=v,
                                 blocks=sess.frame_stats.bricks_distinct, pct_de6=round(percent_delta_e(img, refs[v]), 4),
                                 frame_s=round(dt, 6), converged=int(sess.frame_stats.converged)))
        rows += lod_sweep(sess, views, refs, BUDGETS, tuple(LOD_POLICIES), timeout=600, log=log)
        for r in rows:
            r["stage"] = "coarse"
        # the same resolution for every form around its 5 % crossing: scanned until neighbours differ
        # by at most FINE_STEP bricks drawn (budgets every FINE_STEP, thresholds at geometric steps)
        texels = int(np.prod(pyr.brick_shape))
        forms = {"image": (True, lambda b: policy_changes("image", int(b), texels)),
                 "projected size": (True, lambda b: policy_changes("projected size", int(b), texels)),
                 "projected size (threshold)": (False, lambda t: dict(policy="projected-size", lod_threshold=float(t),
                                                                      max_texels_drawn=None, block_budget=None))}
        n_fine = {}
        for label, (integer, changes) in forms.items():
            for v, (cam, coi) in enumerate(views):
                def measure(value, label=label, changes=changes, v=v, cam=cam, coi=coi):
                    sess.update(**changes(value))
                    sess.render(cam, coi, wait=True, timeout=600)
                    t0 = time.perf_counter()
                    img = sess.render(cam, coi)
                    dt = time.perf_counter() - t0
                    fs = sess.frame_stats
                    rows.append(dict(policy=label, budget=value, view=v, blocks=int(fs.bricks_distinct),
                                     pct_de6=round(percent_delta_e(img, refs[v]), 4), frame_s=round(dt, 6),
                                     converged=int(fs.converged), stage="fine"))
                    return rows[-1]["blocks"], rows[-1]["pct_de6"]

                pts = {r["budget"]: (r["blocks"], r["pct_de6"]) for r in rows if r["policy"] == label and r["view"] == v}
                got = scan_crossing(measure, pts, integer=integer, target=5.0, step=FINE_STEP)
                n_fine[(label, v)] = len(got)
                best = blocks_to_reach(rows, label, 5.0, v)
                log(f"fine scan {label} view {v}: {len(got)} points, fewest bricks at <= 5 %: "
                    f"{best['blocks'] if best else '-'} ({best['budget'] if best else '-'})")
        # the frame time at the 5 % point: the view turns TURN_DEG per frame; the full-resolution frame
        # and the image frame of each camera are timed one after the other (interleaved), each from
        # the same warm state (every brick of the sequence loaded and uploaded beforehand)
        summary = []
        full = dict(policy="fixed", level=0, block_budget=None, max_texels_drawn=None)
        for v, (cam, coi) in enumerate(views):
            img_row = blocks_to_reach(rows, "image", 5.0, v)
            proj = [r for r in (blocks_to_reach(rows, "projected size", 5.0, v),
                                blocks_to_reach(rows, "projected size (threshold)", 5.0, v)) if r]
            proj_row = min(proj, key=lambda r: r["blocks"]) if proj else None
            times = dict(full=[], image=[])
            if img_row is not None:
                image = dict(policy="image", level=None, visibility=True, block_budget=img_row["budget"],
                             max_texels_drawn=None)
                seq = [_turn(cam, coi, k * TURN_DEG) for k in range(TURN_FRAMES)]
                for ch in (full, image):  # warm: every brick of the sequence resident and on the GPU
                    sess.update(**ch)
                    for c in seq:
                        sess.render(c, coi, wait=True, timeout=600)
                lod = sess.action.image_lod
                cuts0, est0 = lod.cuts, lod.estimates
                for c in seq:  # (the image policy's last cut and estimate are from the far end of the turn)
                    sess.update(**full)
                    times["full"].append(_timed(sess, c, coi))
                    sess.update(**image)
                    times["image"].append(_timed(sess, c, coi))
                cuts, ests = lod.cuts - cuts0, lod.estimates - est0
            else:
                cuts = ests = 0
            w = {k: np.array([x[0] for x in t]) for k, t in times.items()}
            c = {k: np.array([x[1] for x in t]) for k, t in times.items()}
            summary.append(dict(view=list(VIEWS)[v], full_blocks=full_blocks[v], image=img_row, proj=proj_row,
                                full_ms=float(np.mean(w["full"]) * 1e3) if len(w["full"]) else float("nan"),
                                image_ms=float(np.mean(w["image"]) * 1e3) if len(w["image"]) else float("nan"),
                                full_med=float(np.median(w["full"]) * 1e3) if len(w["full"]) else float("nan"),
                                image_med=float(np.median(w["image"]) * 1e3) if len(w["image"]) else float("nan"),
                                cpu_ratio=float(c["full"].sum() / c["image"].sum()) if len(c["image"]) else float("nan"),
                                cuts=cuts, estimates=ests))
            log(f"view {v}: frame over a {TURN_FRAMES}-frame turn: full {summary[-1]['full_ms']:.0f} ms, image "
                f"{summary[-1]['image_ms']:.0f} ms (mean wall), CPU ratio {summary[-1]['cpu_ratio']:.2f}, "
                f"{cuts} greedy cuts and {ests} visibility estimates in {TURN_FRAMES} frames")
    ctx.release()
    tmp.cleanup()

    out = args.out_dir
    out.mkdir(parents=True, exist_ok=True)
    stem = "bench_lod" if args.path == "bricks" else "bench_lod_single_pass"
    with open(out / f"{stem}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["policy", "budget", "view", "blocks", "pct_de6", "frame_s", "converged", "stage"])
        w.writeheader()
        w.writerows(rows)
    plot = plot_lod_sweep([r for r in rows if r["policy"] in LOD_POLICIES and r["stage"] == "coarse"], out / f"{stem}.png",
                          title=f"CT-like head {args.size}^3, {args.brick}^3 bricks, {args.image}^2 images, "
                                f"{len(views)} views, {args.path} path")
    lines = [f"Path: {args.path}. Frame times: mean (median) wall over a {TURN_FRAMES}-frame turn of "
             f"{TURN_DEG} degrees per frame, full-resolution and image frames interleaved; CPU: process CPU "
             f"time (llvmpipe's threads included) of the full frames over the image frames.", "",
             "| view | full resolution: bricks | projected size at <= 5 %: bricks (% px) | image at <= 5 %: "
             "bricks (% px) | bricks image / projected | full frame, ms | image frame, ms | full / image: wall (CPU) "
             "| cuts / estimates in the turn |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for s in summary:
        ir, pr = s["image"], s["proj"]
        ratio = f"{ir['blocks'] / pr['blocks']:.2f}" if ir and pr else "-"
        speed = f"{s['full_ms'] / s['image_ms']:.1f}x ({s['cpu_ratio']:.1f}x)" if ir else "-"
        lines.append(f"| {s['view']} | {s['full_blocks']} | "
                     f"{pr['blocks'] if pr else '-'} ({pr['pct_de6'] if pr else '-'}) | "
                     f"{ir['blocks'] if ir else '-'} ({ir['pct_de6'] if ir else '-'}) | {ratio} | "
                     f"{s['full_ms']:.0f} ({s['full_med']:.0f}) | {s['image_ms']:.0f} ({s['image_med']:.0f}) | {speed} | "
                     f"{s['cuts']} / {s['estimates']} |")
    lines += ["", f"Bricks needed: the fewest distinct bricks drawn of any point at <= 5 % pixels Delta E >= 6, after a "
              f"coarse sweep ({len(BUDGETS)} block budgets, {len(THRESHOLDS)} thresholds) and a scan around each form's "
              f"crossing until neighbouring points differ by <= {FINE_STEP} bricks (block and texel budgets every "
              f"{FINE_STEP}, thresholds at geometric steps; points scanned per view below). Projected size is the "
              "better of its two forms.", "",
              "| view | image: bricks (budget) [scanned] | projected size, texel budget: bricks (budget) [scanned] | "
              "projected size, threshold: bricks (threshold) [scanned] |", "| --- | --- | --- | --- |"]
    for v, s in enumerate(summary):
        cells = []
        for label in ("image", "projected size", "projected size (threshold)"):
            b = blocks_to_reach(rows, label, 5.0, v)
            cells.append(f"{b['blocks']} ({b['budget']}) [{n_fine.get((label, v), 0)}]" if b else "-")
        lines.append(f"| {s['view']} | " + " | ".join(cells) + " |")
    lines += ["", f"Summary tables: {s_bytes / 1e6:.2f} MB = {100 * s_bytes / bricks_bytes:.1f} % of the "
              f"compressed bricks ({bricks_bytes / 1e6:.1f} MB), built in {t_summary:.1f} s (bricking: {t_brick:.1f} s). "
              f"Error update after a transfer-function change: {eps_head * 1e3:.1f} ms for the head's {n_bricks} "
              f"bricks, {eps_big * 1e3:.0f} ms for a 1024^3 pyramid of 32^3 bricks ({n_big} bricks)."]
    lines += ["", "| brick | compressed store (pyramid + statistics) | summary tables | share |", "| --- | --- | --- | --- |"]
    lines += [f"| {b}^3 | {ob / 1e6:.2f} MB | {sb / 1e6:.2f} MB | {100 * sb / ob:.1f} % |" for b, sb, ob in overhead]
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    if plot:
        print(f"wrote {out / (stem + '.csv')}, {plot}, {out / (stem + '.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
