"""Benchmark: the cost of an overlay (the ``OVERLAY`` shader variant) against the single volume.

``python tools/bench_overlay.py --sizes 128,256 --image 256 --repeat 5``

For each primary (``procedural:fractal?size=N``, float32, in memory, 64^3 bricks, all of level 0
drawn, the ``bone`` table, step 0.5, one view the volume fills) and one overlay: a signed smooth
map of ``N/2`` voxels per axis at twice the primary's voxel size, shifted by a quarter of the
volume (a statistical map: another shape, spacing and origin), drawn with the ``diverging`` table.
Frame times of

* ``raw``: :class:`bench_render.RawCaster`, the plain one-texture ray caster written for the
  benchmarks outside clipvol's render path - the baseline;
* clipvol's per-brick path without and with the overlay (one and two overlays, sampled
  ``classified``, the default: 8 voxels looked up in the table a sample), the one overlay sampled
  ``interpolated`` (one filtered read, one lookup), a map of the clinical kind (the blobs clipped
  into plateaus at +-3, zeros elsewhere: uniform neighbourhoods take one lookup) sampled either
  way, with a label overlay instead (the map
  thresholded into 8 ids, nearest ids through a colour table), and with the overlay blended
  additively (``blend="additive"``, sampled ``interpolated``, as channels are).

Rounds are interleaved (the shared machine's load hits every configuration alike); medians of
wall-clock and of process CPU time. Printed and written to ``tools/bench/results/bench_overlay.csv``: every time
as a ratio to the raw caster's, and overlay / single volume.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
# raw_runs times every configuration against RawCaster, the baseline outside clipvol's render path
from common import RESULTS, ratio_columns, raw_ratio_line, raw_runs, sizes_main  # noqa: E402  (tools/bench/common.py)


def _signed_map(n: int, seed: int) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    v = gaussian_filter(np.random.default_rng(seed).standard_normal((n, n, n)), 3.0)
    return (6.0 * v / np.abs(v).max()).astype(np.float32)


def _clipped_map(n: int, seed: int) -> np.ndarray:
    """A statistical map of the clinical kind: the smooth map's blobs clipped at +-3 (plateaus), zeros elsewhere."""
    v = _signed_map(n, seed)
    return np.where(np.abs(v) > 1.5, np.clip(2.0 * v, -3.0, 3.0), 0.0).astype(np.float32)


def run(sizes, image: int, repeat: int, step: float, log=print) -> list[dict]:
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.label_colors import LabelColors
    from clipvol.scene.overlay import Overlay
    from clipvol.scene.transfer import TransferFunction

    def make_actions(ctx, n, clip, common):
        m = n // 2
        ovs = [Overlay(NumpyLoader(_signed_map(m, s), brick=64, spacing=(2.0, 2.0, 2.0)),
                       TransferFunction.preset("diverging", value_range=(-3.0, 3.0)), origin=(n / 4.0,) * 3,
                       name=f"map{s}") for s in (1, 2)]
        ids = np.digitize(_signed_map(m, 1), [-4, -2, -1, 0, 1, 2, 4]).astype(np.uint16)  # 8 labels
        lab = Overlay(NumpyLoader(ids, brick=64, spacing=(2.0, 2.0, 2.0), value_range=(0.0, 7.0)), LabelColors(),
                      origin=(n / 4.0,) * 3, name="labels")
        interp = Overlay(ovs[0].loader, ovs[0].tf, origin=ovs[0].origin, name="map1", sampling="interpolated")
        clipped = {smp: Overlay(NumpyLoader(_clipped_map(m, 1), brick=64, spacing=(2.0, 2.0, 2.0)),
                                TransferFunction.preset("diverging", value_range=(-3.0, 3.0)), origin=(n / 4.0,) * 3,
                                name=f"clipped {smp}", sampling=smp) for smp in ("classified", "interpolated")}
        return {"single": ClipRenderAction(ctx, clip, **common),
                "1 overlay": ClipRenderAction(ctx, clip, overlays=tuple(ovs[:1]), **common),
                "1 overlay interpolated": ClipRenderAction(ctx, clip, overlays=(interp,), **common),
                "1 clipped map": ClipRenderAction(ctx, clip, overlays=(clipped["classified"],), **common),
                "1 clipped map interpolated": ClipRenderAction(ctx, clip, overlays=(clipped["interpolated"],), **common),
                "2 overlays": ClipRenderAction(ctx, clip, overlays=tuple(ovs), **common),
                "label overlay": ClipRenderAction(ctx, clip, overlays=(lab,), **common),
                "1 overlay additive": ClipRenderAction(ctx, clip, overlays=(interp,), blend="additive", **common)}

    rows = []
    for n, actions, mw, mc in raw_runs(sizes, image, repeat, step, make_actions):
        m = n // 2
        row = dict(size=n, overlay_size=m, image=image, repeat=repeat, raw_s=round(mw["raw"], 4),
                   **ratio_columns(mw, mc, actions))
        extra = ("1 overlay", "1 overlay interpolated", "1 clipped map", "1 clipped map interpolated", "2 overlays",
                 "label overlay", "1 overlay additive")
        for k in extra:
            key = k.replace(" ", "_")
            row[f"{key}_over_single"] = round(mw[k] / mw["single"], 3)
            row[f"{key}_over_single_cpu"] = round(mc[k] / mc["single"], 3)
        log(f"{n}^3 (+ {m}^3 overlays) at {image}^2, median of {repeat}: " + raw_ratio_line(mw, mc, actions))
        log("  ÷ single volume: " + ", ".join(f"{k} {row[k.replace(' ', '_') + '_over_single']:.2f}x wall, "
                                              f"{row[k.replace(' ', '_') + '_over_single_cpu']:.2f}x CPU"
                                              for k in extra))
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    return sizes_main(argv, __doc__, run, RESULTS / "bench_overlay.csv", "primary edge lengths N (comma-separated)")


if __name__ == "__main__":
    raise SystemExit(main())
