"""The spread of a coarse voxel: the standard deviation of the level-0 voxels beneath it.

A coarse voxel of the pyramid is the mean of the voxels beneath it; a transfer function applied to
that mean shows a value none of them has where they differ (bone next to air), so a sharp table
turns thin bright structures into something else level by level. ``clipvol brick`` therefore writes,
beside each level ``L >= 1``, the standard deviation of the level-0 values beneath each voxel (the
``2**L``-cube of level-0 voxels, edge-replicated like the mean filter), and the renderer applies the
transfer function to a distribution of that mean and spread (:mod:`clipvol.scene.consistent`;
Younesy, Möller & Carr, *Improving the quality of multi-resolution volume rendering*, 2006).

Why moments and not the children's spread: the standard deviation of the level-0 values under a
level-2 voxel is not a function of its children's standard deviations alone. The build carries the
first two raw moments of the level-0 values (float64) from level to level - the parent's moments
are the mean of its eight children's, exactly the parallel-variance formula for equal counts - and
derives ``std = sqrt(max(E[x^2] - E[x]^2, 0))`` at each level; only the std is stored.

The stored type (:func:`spread_dtype`) is the level's own for 8- and 16-bit data (a signed type's
unsigned twin: a spread is >= 0), float32 otherwise, so the renderer reads it in the same texel units
as the data (``raw = a * texel``). Rounding to whole numbers costs at most half a unit.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from .pyramid import _pad_even

__all__ = ["SPREAD_GROUP", "spread_dtype", "moments_down", "spread_of", "spread_on_disk"]

#: the store's group holding the spread arrays, one per level >= 1 (``clipvol_spread/<L>``)
SPREAD_GROUP = "clipvol_spread"


def spread_dtype(dtype) -> np.dtype:
    """The stored type of the spread of data of ``dtype``: ``uint8`` for 8-bit, ``uint16`` for
    16-bit integers, ``float16``/``float32`` for those floats, ``float32`` for every other type."""
    dt = np.dtype(dtype)
    if dt.kind in "iu" and dt.itemsize == 1:
        return np.dtype(np.uint8)
    if dt.kind in "iu" and dt.itemsize == 2:
        return np.dtype(np.uint16)
    if dt == np.float16:
        return np.dtype(np.float16)
    return np.dtype(np.float32)


def _mean8(a: np.ndarray, finite_data: bool = False) -> np.ndarray:
    """Mean of each 2x2x2 block of ``a`` (float64, even extents), NaN ignored (all NaN: NaN);
    ``finite_data``: ``a`` is known to hold no NaN (moments of integer data), nothing to check."""
    finite = None if finite_data else np.isfinite(a)
    if finite is None or finite.all():
        s = a[:, :, 0::2] + a[:, :, 1::2]
        s = s[:, 0::2] + s[:, 1::2]
        return (s[0::2] + s[1::2]) / 8.0
    v = np.where(finite, a, 0.0)
    c = finite.astype(np.float64)
    for ax in (2, 1, 0):
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[ax], sl1[ax] = slice(0, None, 2), slice(1, None, 2)
        v = v[tuple(sl0)] + v[tuple(sl1)]
        c = c[tuple(sl0)] + c[tuple(sl1)]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(c > 0, v / np.maximum(c, 1.0), np.nan)


def moments_down(block: np.ndarray, m1: np.ndarray | None = None, m2: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(E[x], E[x^2])`` of the level-0 values beneath each voxel of the next level (float64).

    ``block``: a level's block (its shape decides the padding); ``m1``, ``m2``: that block's own
    moments of level 0 (None at level 0, where they are the values and their squares). Odd extents
    replicate the last voxel (and its moments), as :func:`~clipvol.bricking.pyramid.downsample` does,
    so a block passed slab by slab gives the moments of the whole level."""
    if block.ndim != 3:
        raise ParameterError(f"moments_down: expected a 3-D block, got shape {block.shape}")
    ints = block.dtype.kind in "iub"  # no NaN anywhere: the NaN-aware sums are not needed
    if m1 is None:
        x = block.astype(np.float64)
        with np.errstate(over="ignore", invalid="ignore"):
            m1, m2 = x, x * x
    return (_mean8(_pad_even(np.asarray(m1, dtype=np.float64)), ints),
            _mean8(_pad_even(np.asarray(m2, dtype=np.float64)), ints))


def spread_of(m1: np.ndarray, m2: np.ndarray, dtype) -> np.ndarray:
    """The stored spread (:func:`spread_dtype` of the data's ``dtype``) of moments ``m1``, ``m2``:
    ``sqrt(max(m2 - m1^2, 0))``, rounded and clipped for the integer types; NaN where no value was
    finite is stored as 0 (the NaN-aware renderer classifies such voxels as transparent anyway)."""
    out_t = spread_dtype(dtype)
    with np.errstate(invalid="ignore", over="ignore"):
        var = np.maximum(m2 - m1 * m1, 0.0)
        s = np.sqrt(var)
    s = np.where(np.isfinite(s), s, 0.0)
    if out_t.kind == "u":
        return np.clip(np.rint(s), 0, np.iinfo(out_t).max).astype(out_t)
    return np.clip(s, 0.0, float(np.finfo(out_t).max)).astype(out_t)


def spread_on_disk(path) -> tuple[list[int], int] | None:
    """The levels whose spread arrays the store at ``path`` holds and their bytes on disk, or None
    when it holds none (a store built before them, or by another tool: its coarse levels are
    classified by their mean). Read from the folders, for ``clipvol info``."""
    from pathlib import Path

    from .summary import tree_bytes

    base = Path(path) / SPREAD_GROUP
    levels = sorted(int(d.name) for d in base.iterdir() if d.name.isdigit() and (d / "zarr.json").is_file()) \
        if base.is_dir() else []
    return (levels, tree_bytes(base)) if levels else None
