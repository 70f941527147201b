"""Benchmark: the cost of gradient lighting (the ``SHADING`` shader variant).

``python tools/bench_shading.py --sizes 128,256 --image 256 --repeat 5``

For each volume (``procedural:fractal?size=N``, float32, generated in memory, 64^3 bricks, all
of level 0 drawn), one view that the volume fills, the ``bone`` table, step 0.5: frame times of

* ``raw``: :class:`bench_render.RawCaster`, a plain one-texture ray caster (about 30 lines of GLSL,
  unlit) written for the benchmarks, outside clipvol's render path - the baseline;
* clipvol unlit and lit (``shading=True``), in the per-brick and the single-pass paths.

Rounds are interleaved (the shared machine's load hits every configuration alike); medians of
wall-clock and of process CPU time (all llvmpipe threads). Printed and written to
``tools/bench/results/bench_shading.csv``: every time as a ratio to the raw caster's, and lit / unlit per path.
A lit sample reads the data 7 times (the sample and six central-difference neighbours), so the
ratio lit / unlit is expected to be well above 1 on a CPU rasteriser.
"""

from __future__ import annotations



# raw_runs times every configuration against RawCaster, the baseline outside clipvol's render path
from common import RESULTS, ratio_columns, raw_ratio_line, raw_runs, sizes_main  # noqa: E402  (tools/bench/common.py)


def run(sizes, image: int, repeat: int, step: float, log=print) -> list[dict]:
    from clipvol.render.action import ClipRenderAction

    def make_actions(ctx, n, clip, common):
        return {f"{path} {'lit' if lit else 'unlit'}": ClipRenderAction(ctx, clip, path=path, shading=lit, **common)
                for path in ("bricks", "single-pass") for lit in (False, True)}

    rows = []
    for n, actions, mw, mc in raw_runs(sizes, image, repeat, step, make_actions):
        row = dict(size=n, image=image, repeat=repeat, raw_s=round(mw["raw"], 4), raw_cpu_s=round(mc["raw"], 4),
                   **ratio_columns(mw, mc, actions))
        for path in ("bricks", "single-pass"):
            key = path.replace("-", "_")
            row[f"{key}_lit_over_unlit"] = round(mw[f"{path} lit"] / mw[f"{path} unlit"], 3)
            row[f"{key}_lit_over_unlit_cpu"] = round(mc[f"{path} lit"] / mc[f"{path} unlit"], 3)
        log(f"{n}^3 at {image}^2, median of {repeat}: " + raw_ratio_line(mw, mc, actions))
        log("  lit / unlit: " + ", ".join(f"{p} {row[p.replace('-', '_') + '_lit_over_unlit']:.2f}x wall, "
                                           f"{row[p.replace('-', '_') + '_lit_over_unlit_cpu']:.2f}x CPU"
                                           for p in ("bricks", "single-pass")))
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    return sizes_main(argv, __doc__, run, RESULTS / "bench_shading.csv", "volume edge lengths N (comma-separated)")


if __name__ == "__main__":
    raise SystemExit(main())
