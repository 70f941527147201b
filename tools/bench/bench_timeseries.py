"""Time-series playback benchmark: steps per second with prefetch, without, and from memory.

One run on this machine (Mesa llvmpipe, no GPU), three ways of playing the same series of an
OME-Zarr image with a ``t`` axis (``bench-data/series-T8-128.zarr``: 8 steps of 128^3 float32, a
moving bright blob in noise, blosc lz4, written with zarr), each step drawn converged
(``wait=True``) at 256^2 from the same camera:

* **cached** - one step whose bricks are all in memory and on the GPU, re-drawn: the rate a
  player reaches when nothing has to be loaded (the ceiling);
* **prefetch** - :class:`clipvol.app.timeseries.TimeSeriesPlayer` with the budget split between
  the step on screen and the next one, whose loader threads fill it meanwhile;
* **no prefetch** - the same player with ``prefetch=False``: each step loads after it is asked for.

A player shows each step for a frame period (``--period``, default 1.5x the cached frame time, so
that a step that needs no loading keeps the rate), sleeping after the frame until the period is
over: that idle time is what prefetching can use. Back-to-back stepping with no idle time cannot
hide loads on a CPU-only machine, where the loader threads and the software rasterizer share the
same cores; that figure is printed too. The budget holds one step about twice (``--budget``), as
the target case says. Printed: steps/s of each and the ratios prefetch / cached (target >= 0.9)
and prefetch / no prefetch. Writes ``tools/bench/results/bench_timeseries.csv``.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import time
from pathlib import Path

import numpy as np

from common import DATA, RESULTS  # noqa: E402  (tools/bench/common.py)


def build_series(path: Path, steps: int, n: int) -> Path:
    import zarr

    if (path / "zarr.json").is_file():
        return path
    rng = np.random.default_rng(0)
    g = zarr.open_group(str(path), mode="w")
    arr = g.create_array("0", shape=(steps, n, n, n), chunks=(1, 64, 64, 64), dtype="float32")
    z, y, x = np.mgrid[:n, :n, :n].astype(np.float32)
    for t in range(steps):
        c = n * (0.25 + 0.5 * t / max(steps - 1, 1))
        blob = np.exp(-((x - c) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2) / (0.02 * n * n))
        arr[t] = (0.8 * blob + 0.2 * rng.random((n, n, n), dtype=np.float32)).astype(np.float32)
    axes = [{"name": "t", "type": "time"}] + [{"name": a, "type": "space"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1, 1]}]}]}],
        "omero": {"channels": [{"window": {"min": 0.0, "max": 1.0}}]}}})
    return path


def _paced(step, frames: int, period: float) -> float:
    """Steps per second of ``frames`` calls of ``step()``, each shown for at least ``period`` s."""
    t0 = time.perf_counter()
    for _ in range(frames):
        t = time.perf_counter()
        step()
        left = period - (time.perf_counter() - t)
        if left > 0:
            time.sleep(left)
    return frames / (time.perf_counter() - t0)


def play(loaders, ctx, cam, tf, budget: int, prefetch: bool, rounds: int, period: float = 0.0) -> float:
    from clipvol.app.timeseries import TimeSeriesPlayer

    with TimeSeriesPlayer(loaders, ctx, memory_budget=budget, prefetch=prefetch) as p:
        p.set_center(cam.target)
        p.render(cam, tf, wait=True)

        def step() -> None:
            p.advance()
            p.render(cam, tf, wait=True)

        return _paced(step, rounds * len(loaders), period)


def cached(loaders, ctx, cam, tf, budget: int, frames: int, period: float = 0.0) -> float:
    from clipvol.app.timeseries import TimeSeriesPlayer

    with TimeSeriesPlayer(loaders[:1], ctx, memory_budget=budget, prefetch=False) as p:
        p.set_center(cam.target)
        p.render(cam, tf, wait=True)
        return _paced(lambda: p.render(cam, tf, wait=True), frames, period)


def main(argv: list[str] | None = None) -> int:
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.render.context import create_context
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--n", type=int, default=128, help="edge of one step in voxels")
    ap.add_argument("--budget", default=None, help="memory budget (default: about twice one step)")
    ap.add_argument("--rounds", type=int, default=2, help="passes over the series (median of --repeat)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--period", type=float, default=None, help="seconds a step is shown (default 1.5x cached)")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    path = build_series(DATA / f"series-T{args.steps}-{args.n}.zarr", args.steps, args.n)
    loaders = [ZarrLoader(path, t=k) for k in range(args.steps)]
    step_bytes = sum(loaders[0].pyramid.num_bricks(L) for L in range(loaders[0].pyramid.num_levels)) \
        * loaders[0].pyramid.brick_nbytes
    from clipvol.units import parse_bytes

    budget = parse_bytes(args.budget) if args.budget else int(2.2 * step_bytes)
    n = args.n
    cam = Camera.perspective((n * 0.5, n * 0.4, -1.6 * n), (n / 2 - 0.5,) * 3, up=(0, 1, 0), fov_y=35.0,
                             size=(args.size, args.size))
    tf = TransferFunction.preset("bone")
    ctx = create_context()
    rates = {"cached": [], "prefetch": [], "no_prefetch": [], "prefetch_unpaced": [], "no_prefetch_unpaced": []}
    frames = args.steps * args.rounds
    try:
        period = args.period or 1.5 / cached(loaders, ctx, cam, tf, budget, 4)
        for _ in range(args.repeat):  # interleaved, so drift of a shared machine hits all of them
            rates["cached"].append(cached(loaders, ctx, cam, tf, budget, frames, period))
            rates["prefetch"].append(play(loaders, ctx, cam, tf, budget, True, args.rounds, period))
            rates["no_prefetch"].append(play(loaders, ctx, cam, tf, budget, False, args.rounds, period))
            rates["prefetch_unpaced"].append(play(loaders, ctx, cam, tf, budget, True, args.rounds))
            rates["no_prefetch_unpaced"].append(play(loaders, ctx, cam, tf, budget, False, args.rounds))
    finally:
        ctx.release()
    med = {k: statistics.median(v) for k, v in rates.items()}
    rows = [
        ("prefetch_steps_per_s", med["prefetch"], "cached_steps_per_s", med["cached"],
         med["prefetch"] / med["cached"], ">= 0.9"),
        ("prefetch_steps_per_s", med["prefetch"], "no_prefetch_steps_per_s", med["no_prefetch"],
         med["prefetch"] / med["no_prefetch"], "reported"),
        ("unpaced_prefetch_steps_per_s", med["prefetch_unpaced"], "unpaced_no_prefetch_steps_per_s",
         med["no_prefetch_unpaced"], med["prefetch_unpaced"] / med["no_prefetch_unpaced"], "reported"),
    ]
    print(f"series {args.steps} x {n}^3 float32 ({step_bytes / 1e6:.1f} MB a step), budget {budget / 1e6:.1f} MB, "
          f"{args.size}^2 frames, a step shown for {period * 1e3:.0f} ms, median of {args.repeat}")
    for k, v in med.items():
        print(f"  {k:12s} {v:6.2f} steps/s")
    for r in rows:
        print(f"  {r[0]} / {r[2]} = {r[4]:.2f} (target {r[5]})")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    with open(args.out_dir / "bench_timeseries.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["metric", "value", "reference", "reference_value", "ratio", "target"])
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
