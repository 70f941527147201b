"""Brick the built-in dataset, fly around it, and write the error-against-time report.

``clipvol demo`` (no arguments) builds a 192^3 procedural volume - the ``fractal`` generator
(detail at every scale) shaped into a ball so the octree has empty bricks to skip - bricks it into
``./clipvol-demo/fractal-ball.zarr`` with :func:`clipvol.bricking.pipeline.brick_volume` (32^3 bricks),
renders an orbit flythrough with the multiresolution renderer to ``orbit.gif``, a zoom onto a
point with brick outlines coloured by level (frames as they come) to ``zoom.gif``, runs :func:`clipvol.app.report.run_report` into
``clipvol-demo/report/`` and prints where everything is. ``--quick`` does a tiny version in seconds
(used by the tests). Re-running reuses a finished store.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

def demo_transfer_function():
    """The demo's :class:`~clipvol.scene.transfer.TransferFunction` (the ``demo`` preset, over the data's value range)."""
    from clipvol.scene.transfer import TransferFunction

    return TransferFunction.preset("demo")


def demo_volume(n: int, seed: int = 3, slab: int = 32) -> np.ndarray:
    """``(n, n, n)`` float32: the procedural fractal times a soft ball envelope (computed in z-slabs)."""
    import numpy as np

    from clipvol.bricking.generators import Fractal

    gen = Fractal((n, n, n), seed=seed)
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    out = np.empty((n, n, n), dtype=np.float32)
    yy, xx = np.meshgrid(c, c, indexing="ij")
    for z0 in range(0, n, slab):
        z1 = min(z0 + slab, n)
        f = gen.region(0, (z0, 0, 0), (z1, n, n))
        r = np.sqrt(c[z0:z1, None, None] ** 2 + yy[None] ** 2 + xx[None] ** 2)
        out[z0:z1] = f * np.clip((1.0 - r) / 0.3, 0.0, 1.0)
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="clipvol-demo", help="output directory (default ./clipvol-demo)")
    p.add_argument("--quick", action="store_true", help="a tiny version that runs in seconds")
    from clipvol.tools.common_args import add_common_arguments, add_old_spelling

    p.add_argument("--edge", type=int, default=None, metavar="N",
                   help="volume edge in voxels (default 192; 40 with --quick)")
    add_old_spelling(p, "--size", "--edge", " (--size is an image's WxH in the drawing commands)", type=int)
    add_common_arguments(p, ("frames",))
    p.add_argument("--no-report", action="store_true", help="skip the report")
    add_common_arguments(p, ("overwrite",))


def _store_ok(path: Path, n: int) -> bool:
    from clipvol.errors import ClipvolError
    from clipvol.paging.open import open_store

    try:
        return open_store(path).pyramid.shape == (n, n, n)
    except ClipvolError:
        return False


def run(args) -> int:
    from clipvol.app.flythrough import render_path
    from clipvol.app.report import run_report
    from clipvol.app.session import open_loader
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.errors import ParameterError

    quick = bool(args.quick)
    n = args.edge or (40 if quick else 192)
    frames = args.frames or (4 if quick else 36)
    if n < 8 or n > 1024:
        raise ParameterError(f"--size: expected 8..1024 voxels, got {n}")
    if frames < 1:
        raise ParameterError(f"--frames: expected >= 1, got {frames}")
    brick = 16 if quick else 32
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    store = out / "fractal-ball.zarr"
    t0 = time.perf_counter()
    if store.exists() and _store_ok(store, n):
        print(f"reusing {store}")
    else:
        print(f"building a {n}^3 procedural volume and bricking it into {store} ...", flush=True)
        vol = demo_volume(n)
        brick_volume(vol, store, brick=brick, progress=not quick, overwrite=args.overwrite)
        del vol
    t_brick = time.perf_counter() - t0
    loader = open_loader(store)
    tf = demo_transfer_function()
    size = (64, 64) if quick else (256, 256)
    from clipvol.render.context import create_context

    ctx = create_context()
    try:
        t1 = time.perf_counter()
        from clipvol.scene.paths import fit_distance

        # the ball fills the cube's inscribed sphere: come closer than the cube's bounding sphere
        dist = 0.75 * fit_distance(loader.pyramid, 35.0, size)
        orbit = render_path(loader, out / "orbit.gif", path="orbit", frames=frames, size=size, converged=True,
                            tf=tf, ctx=ctx, fps=12, path_kwargs={"distance": dist})
        zoom = render_path(loader, out / "zoom.gif", path="zoom", frames=max(frames // 2, 2), size=size, converged=False,
                           tf=tf, outlines=True, ctx=ctx, fps=6)
        t_render = time.perf_counter() - t1
        report = None
        if not args.no_report:
            t2 = time.perf_counter()
            # a short report (the demo should take about a minute): three projected-size
            # thresholds, the image policy at a 5 % error budget, adaptive image sampling at step
            # 2.5 (level 0) and step 1 (level 1, classified by its distribution), 3 rounds over 2
            # views; `clipvol report` on the store measures the full sweep
            # (block, memory and texture budgets too)
            report = run_report(
                loader, out / "report", views=2, size=(48, 48) if quick else (160, 160),
                thresholds=(1.0, 4.0, 16.0), tf=tf, ctx=ctx, memory_budgets=(), texture_budgets=(),
                block_budgets=(), max_errors=() if quick else ("5%",),
                refines=() if quick else ((2.5, 0.3), (1.0, 0.08, 1)),
                max_frames=3 if quick else 8, log=None if quick else (lambda s: print(s, flush=True)),
                rounds=2 if quick else 3,
            )
            t_report = time.perf_counter() - t2
    finally:
        ctx.release()
    print()
    print(f"clipvol demo: {n}^3 voxels, brick {brick}, {loader.pyramid.num_levels} levels")
    print(f"  store   {store}  ({t_brick:.1f} s)")
    print(f"  orbit   {orbit.gif}  ({orbit.frames} frames, converged; statistics {orbit.csv})")
    print(f"  zoom    {zoom.gif}  ({zoom.frames} frames as they come, brick outlines by level; {zoom.csv})  ({t_render:.1f} s)")
    if report is not None:
        print(f"  report  {report.markdown}  ({t_report:.1f} s)")
        for p in report.plots:
            print(f"          {p}")
        from clipvol.app.report import summarise

        for s in summarise(report.rows):
            if s["sweep"] in ("fixed", "lod_threshold"):
                print(f"          {s['setting']:>10}: {s['frame_s'] * 1e3:7.1f} ms/frame ({s['speedup']:.2f}x)  "
                      f"{s['bricks_drawn']:6.0f} bricks  {s['pct_de6']:6.2f} % pixels dE>=6")
        print(f"          {report.headline}")
    print(f"look at it interactively:  clipvol view {store} --tf demo")
    return 0
