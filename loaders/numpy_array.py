"""Serve a numpy array or memory-map (or a ``.npy`` file) as a brick pyramid, without bricking it.

For a quick look at data that is already an array: level 0 bricks are slices of the array, and
coarser levels are computed on demand. A brick ``(L, b)`` covers the level-0 region
``[b * B * 2**L, (b + 1) * B * 2**L)`` (clipped to the volume); applying
:func:`clipvol.bricking.pyramid.downsample` ``L`` times to that region gives exactly the brick of the
full-volume recursive down-sample, because the region starts on a multiple of ``2**L`` and has
an even extent at every intermediate level except at the volume's end, where the global
down-sample does the same edge replication. Coarse levels that are small (at most
``cache_bytes`` each) are computed once, whole, by streaming level 0 in aligned slabs, and kept.

Level-0 reads touch only the brick's region, so a memory-map of a file far larger than memory
works; coarse bricks of large levels read ``8**L`` times their size, so for big data run
``clipvol brick`` once and use the zarr loader.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np

from clipvol.bricking.pyramid import (
    FILTERS,
    Int3,
    Pyramid,
    downsample,
    pad_to_brick,
    validate_dtype,
)
from clipvol.errors import InputNotFoundError, ParameterError
from clipvol.paging.readcount import ReadCounter

__all__ = ["NumpyLoader", "finite_range"]

#: bytes of level 0 scanned per step when computing a value range or a whole cached level
SLAB_BYTES = 32 * 2**20


def _slab_steps(shape, itemsize: int, align: int = 1) -> int:
    plane = max(1, shape[1] * shape[2] * itemsize)
    n = max(1, SLAB_BYTES // plane)
    return max(align, n // align * align)


def finite_range(array: np.ndarray) -> tuple[float, float]:
    """``(min, max)`` of the finite values of ``array``, read in slabs (memory-maps stay cheap);
    ``(0.0, 0.0)`` when there is none."""
    lo, hi = math.inf, -math.inf
    step = _slab_steps(array.shape, array.dtype.itemsize) if array.ndim == 3 else max(1, len(array))
    for z in range(0, array.shape[0], step):
        s = np.asarray(array[z:z + step])
        if s.dtype.kind == "f":
            s = s[np.isfinite(s)]
        if s.size:
            lo, hi = min(lo, float(s.min())), max(hi, float(s.max()))
    return (lo, hi) if lo <= hi else (0.0, 0.0)


def _triple(v, name: str, cast=int):
    try:
        t = (cast(v),) * 3 if np.isscalar(v) else tuple(cast(x) for x in v)
    except (TypeError, ValueError):
        t = ()
    if len(t) != 3:
        raise ParameterError(f"{name}: expected a number or three numbers (z, y, x), got {v!r}")
    return t


class NumpyLoader:
    """Loader over an in-memory array, a memory-map, or the path of a ``.npy`` file.

    Parameters
    ----------
    array : ndarray or str or Path
        3-D ``(z, y, x)`` integer or float data; a path is opened with ``np.load(mmap_mode='r')``.
    brick : int or (int, int, int)
        Brick shape.
    spacing : (float, float, float)
        Level-0 voxel size ``(z, y, x)``.
    filter : {'mean', 'max', 'subsample'}
        Down-sampling filter for the coarser levels.
    value_range : (float, float), optional
        Known ``(min, max)``; computed from the finite values of the data when omitted.
    cache_bytes : int
        Coarse levels at most this large are computed whole once and kept.
    """

    def __init__(self, array, brick=64, spacing=(1.0, 1.0, 1.0), filter: str = "mean",
                 value_range: tuple[float, float] | None = None, cache_bytes: int = 16 * 2**20) -> None:
        if isinstance(array, str) and array.startswith("numpy:"):
            array = array[len("numpy:"):]
        if isinstance(array, (str, Path)):
            path = Path(array)
            if not path.is_file():
                raise InputNotFoundError(f"{path}: no such .npy file")
            from clipvol.bricking.npy import open_npy

            array = open_npy(path)
            self.source = str(path)
        else:
            self.source = f"<{type(array).__name__} {getattr(array, 'shape', '?')}>"
        if not isinstance(array, np.ndarray):
            raise ParameterError(f"array: expected a numpy array, memory-map or .npy path, got {type(array).__name__}")
        if array.ndim != 3:
            raise ParameterError(f"array: expected 3 dimensions (z, y, x), got shape {array.shape}")
        if filter not in FILTERS:
            raise ParameterError(f"filter: expected one of {', '.join(FILTERS)}, got {filter!r}")
        dtype = validate_dtype(array.dtype, "array.dtype").newbyteorder("=")
        self.array = array
        if value_range is None:
            value_range = finite_range(array)
        self._pyramid = Pyramid.build(array.shape, _triple(brick, "brick"), _triple(spacing, "spacing", float),
                                      filter, dtype, value_range)
        self.cache_bytes = int(cache_bytes)
        self._levels: dict[int, np.ndarray] = {}
        self._lock = threading.RLock()
        self._nonfinite: bool | None = None
        #: bytes of the source array read to make bricks (counted where the source is sliced)
        self.read_counter = ReadCounter()

    @property
    def pyramid(self) -> Pyramid:
        return self._pyramid

    @property
    def nonfinite(self) -> bool:
        """Whether the array holds NaN or Inf (scanned once in slabs, on first use; integer
        arrays: False without a scan). Lets a renderer pick its NaN-free shader variant."""
        if self._nonfinite is None:
            arr = self.array
            if arr.dtype.kind != "f":
                self._nonfinite = False
            else:
                step = _slab_steps(arr.shape, arr.dtype.itemsize)
                self._nonfinite = any(not np.isfinite(np.asarray(arr[z:z + step])).all()
                                      for z in range(0, arr.shape[0], step))
        return self._nonfinite

    def _cacheable(self, level: int) -> bool:
        return level > 0 and math.prod(self._pyramid.levels[level].shape) * self._pyramid.dtype.itemsize <= self.cache_bytes

    def read_brick(self, level: int, index: Int3) -> np.ndarray:
        """Brick ``index`` of ``level`` (see the module docstring for how coarse levels are made)."""
        pyr = self._pyramid
        index = pyr.check_key(level, index)
        start, stop = pyr.brick_voxel_box(level, index)
        if self._cacheable(level):
            whole = self._whole_level(level)
            block = whole[tuple(slice(a, b) for a, b in zip(start, stop))]
        else:
            f = 1 << level
            sl = tuple(slice(a * f, min(b * f, n)) for a, b, n in zip(start, stop, pyr.shape))
            block = np.asarray(self.array[sl])
            self.read_counter.add(block.nbytes)
            for _ in range(level):
                block = downsample(block, pyr.filter)
        block = np.array(block, dtype=pyr.dtype, copy=True)  # never hand out a view of our data
        return pad_to_brick(block, pyr.brick_shape)

    def _whole_level(self, level: int) -> np.ndarray:
        with self._lock:  # one thread computes; the others wait for the result
            hit = self._levels.get(level)
            if hit is not None:
                return hit
            finer = level - 1
            if finer > 0 and self._cacheable(finer):
                out = downsample(self._whole_level(finer), self._pyramid.filter)
            else:
                out = self._stream_level(level)
            out.setflags(write=False)
            self._levels[level] = out
            return out

    def _stream_level(self, level: int) -> np.ndarray:
        """Level ``level`` whole, from level-0 slabs of a multiple of ``2**level`` planes."""
        f = 1 << level
        step = _slab_steps(self.array.shape, self.array.dtype.itemsize * 8, f)
        parts = []
        for z in range(0, self.array.shape[0], step):
            block = np.asarray(self.array[z:z + step])
            self.read_counter.add(block.nbytes)
            for _ in range(level):
                block = downsample(block, self._pyramid.filter)
            parts.append(block)
        return np.ascontiguousarray(np.concatenate(parts, axis=0), dtype=self._pyramid.dtype)

    def __repr__(self) -> str:
        p = self._pyramid
        return f"NumpyLoader({self.source}, shape {p.shape}, {p.dtype}, brick {p.brick_shape}, {p.num_levels} levels)"
