"""Where a slice's coarser data looks the same: per brick, how far its colours are from level 0's.

Why: a multiresolution slice (:mod:`clipvol.scene.slice_cover`) decides by distance alone - within
reach of the point of interest it reads level 0 whatever the data looks like. Where the data is
smooth, or the colour map flat over its values, a coarser brick draws the same picture for an
eighth of the bytes (and its parent for a 64th). The store's summary tables
(:mod:`clipvol.bricking.summary`, after Wang, Garcia & Shen 2007) already pair every voxel with the
parent voxel above it; under the slice's colours those pairs say, without reading a voxel, how far
a coarser brick's picture is from the finer one's. Slices are opaque: a colour map is a grey
window ``(center, width)`` or a transfer function's colours, no alpha. Pure numpy.

The rule
--------
* **Per code bin, a colour box.** The tables hold 256 codes of the store's
  :class:`~clipvol.bricking.summary.Quantiser`. An 8-bit store's code is its value (exact); any other
  store's code is a bin of 1/256 of its value range, and a narrow window can spread one bin over
  many grey levels. Each bin's colours are sampled at :data:`BIN_SAMPLES` evenly spaced values from
  its lower to its upper edge, and the CIE L*u*v* box around them stands for the bin.
* **Per pair of codes, the farthest colours.** ``Delta E(k, l)`` is the largest distance between a
  point of bin ``k``'s box and one of bin ``l``'s (per channel the larger of ``hi_k - lo_l`` and
  ``hi_l - lo_k``): no value of either bin can be farther apart, so a wide bin cannot hide a
  difference the window shows.
* **Per child brick, the largest.** ``D(c)`` is the largest ``Delta E`` over the brick's (parent
  code, child code, count) pairs (:data:`QUANTILE` 1; :func:`brick_differences` takes any quantile,
  weighted by the counts): every voxel of the brick stays within ``D`` of the parent voxel above it.
  A high quantile instead (99 %) lets a feature under 1 % of a brick's voxels - one vessel through
  a 64³ brick is 0.02 % of it - leave no trace in ``D``: the slice would draw the parent, and the
  vessel would be gone from a plane through it. With the largest, a coarser brick stands in only
  where no voxel beneath it changes colour by more than the tolerance.
* **Bottom-up, the worst accumulated difference.** ``E(b) = max over children c of (E(c) + D(c))``,
  ``E = 0`` at level 0: how far drawing ``b``'s data can be from the level-0 data beneath it (a
  brick drawn two levels up pays both levels). ``E`` grows towards the root, so the bricks that may
  stand for their children (``E <= tol``) are closed under descent, and removing their children
  from a cover leaves a tree.

:func:`stand_ins` turns the errors into the per-level masks the cover reads
(:func:`~clipvol.scene.slice_cover.slice_cover`'s ``stand_in``). The default tolerance
:data:`DEFAULT_TOL` is measured (``docs/benchmarks.md``, "A slice reads coarser data where the colours
cannot tell").

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007 (the summary tables).
E. LaMar, B. Hamann, K. I. Joy, "Multiresolution cutting planes" (the slice's cover).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ..bricking.summary import SUMMARY_BINS, Quantiser, SummaryTables
from ..errors import ParameterError
from .metrics import rgb_to_luv

__all__ = ["BIN_SAMPLES", "QUANTILE", "DEFAULT_TOL", "window_grey", "grey_window_colours", "bin_colour_boxes",
           "code_distances", "brick_differences", "accumulated_errors", "stand_ins"]

#: values sampled per code bin (edges included) for its colour box: a transfer function's table of
#: 256 entries over the value range changes slope at most twice inside one of 256 bins
BIN_SAMPLES = 17
#: the share of a brick's voxels whose colour difference ``D`` bounds: all of them (see the module
#: docstring: a thin feature must not hide in the rest of a quantile)
QUANTILE = 1.0
#: the default tolerance in CIELUV Delta E (``SliceAction.exact_tol``): below the Delta E of 6 the
#: benchmarks count as visible, with room for what the voxel pairs do not see (trilinear
#: interpolation between the coarser voxels). Measured in docs/benchmarks.md, "A slice reads coarser
#: data where the colours cannot tell"
DEFAULT_TOL = 4.0


def window_grey(values: np.ndarray, center: float, width: float) -> np.ndarray:
    """Grey level in ``[0, 1]`` of ``values`` for a window ``center``/``width`` (``C - W/2`` black,
    ``C + W/2`` white; NaN stays NaN): the slice's grey map before its 8-bit rounding."""
    if not (math.isfinite(center) and math.isfinite(width) and width > 0):
        raise ParameterError(f"window: expected a finite centre and a width > 0, got {center!r}, {width!r}")
    v = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.clip((v - (center - width / 2.0)) / width, 0.0, 1.0)


def grey_window_colours(center: float, width: float) -> Callable[[np.ndarray], np.ndarray]:
    """The colours ``(..., 3)`` RGB in ``[0, 1]`` a grey window gives values, as a colour map for
    :func:`bin_colour_boxes` (8-bit rounded, as the slice's read-back maps them)."""
    window_grey(np.zeros(1), center, width)  # checks the window

    def colours(values: np.ndarray) -> np.ndarray:
        g = np.rint(window_grey(values, center, width) * 255.0) / 255.0
        return np.repeat(g[..., None], 3, axis=-1)

    return colours


