"""Per-brick statistics stored beside the pyramid (``clipvol_stats/<level>/``).

A renderer skips bricks that the transfer function makes fully transparent from ``min``/``max``
alone, and image-based level-of-detail (Wang, Garcia & Shen 2007) estimates a brick's error from its histogram,
both without reading the brick. The definitions, all over the brick's *valid* voxels (an edge
brick's padding is not counted):

* ``min``, ``max``, ``mean``, ``std`` (population, ``ddof=0``) over finite values, float64;
  NaN when the brick has no finite value;
* ``nan_count``, ``inf_count``: int64 counts;
* ``histogram``: 64 bins, exactly ``numpy.histogram(v, bins=64, range=(lo, hi))`` of the
  non-NaN values ``v`` taken as float64 and clipped to ``[lo, hi]`` (so ``-inf``/``+inf`` land
  in the first/last bin), where ``(lo, hi)`` is the finite value range of level 0 (the store's
  ``value_range``; a zero-width range is widened by 0.5 either side, as numpy does).

Why a lookup table: for 8- and 16-bit integers one ``bincount`` over the brick gives all the
numbers above in a single pass after a (SIMD-fast) min/max: moments from the value counts, the 64
bins by summing the counts through a value-to-bin table. That keeps the statistics cheaper than compression, which
the bricking throughput target needs. Wider integers and floats use numpy reductions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .store import HIST_BINS

__all__ = ["BrickStats", "StatsComputer", "histogram_edges", "finite_range"]


def histogram_edges(lo: float, hi: float, bins: int = HIST_BINS) -> np.ndarray:
    """The bin edges ``numpy.histogram`` uses for ``range=(lo, hi)`` (float64)."""
    lo, hi = float(lo), float(hi)
    if lo == hi:
        lo, hi = lo - 0.5, hi + 0.5
    return np.linspace(lo, hi, bins + 1, endpoint=True, dtype=np.float64)


def finite_range(block: np.ndarray) -> tuple[float, float] | None:
    """``(min, max)`` of the finite values of ``block``, or None if it has none."""
    if block.size == 0:
        return None
    if block.dtype.kind != "f":
        return float(block.min()), float(block.max())
    fin = np.isfinite(block)
    if fin.all():
        return float(block.min()), float(block.max())
    vals = block[fin]
    if vals.size == 0:
        return None
    return float(vals.min()), float(vals.max())


@dataclass(frozen=True, slots=True)
class BrickStats:
    """Statistics of one brick (see the module docstring for the definitions)."""

    min: float
    max: float
    mean: float
    std: float
    nan_count: int
    inf_count: int
    histogram: np.ndarray  # (bins,) int64


class StatsComputer:
    """Computes :class:`BrickStats` for one dtype and one global value range; thread-safe.

    Parameters
    ----------
    dtype : numpy.dtype
        The pyramid's dtype.
    value_range : (float, float)
        Finite ``(min, max)`` of level 0: the histogram's range.
    bins : int
        Number of histogram bins.
    """

    def __init__(self, dtype, value_range: tuple[float, float], bins: int = HIST_BINS) -> None:
        self.dtype = np.dtype(dtype)
        self.bins = int(bins)
        self.value_range = (float(value_range[0]), float(value_range[1]))
        self.edges = histogram_edges(*self.value_range, self.bins)
        self._lut = None
        if self.dtype.kind in "iu" and self.dtype.itemsize <= 2:
            info = np.iinfo(self.dtype)
            self._offset = -int(info.min)
            values = np.arange(int(info.min), int(info.max) + 1, dtype=np.float64)
            idx = np.searchsorted(self.edges, np.clip(values, self.edges[0], self.edges[-1]), side="right") - 1
            self._lut = np.clip(idx, 0, self.bins - 1).astype(np.intp)

    def compute(self, block: np.ndarray) -> BrickStats:
        """Statistics of ``block`` (the brick's valid voxels)."""
        if self._lut is not None:
            return self._from_counts(block)
        return self._generic(block)

    def _from_counts(self, block: np.ndarray) -> BrickStats:
        flat = block.reshape(-1)
        n = int(flat.size)
        lo, hi = int(flat.min()), int(flat.max())
        if lo == hi:
            hist = np.zeros(self.bins, dtype=np.int64)
            hist[self._lut[lo + self._offset]] = n
            return BrickStats(float(lo), float(hi), float(lo), 0.0, 0, 0, hist)
        if self.dtype.kind == "u":
            shifted = flat - flat.dtype.type(lo)  # stays in range: no overflow
        else:
            shifted = flat.astype(np.int32) - lo
        counts = np.bincount(shifted, minlength=hi - lo + 1)
        nz = np.flatnonzero(counts)
        c = counts[nz].astype(np.float64)
        v = nz.astype(np.float64) + lo
        # plain ufunc sums, not np.dot: BLAS called from several threads at once spins its own
        # thread pool and slows everything down
        mean = float((c * v).sum() / n)
        d = v - mean
        std = float(np.sqrt((c * d * d).sum() / n))
        hist = np.bincount(self._lut[nz + (lo + self._offset)], weights=c, minlength=self.bins).astype(np.int64)
        return BrickStats(float(lo), float(hi), mean, std, 0, 0, hist)

    def _generic(self, block: np.ndarray) -> BrickStats:
        lo, hi = self.edges[0], self.edges[-1]
        nan_count = inf_count = 0
        if block.dtype.kind == "f":
            fin = np.isfinite(block)
            nfin = int(np.count_nonzero(fin))
            if nfin == block.size:
                vals = block.astype(np.float64).reshape(-1)
                hvals = vals
            else:
                nan = np.isnan(block)
                nan_count = int(np.count_nonzero(nan))
                inf_count = int(block.size - nfin - nan_count)
                vals = block[fin].astype(np.float64)
                hvals = block[~nan].astype(np.float64)
        else:
            vals = block.astype(np.float64).reshape(-1)
            hvals = vals
        hist = np.histogram(np.clip(hvals, lo, hi), bins=self.bins, range=(lo, hi))[0].astype(np.int64)
        if vals.size == 0:
            return BrickStats(np.nan, np.nan, np.nan, np.nan, nan_count, inf_count, hist)
        if block.dtype.kind in "iu":  # exact extremes even where float64 rounds (64-bit ints)
            vmin, vmax = float(block.min()), float(block.max())
        else:
            vmin, vmax = float(vals.min()), float(vals.max())
        return BrickStats(vmin, vmax, float(vals.mean()), float(vals.std()), nan_count, inf_count, hist)
