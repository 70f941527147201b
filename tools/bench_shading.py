"""Benchmark: the cost of gradient lighting (the ``SHADING`` shader variant).

``python tools/bench_shading.py --sizes 128,256 --image 256 --repeat 5``

For each volume (``procedural:fractal?size=N``, float32, generated in memory, 64^3 bricks, all
of level 0 drawn), one view that the volume fills, the ``bone`` table, step 0.5: frame times of

* ``raw``: :class:`bench_render.RawCaster`, a plain one-texture ray caster (about 30 lines of GLSL,
  unlit) written for the benchmarks, outside clipvol's render path - the baseline;
* clipvol unlit and lit (``shading=True``), in the per-brick and the single-pass paths.

Rounds are interleaved (the shared machine's load hits every configuration alike); medians of
wall-clock and of process CPU time (all llvmpipe threads). Printed and written to
``docs/bench_shading.csv``: every time as a ratio to the raw caster's, and lit / unlit per path.
A lit sample reads the data 7 times (the sample and six central-difference neighbours), so the
ratio lit / unlit is expected to be well above 1 on a CPU rasteriser.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import RawCaster, fractal_scene, interleaved_medians, write_rows  # noqa: E402  (RawCaster: the baseline outside clipvol's render path)

REPO = Path(__file__).resolve().parent.parent


def run(sizes, image: int, repeat: int, step: float, log=print) -> list[dict]:
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction

    ctx = create_context()
    rows = []
    for n in sizes:
        vol, loader, cam, tf, budget, clip = fractal_scene(n, image)
        pyr = loader.pyramid
        common = dict(policy="fixed", level=0, step=step, texture_budget=budget)
        actions = {f"{path} {'lit' if lit else 'unlit'}": ClipRenderAction(ctx, clip, path=path, shading=lit, **common)
                   for path in ("bricks", "single-pass") for lit in (False, True)}
        raw = RawCaster(ctx, vol, pyr.value_range)
        mw, mc = interleaved_medians(raw, actions, cam, tf, step, repeat)
        row = dict(size=n, image=image, repeat=repeat, raw_s=round(mw["raw"], 4), raw_cpu_s=round(mc["raw"], 4))
        for k in actions:
            key = k.replace(" ", "_").replace("-", "_")
            row[f"{key}_s"] = round(mw[k], 4)
            row[f"{key}_over_raw"] = round(mw[k] / mw["raw"], 3)
            row[f"{key}_cpu_over_raw"] = round(mc[k] / mc["raw"], 3)
        for path in ("bricks", "single-pass"):
            key = path.replace("-", "_")
            row[f"{key}_lit_over_unlit"] = round(mw[f"{path} lit"] / mw[f"{path} unlit"], 3)
            row[f"{key}_lit_over_unlit_cpu"] = round(mc[f"{path} lit"] / mc[f"{path} unlit"], 3)
        log(f"{n}^3 at {image}^2, median of {repeat}: raw {mw['raw']:.3f} s; " + "; ".join(
            f"{k} {mw[k]:.3f} s = {mw[k] / mw['raw']:.2f}x raw (CPU {mc[k] / mc['raw']:.2f}x)" for k in actions))
        log("  lit / unlit: " + ", ".join(f"{p} {row[p.replace('-', '_') + '_lit_over_unlit']:.2f}x wall, "
                                           f"{row[p.replace('-', '_') + '_lit_over_unlit_cpu']:.2f}x CPU"
                                           for p in ("bricks", "single-pass")))
        rows.append(row)
        for a in actions.values():
            a.close()
        raw.release()
        clip.close()
    ctx.release()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128,256", help="volume edge lengths N (comma-separated)")
    ap.add_argument("--image", type=int, default=256, help="image edge in pixels")
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds (medians)")
    ap.add_argument("--step", type=float, default=0.5)
    ap.add_argument("--out", default=str(REPO / "docs" / "bench_shading.csv"))
    args = ap.parse_args(argv)
    rows = run([int(s) for s in args.sizes.split(",")], args.image, args.repeat, args.step)
    write_rows(args.out, rows)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