def bin_colour_boxes(quantiser: Quantiser, colours: Callable[[np.ndarray], np.ndarray],
                     samples: int = BIN_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)``, each ``(256, 3)``: per code of ``quantiser`` the CIE L*u*v* box of the colours
    ``colours(values) -> (..., 3)`` RGB gives the values of its bin (one value per code for the
    identity quantiser; ``samples`` evenly spaced values from edge to edge otherwise)."""
    if quantiser.method == "identity":
        t = np.zeros(1)
        values = np.arange(SUMMARY_BINS, dtype=np.float64)[:, None] + t[None, :]
    else:
        t = np.linspace(0.0, 1.0, int(samples))
        step = (quantiser.hi - quantiser.lo) / SUMMARY_BINS
        values = quantiser.lo + (np.arange(SUMMARY_BINS, dtype=np.float64)[:, None] + t[None, :]) * step
    luv = rgb_to_luv(np.asarray(colours(values), dtype=np.float64))  # (256, s, 3)
    return luv.min(axis=1), luv.max(axis=1)


def code_distances(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``(256 * 256,)`` the largest Delta E between a colour of bin ``k``'s box and one of bin
    ``l``'s, at ``k * 256 + l`` (a pair code of the summary tables)."""
    far = np.maximum(hi[:, None, :] - lo[None, :, :], hi[None, :, :] - lo[:, None, :])
    return np.sqrt(np.sum(np.maximum(far, 0.0) ** 2, axis=-1)).reshape(-1)


def brick_differences(tables: SummaryTables, level: int, dist: np.ndarray, quantile: float = QUANTILE) -> np.ndarray:
    """``(n_bricks,)`` per (flat) brick of ``level`` (below the top): ``D``, the ``quantile`` of the
    pairs' Delta E (``dist`` by pair code) weighted by their counts; 0 for a brick without pairs."""
    off = tables.pairs_offsets[level]
    n = len(off) - 1
    out = np.zeros(n)
    if off[-1] == 0:
        return out
    code = tables.pairs_code[level].astype(np.int64)
    d = dist[code]
    if float(quantile) >= 1.0:  # the largest (the default): one pass, no sort - a window being dragged
        some = np.nonzero(np.diff(off) > 0)[0]  # re-evaluates this per window (10^7 pairs: ~0.1 s, not 1.1 s)
        out[some] = np.maximum.reduceat(np.where(tables.pairs_count[level] > 0, d, 0.0), off[some])
        return out
    owner = np.repeat(np.arange(n, dtype=np.int64), np.diff(off))
    w = tables.pairs_count[level].astype(np.float64)
    # by brick, then by Delta E: one integer key (a pair code's rank in Delta E order), a quarter of
    # a two-key lexsort's time (a window being dragged re-evaluates this per window)
    rank = np.empty(len(dist), dtype=np.int64)
    rank[np.argsort(dist, kind="stable")] = np.arange(len(dist))
    order = np.argsort(owner * len(dist) + rank[code])
    cum = np.cumsum(w[order])
    total = np.bincount(owner, weights=w, minlength=n)
    before = np.concatenate([[0.0], np.cumsum(total)[:-1]])
    some = np.nonzero(total > 0)[0]
    # the first pair (in Delta E order) at which the brick's count reaches the quantile of its total
    pos = np.searchsorted(cum, before[some] + float(quantile) * total[some] - 1e-9 * total[some], side="left")
    out[some] = d[order][np.minimum(pos, len(cum) - 1)]
    return out


def accumulated_errors(tables: SummaryTables, colours: Callable[[np.ndarray], np.ndarray], *,
                       quantile: float = QUANTILE) -> list[np.ndarray]:
    """Per level, grid-shaped: ``E``, the worst accumulated colour difference of drawing a brick's
    data over the level-0 data beneath it (the module docstring's rule; 0 at level 0)."""
    if not 0.0 < float(quantile) <= 1.0:
        raise ParameterError(f"quantile: expected a share in (0, 1], got {quantile!r}")
    pyr = tables.pyramid
    dist = code_distances(*bin_colour_boxes(tables.quantiser, colours))
    errs = [np.zeros(pyr.num_bricks(0))]
    for L in range(1, pyr.num_levels):
        cl = L - 1
        grid = pyr.grid(cl)
        cidx = np.unravel_index(np.arange(pyr.num_bricks(cl)), grid)
        parent = np.ravel_multi_index(tuple(i // 2 for i in cidx), pyr.grid(L))
        e = np.zeros(pyr.num_bricks(L))
        np.maximum.at(e, parent, errs[cl] + brick_differences(tables, cl, dist, quantile))
        errs.append(e)
    return [e.reshape(pyr.grid(L)) for L, e in enumerate(errs)]


def stand_ins(errors: list[np.ndarray], tol: float) -> tuple[np.ndarray, ...]:
    """Per level, grid-shaped bool: the bricks whose data may stand for their children's
    (``E <= tol``); level 0 has no children (all False)."""
    if not (math.isfinite(float(tol)) and float(tol) >= 0.0):
        raise ParameterError(f"tol: expected a Delta E >= 0, got {tol!r}")
    out = [np.zeros(errors[0].shape, dtype=bool)]
    out += [np.asarray(e) <= float(tol) for e in errors[1:]]
    return tuple(out)
