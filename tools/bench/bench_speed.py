"""The frame and loading targets, measured in one run: the full-resolution frame against a plain
one-texture caster, and the paging path against the decode floor.

Both halves reuse the benchmarks that explain them (``tools/bench/bench_render.py`` for the frame,
``tools/bench/bench_integrity.py`` for paging); this script only puts them in one process, one after the
other, and prints each figure beside its target:

* **frame** - clipvol's full-resolution frame (``policy="fixed", level=0``, the default
  ``path="auto"``: what a user gets) of ``procedural:fractal?size=N`` (float32, 64³ bricks, the
  volume filling a ``--size``² view, step 0.5, ``bone`` table) divided by :class:`RawCaster`'s frame
  of the same volume, view, step and table: interleaved rounds, medians, wall and process CPU. The
  raw caster is timed at two stops: its own (``RAW_OPAQUE`` 0.9995) and where
  clipvol stops (``OPAQUE``, 1 - 0.5/255), so the second ratio shows what the shader and the frame
  around it cost when both do exactly the same samples. Target: <= 1 against the first.
* **paging** - ``ZarrLoader.read_brick_into`` with its checksum and statistics checks (the default)
  on the bricks of a 256x512x512 float32 fractal store (cached under ``bench-data/``), 2 threads,
  against the floor (file read + ``numcodecs`` decode of the same bricks on as many threads), and a
  ``ClipTexture`` filled by its own loader threads against the same floor. Throughput ratios (> 1:
  faster than the floor); targets >= 0.85 (loader) and >= 0.8 (fill).

Run ``python tools/bench/bench_speed.py`` (about 3 minutes on 2 cores; ``--quick``: 128³ frame
and a 128³ store, seconds). Writes ``tools/bench/results/bench_speed.csv`` (``--out``).
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench_integrity import FULL, QUICK, _chunk_path, chunk_keys, cliptexture_fill, interleaved_loads  # noqa: E402
from common import DATA, RESULTS, fractal_store, raw_runs  # noqa: E402  (tools/bench/common.py)

FRAME_TARGET = 1.0
LOADER_TARGET = 0.85
FILL_TARGET = 0.8


def frame_rows(sizes, image: int, repeat: int, step: float, log=print) -> list[tuple]:
    """Per size: the full-resolution frame (default path) over the raw caster at both stops."""
    from clipvol.render.action import ClipRenderAction

    def make(ctx, n, clip, common):
        return {"full resolution": ClipRenderAction(ctx, clip, **common)}

    rows = []
    for n, actions, mw, mc in raw_runs(sizes, image, repeat, step, make):
        drawn = actions["full resolution"].path_drawn
        k = "full resolution"
        log(f"{n}^3 at {image}^2, median of {repeat}: frame {mw[k]:.3f} s ({drawn}), raw caster {mw['raw']:.3f} s, "
            f"at clipvol's stop {mw['raw_same_stop']:.3f} s")
        rows += [
            (f"frame {n}^3 / raw caster, wall", round(mw[k] / mw["raw"], 3), f"<= {FRAME_TARGET}",
             f"full-resolution frame ({drawn} path) / RawCaster stopping at 0.9995 (its own stop)"),
            (f"frame {n}^3 / raw caster, CPU", round(mc[k] / mc["raw"], 3), f"<= {FRAME_TARGET}", "process CPU time"),
            (f"frame {n}^3 / raw caster at clipvol's stop, wall", round(mw[k] / mw["raw_same_stop"], 3), "-",
             "the same caster stopping where clipvol stops: the shader and the frame around it"),
            (f"frame {n}^3 / raw caster at clipvol's stop, CPU", round(mc[k] / mc["raw_same_stop"], 3), "-", ""),
        ]
    return rows


def paging_rows(cfg: dict, rounds: int, threads: int, data_dir: Path, log=print) -> list[tuple]:
    """The default loader and a clip-texture fill against the decode floor, on the same bricks."""
    from clipvol.loaders.zarr_store import ZarrLoader

    store = fractal_store(cfg["size"], int(cfg["brick"]), data_dir)
    loader = ZarrLoader(store)  # the defaults: checksum and statistics checks on
    keys = chunk_keys(store, loader.pyramid.num_levels)
    for k in keys:  # the page cache warm: every path reads from memory
        Path(_chunk_path(store, *k)).read_bytes()
    loader.brick_statistics(0)
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(time.sleep, [0.01] * threads))
        wall, cpu = interleaved_loads(store, keys, {"loader": loader}, rounds, pool)
        fill = cliptexture_fill(store, threads, rounds, pool)
    # throughput ratios: the floor's time over the loader's (best round for wall: other processes
    # only ever add time; median for thread CPU)
    lw = min(wall["floor"]) / min(wall["loader"])
    lc = statistics.median(cpu["floor"]) / statistics.median(cpu["loader"])
    log(f"paging: loader {lw:.2f}x the floor (wall), {lc:.2f}x (CPU); clip-texture fill {fill['wall_ratio']:.2f}x "
        f"(wall), {len(keys)} bricks, {rounds} rounds")
    return [
        ("loader / decode floor, CPU", round(lc, 3), f">= {LOADER_TARGET}",
         f"ZarrLoader (checksum + statistics) / file read + numcodecs decode; {threads} threads, median round"),
        ("loader / decode floor, wall", round(lw, 3), f">= {LOADER_TARGET}", "best round"),
        ("clip-texture fill / decode floor, wall", round(fill["wall_ratio"], 3), f">= {FILL_TARGET}",
         "ClipTexture filled by its own loader threads; best round"),
        ("clip-texture fill / decode floor, CPU", round(fill["cpu_ratio"], 3), "-", "process CPU"),
    ]


def met(value: float, target: str) -> str:
    if target.startswith("<="):
        return "yes" if value <= float(target[2:]) else "no"
    if target.startswith(">="):
        return "yes" if value >= float(target[2:]) else "no"
    return ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="256,512", help="edges of the fractal volumes drawn (default 256,512)")
    ap.add_argument("--size", type=int, default=512, help="image edge in pixels (default 512)")
    ap.add_argument("--repeat", type=int, default=11, help="interleaved frame rounds (median)")
    ap.add_argument("--step", type=float, default=0.5)
    ap.add_argument("--rounds", type=int, default=15, help="interleaved paging rounds")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="a 128^3 frame at 256^2 and a 128^3 store: a smoke run")
    ap.add_argument("--data-dir", type=Path, default=DATA)
    ap.add_argument("--out", type=Path, default=None, help="CSV (default tools/bench/results/bench_speed.csv; --quick: bench-data/)")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.size, args.repeat, args.rounds = "128", 256, 3, 3
    out = args.out or (args.data_dir / "bench_speed_quick.csv" if args.quick else RESULTS / "bench_speed.csv")
    sizes = [int(s) for s in args.sizes.split(",")]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    rows = frame_rows(sizes, args.size, args.repeat, args.step)
    rows += paging_rows(dict(QUICK if args.quick else FULL), args.rounds, args.threads, args.data_dir)
    rows.append(("run", round(time.perf_counter() - t0, 1), "s",
                 f"one process; load average {load:.2f} at the start, {os.getloadavg()[0]:.2f} at the end"))
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["metric", "value", "target", "met", "note"])
        for name, value, target, note in rows:
            w.writerow([name, value, target, met(value, target), note])
    for name, value, target, note in rows:
        print(f"{name:>48}: {value} {target} {met(value, target)}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
