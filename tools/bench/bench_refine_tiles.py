"""Does drawing a refined frame's coarsest pass across four rasteriser tiles pay?

Mesa llvmpipe bins a frame into 64 x 64 tiles and shades each tile on one thread, so the 64² pass
of a 256² refined frame (:mod:`clipvol.render.refine`) would run on one thread while the others
wait. clipvol draws such a pass about the corner of four tiles (:func:`clipvol.render.refine.pass_origin`).
This script times, in one process and interleaved rounds (order reversed on odd rounds, median of
``--repeat``), four frames of each view: the raw one-texture caster (:class:`common.RawCaster`,
step 0.5, clipvol's stop: the reference outside clipvol's render path), the full-resolution frame
(level 0, step 0.5), the refined frame as clipvol draws it, and the same refined frame with every
pass at its target's origin (``pass_origin`` replaced for those calls). Each clipvol frame is
given as a ratio of its time to the raw caster's, the refined ones also as a speed-up over the
full-resolution frame. The two refined frames must be the same image (the largest 8-bit
difference is printed; the rays do not change, only where the pass lies in its target).

Data: the CT-like head 256³ (:func:`common.ct_store`) or ``--store``; ``bone``; the views of
``bench_mission.py``. Rows: ``tools/bench/results/bench_refine_tiles.csv``.
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

import bench_mission  # noqa: E402
import common  # noqa: E402


def run(store: Path, image: int, step: float, tolerance: float, repeat: int, log=print) -> list[dict]:
    import clipvol.render.paths.setup as setup_module
    import clipvol.render.refine as refine_module
    from clipvol.render.paths.setup import OPAQUE

    spread = refine_module.pass_origin

    def at_origin(size):
        return 0, 0

    def use(fn) -> None:  # the module and the draw set-up that imported it by name
        refine_module.pass_origin = fn
        setup_module.pass_origin = fn

    scene = common.WarmScene(store)
    tf = scene.tf
    full = scene.action(policy="fixed", level=0, step=0.5)
    refined = scene.action(policy="fixed", level=0, step=step, refine_tolerance=tolerance)
    raw = scene.raw_caster()
    rows = []
    try:
        for view, cam in bench_mission.views(scene.pyramid, image).items():
            full.render(cam, tf, wait=True, timeout=600)
            fc = full._selection_camera(cam)  # the same depth range as clipvol's frame
            raw.render(fc, tf, 0.5, OPAQUE)
            refined.render(cam, tf, wait=True, timeout=600)
            use(at_origin)
            one = refined.render(cam, tf)
            use(spread)
            four = refined.render(cam, tf)
            frames = {"raw": None, "full": (full, spread), "four tiles": (refined, spread),
                      "one tile": (refined, at_origin)}
            times = {k: [] for k in frames}
            for r in range(repeat):
                for k in (list(frames) if r % 2 == 0 else list(frames)[::-1]):
                    t = time.perf_counter()
                    if k == "raw":
                        raw.render(fc, tf, 0.5, OPAQUE)
                    else:
                        action, fn = frames[k]
                        use(fn)
                        action.render(cam, tf)
                    times[k].append(time.perf_counter() - t)
            use(spread)
            med = {k: statistics.median(v) for k, v in times.items()}

            def paired(ref, k):  # the median over rounds of ref's time over k's, both of one round
                return round(statistics.median(a / b for a, b in zip(times[ref], times[k])), 3)

            row = {"date": time.strftime("%Y-%m-%d"), "store": store.name, "image": image, "view": view,
                   "step": step, "tolerance": tolerance, "rounds": repeat, "raw_ms": round(1e3 * med["raw"], 1),
                   "full_ms": round(1e3 * med["full"], 1), "four_tiles_ms": round(1e3 * med["four tiles"], 1),
                   "one_tile_ms": round(1e3 * med["one tile"], 1),
                   "full_over_raw": round(1.0 / paired("raw", "full"), 3),
                   "four_tiles_over_raw": round(1.0 / paired("raw", "four tiles"), 3),
                   "one_tile_over_raw": round(1.0 / paired("raw", "one tile"), 3),
                   "speedup_four_tiles": paired("full", "four tiles"), "speedup_one_tile": paired("full", "one tile"),
                   "max_abs_diff": int(np.abs(one.astype(np.int16) - four.astype(np.int16)).max())}
            rows.append(row)
            log(f"{image}^2 {view:4}: raw caster {row['raw_ms']} ms; full {row['full_ms']} ms "
                f"({row['full_over_raw']:.2f}x raw); refined across four tiles {row['four_tiles_ms']} ms "
                f"({row['four_tiles_over_raw']:.2f}x raw, {row['speedup_four_tiles']:.2f}x faster than full), "
                f"in one tile {row['one_tile_ms']} ms ({row['one_tile_over_raw']:.2f}x raw, "
                f"{row['speedup_one_tile']:.2f}x); images differ by at most {row['max_abs_diff']}")
    finally:
        use(spread)
        scene.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, default=None, help="a clipvol store (default: the CT-like head 256^3)")
    ap.add_argument("--image", type=int, default=256, help="image edge (default 256: a 64^2 coarsest pass)")
    ap.add_argument("--step", type=float, default=2.0)
    ap.add_argument("--tolerance", type=float, default=0.16)
    ap.add_argument("--repeat", type=int, default=9, help="interleaved rounds, medians taken (>= 5)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_refine_tiles.csv")
    a = ap.parse_args(argv)
    if a.repeat < 5:
        ap.error(f"--repeat: expected at least 5 rounds, got {a.repeat}")
    store = a.store if a.store is not None else common.ct_store("256x256x256", 32)
    rows = run(store, a.image, a.step, a.tolerance, a.repeat)
    return common.save_rows(a.out, rows)


if __name__ == "__main__":
    sys.exit(main())
