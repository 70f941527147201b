"""Empty-space skipping below the brick: the full-resolution frame with and without it, against a
plain one-texture ray caster with the same table and stop.

Data: the procedural CT-like head (:func:`clipvol.bricking.generators.ct_head`, ``N``³ uint8, air
around it), 64³ bricks, the ``bone`` table, an iso view and a face view, at 256² and 512² images.
Per image size and view, in one process, warm (every brick on the GPU, one converged frame of
each first) and interleaved round by round, median of ``--repeat`` (>= 5) rounds:

* ``raw``   - ``RawCaster`` of ``tools/bench/bench_render.py`` (``tools/bench_render.py`` in trees
  where the benchmarks are not moved yet): one 3D texture, one table lookup per sample, the table
  corrected for the step, stopping where clipvol stops (``clipvol.render.paths.setup.OPAQUE``);
* ``plain`` - clipvol's full-resolution frame (``policy="fixed", level=0``) with
  ``skip_empty=False``, drawn by the path ``auto`` picks (``path``) and by the single pass;
* ``skip``  - the same with ``skip_empty=True`` (the default).

Columns: median wall and process-CPU seconds (llvmpipe's rasteriser threads count in the CPU
time, which is steadier than wall time on a loaded machine), each configuration over ``raw``, skip
over plain, the fraction of the cells holding data that the table makes empty, and the largest
8-bit difference between the skip and plain images (must be <= 1).
Target: ``skip`` <= 0.7x ``raw``. Rows go to ``tools/bench/results/bench_skip.csv``.

Runs on whatever GL the context gets: Mesa llvmpipe on a machine without a GPU (the figures in
docs/rendering.md were measured on a shared 2-core machine), a GPU's driver where there is one.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def raw_caster_class():
    """``RawCaster`` from the benchmark beside this one, or from ``tools/`` before the move."""
    for where in (HERE, HERE.parent.parent):
        if str(where) not in sys.path:
            sys.path.insert(0, str(where))
    try:
        from bench_render import RawCaster  # tools/bench/bench_render.py
    except ImportError:
        from tools.bench_render import RawCaster  # tools/bench_render.py
    return RawCaster


def views(pyr, image: int):
    from clipvol.scene.camera import Camera

    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    dist = 1.05 * float(np.linalg.norm(hi - lo))
    iso = np.array([0.55, 0.45, 0.7])
    iso /= np.linalg.norm(iso)
    face = np.array([0.0, 0.0, 1.0])  # the face is at low z (ct_head)
    return {name: Camera.perspective(tuple(c - d * dist), tuple(c), up=(0, -1, 0), fov_y=35, size=(image, image))
            for name, d in (("iso", iso), ("face", face))}


def timed(fn) -> tuple[float, float, object]:
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - t, time.process_time() - c, out


def run(n: int, images, repeat: int, step: float, out: Path, log=print) -> list[dict]:
    from clipvol.bricking.generators import ct_head
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction
    from clipvol.render.paths.setup import OPAQUE
    from clipvol.scene.transfer import TransferFunction

    RawCaster = raw_caster_class()
    vol = ct_head((n,) * 3, seed=0)
    loader = NumpyLoader(vol, brick=64)
    pyr = loader.pyramid
    ctx = create_context()
    budget = int(sum(pyr.num_bricks(L) for L in range(pyr.num_levels)) * pyr.brick_nbytes * 1.2) + (64 << 20)
    clip = ClipTexture(loader, budget, threads=2)
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    raw = RawCaster(ctx, vol, pyr.value_range)
    configs = {"plain": dict(skip_empty=False), "skip": dict(skip_empty=True),
               "plain_single_pass": dict(skip_empty=False, path="single-pass"),
               "skip_single_pass": dict(skip_empty=True, path="single-pass")}
    actions = {k: ClipRenderAction(ctx, clip, policy="fixed", level=0, step=step, texture_budget=budget, **kw)
               for k, kw in configs.items()}
    rows = []
    try:
        for image in images:
            for view, cam in views(pyr, image).items():
                imgs = {k: a.render(cam, tf, wait=True, timeout=600) for k, a in actions.items()}
                fc = actions["plain"]._selection_camera(cam)
                raw.render(fc, tf, step, OPAQUE)
                wall = {k: [] for k in ["raw", *actions]}
                cpu = {k: [] for k in ["raw", *actions]}
                for _ in range(repeat):
                    w, c, _img = timed(lambda: raw.render(fc, tf, step, OPAQUE))
                    wall["raw"].append(w)
                    cpu["raw"].append(c)
                    for k, a in actions.items():
                        w, c, _img = timed(lambda: a.render(cam, tf))
                        wall[k].append(w)
                        cpu[k].append(c)
                mw = {k: statistics.median(v) for k, v in wall.items()}
                mc = {k: statistics.median(v) for k, v in cpu.items()}
                row = {"date": time.strftime("%Y-%m-%d"), "volume": f"ct_head {n}^3 uint8, 64^3 bricks",
                       "image": image, "view": view, "step": step, "rounds": repeat,
                       "path": actions["plain"].path_drawn}
                for k in wall:
                    row[f"{k}_ms"] = round(1e3 * mw[k], 1)
                for k in actions:
                    row[f"{k}_over_raw"] = round(mw[k] / mw["raw"], 3)
                    row[f"{k}_over_raw_cpu"] = round(mc[k] / mc["raw"], 3)
                row["empty_cells"] = round(actions["skip"].cache.empty_fraction(), 3)
                row["skipped"] = bool(actions["skip"].skipped_empty and actions["skip_single_pass"].skipped_empty)
                row["skip_over_plain"] = round(mw["skip"] / mw["plain"], 3)
                row["skip_over_plain_single_pass"] = round(mw["skip_single_pass"] / mw["plain_single_pass"], 3)
                row["max_diff_skip_vs_plain"] = int(max(
                    np.abs(imgs["skip"].astype(int) - imgs["plain"].astype(int)).max(),
                    np.abs(imgs["skip_single_pass"].astype(int) - imgs["plain_single_pass"].astype(int)).max()))
                rows.append(row)
                log(f"{image}^2 {view}: raw {row['raw_ms']} ms; skip/raw {row['skip_over_raw']} "
                    f"(cpu {row['skip_over_raw_cpu']}), plain/raw {row['plain_over_raw']}, skip/plain "
                    f"{row['skip_over_plain']}; single pass skip/raw {row['skip_single_pass_over_raw']}, "
                    f"plain/raw {row['plain_single_pass_over_raw']}; max diff {row['max_diff_skip_vs_plain']}")
    finally:
        for a in actions.values():
            a.close()
        raw.release()
        clip.close()
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    log(f"wrote {out}")
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=256, help="head edge in voxels (default 256)")
    ap.add_argument("--images", default="256,512", help="image edges, comma separated (default 256,512)")
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds, median taken (>= 5)")
    ap.add_argument("--step", type=float, default=0.5, help="sample spacing in voxels (default 0.5)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "bench_skip.csv")
    a = ap.parse_args(argv)
    if a.repeat < 5:
        ap.error(f"--repeat: expected at least 5 rounds, got {a.repeat}")
    run(a.size, [int(v) for v in a.images.split(",")], a.repeat, a.step, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
