"""Pyramid geometry and the down-sampling filters: pure numpy, no GL, no I/O.

One convention everywhere (see ``docs/format.md``):

* arrays are numpy order ``(z, y, x)``; world vectors are ``(x, y, z)``;
* level-0 voxel ``i`` has its centre at ``i * spacing``; level ``L`` has scale ``2**L * spacing``
  and translation ``(2**L - 1) / 2 * spacing`` for the 2x2x2 ``mean`` and ``max`` filters (the
  centre of the block it summarises) or ``0`` for ``subsample`` (it *is* voxel ``2**L * i``);
* every level halves every axis (ceil) until one brick holds the whole level, so with one brick
  shape for all levels the bricks form an octree: brick ``(L+1, b)`` covers ``(L, 2b + {0,1}^3)``.

An axis that is already one brick long keeps halving with the others (a 1-voxel axis stays one
voxel). That keeps the octree uniform, which the render action's traversal relies on.

Odd sizes: the last, half-filled block of an axis is treated as if its existing voxels were
repeated (edge replication). For ``mean`` that is exactly the mean of the voxels that exist, for
``max`` their maximum and for ``subsample`` their first voxel.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from ..errors import ParameterError

__all__ = [
    "FILTERS",
    "LevelInfo",
    "Pyramid",
    "level_shapes",
    "level_transform",
    "downsample",
    "pad_to_brick",
    "validate_dtype",
    "NEIGHBOUR_OFFSETS",
]

#: the 27 offsets ``(z, y, x)`` of a brick's 3x3x3 neighbourhood in its level's grid, itself included
#: (trilinear filtering near a face reads the neighbour: the transparency footprint and the GPU
#: cache's neighbour uploads both walk it)
NEIGHBOUR_OFFSETS = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(27, 3)

#: ``mode`` is for label volumes (integer ids): the most frequent id of each 2x2x2 block, never a
#: blend of ids
FILTERS = ("mean", "subsample", "max", "mode")

Int3 = tuple[int, int, int]
Float3 = tuple[float, float, float]


def _int3(value, name: str) -> Int3:
    try:
        t = tuple(int(v) for v in value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected three integers (z, y, x), got {value!r}") from None
    if len(t) != 3:
        raise ParameterError(f"{name}: expected three integers (z, y, x), got {value!r}")
    return t  # type: ignore[return-value]


def validate_dtype(dtype, name: str = "dtype") -> np.dtype:
    """Return ``dtype`` as a numpy dtype if clipvol supports it: integers and floats up to 64 bits.

    Complex, bool, object, string and structured dtypes are refused (an object dtype could make a
    reader unpickle data, which we never do).
    """
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise ParameterError(f"{name}: expected a numeric dtype such as 'uint16' or 'float32', got {dtype!r}") from None
    if dt.kind not in "iuf" or dt.itemsize > 8 or dt.fields is not None:
        raise ParameterError(
            f"{name}: expected an integer or float dtype of at most 64 bits, got {dt} "
            "(complex, bool, object, string and structured dtypes are not supported)"
        )
    return dt


@dataclass(frozen=True, slots=True)
class LevelInfo:
    """One resolution level: its shape in voxels and its voxel-to-world transform (all ``(z, y, x)``).

    A voxel ``i`` of this level has its centre at ``translation + i * scale`` in world units.
    """

    shape: Int3
    scale: Float3
    translation: Float3

    def __post_init__(self) -> None:
        object.__setattr__(self, "shape", _int3(self.shape, "LevelInfo.shape"))
        if any(s < 1 for s in self.shape):
            raise ParameterError(f"LevelInfo.shape: every axis must be >= 1, got {self.shape}")
        sc = tuple(float(v) for v in self.scale)
        tr = tuple(float(v) for v in self.translation)
        if len(sc) != 3 or len(tr) != 3:
            raise ParameterError(f"LevelInfo: scale and translation need three values, got {sc}, {tr}")
        if not all(np.isfinite(sc)) or any(v <= 0 for v in sc):
            raise ParameterError(f"LevelInfo.scale: expected finite values > 0, got {sc}")
        if not all(np.isfinite(tr)):
            raise ParameterError(f"LevelInfo.translation: expected finite values, got {tr}")
        object.__setattr__(self, "scale", sc)
        object.__setattr__(self, "translation", tr)


def level_shapes(shape: Int3, brick_shape: Int3) -> list[Int3]:
    """Shapes of all levels: halve every axis (ceil) until one brick holds the level."""
    shape = _int3(shape, "shape")
    brick_shape = _int3(brick_shape, "brick_shape")
    if any(s < 1 for s in shape):
        raise ParameterError(f"shape: every axis must be >= 1, got {shape}")
    if any(b < 1 for b in brick_shape):
        raise ParameterError(f"brick_shape: every axis must be >= 1, got {brick_shape}")
    shapes = [shape]
    while any(s > b for s, b in zip(shapes[-1], brick_shape)):
        shapes.append(tuple((s + 1) // 2 for s in shapes[-1]))  # type: ignore[arg-type]
    return shapes


def level_transform(level: int, spacing: Float3, filter: str) -> tuple[Float3, Float3]:
    """``(scale, translation)`` of ``level`` for a level-0 ``spacing`` and a down-sampling ``filter``."""
    if filter not in FILTERS:
        raise ParameterError(f"filter: expected one of {', '.join(FILTERS)}, got {filter!r}")
    f = 2.0**level
    scale = tuple(f * s for s in spacing)
    offset = 0.0 if filter == "subsample" else (f - 1.0) / 2.0
    translation = tuple(offset * s for s in spacing)
    return scale, translation  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class Pyramid:
    """Everything a reader needs to know about a multiresolution brick pyramid, without its data.

    Loaders expose one as ``loader.pyramid``; the clip-texture and the render action reason about
    bricks only through it. ``value_range`` is the ``(min, max)`` of the finite values of level 0;
    ``fill_value`` is the background that a missing (empty) brick holds.
    """

    levels: tuple[LevelInfo, ...]
    brick_shape: Int3
    dtype: np.dtype
    value_range: tuple[float, float]
    fill_value: float = 0.0
    filter: str = "mean"
    _grids: tuple[Int3, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "brick_shape", _int3(self.brick_shape, "brick_shape"))
        if any(b < 1 for b in self.brick_shape):
            raise ParameterError(f"brick_shape: every axis must be >= 1, got {self.brick_shape}")
        object.__setattr__(self, "dtype", validate_dtype(self.dtype))
        levels = tuple(self.levels)
        if not levels or not all(isinstance(lv, LevelInfo) for lv in levels):
            raise ParameterError("levels: expected a non-empty sequence of LevelInfo")
        object.__setattr__(self, "levels", levels)
        lo, hi = (float(v) for v in self.value_range)
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi < lo:
            raise ParameterError(f"value_range: expected finite (min, max) with min <= max, got {self.value_range}")
        object.__setattr__(self, "value_range", (lo, hi))
        object.__setattr__(self, "fill_value", float(self.fill_value))
        if self.filter not in FILTERS:
            raise ParameterError(f"filter: expected one of {', '.join(FILTERS)}, got {self.filter!r}")
        grids = tuple(
            tuple(-(-s // b) for s, b in zip(lv.shape, self.brick_shape)) for lv in levels
        )
        object.__setattr__(self, "_grids", grids)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        shape: Int3,
        brick_shape: Int3 = (64, 64, 64),
        spacing: Float3 = (1.0, 1.0, 1.0),
        filter: str = "mean",
        dtype="float32",
        value_range: tuple[float, float] = (0.0, 1.0),
        fill_value: float = 0.0,
    ) -> "Pyramid":
        """The pyramid ``clipvol brick`` writes for a level-0 ``shape`` (``(z, y, x)``)."""
        spacing = tuple(float(s) for s in spacing)
        if len(spacing) != 3 or not all(np.isfinite(spacing)) or any(s <= 0 for s in spacing):
            raise ParameterError(f"spacing: expected three finite values > 0 (z, y, x), got {spacing}")
        levels = []
        for L, shp in enumerate(level_shapes(shape, brick_shape)):
            scale, translation = level_transform(L, spacing, filter)  # type: ignore[arg-type]
            levels.append(LevelInfo(shp, scale, translation))
        return cls(tuple(levels), brick_shape, dtype, value_range, fill_value, filter)

    # -- geometry -----------------------------------------------------------------------------
    @property
    def num_levels(self) -> int:
        return len(self.levels)

    @property
    def shape(self) -> Int3:
        """Level-0 shape ``(z, y, x)``."""
        return self.levels[0].shape

    @property
    def spacing(self) -> Float3:
        """Level-0 voxel size ``(z, y, x)`` in world units."""
        return self.levels[0].scale

    @property
    def brick_nbytes(self) -> int:
        """Bytes of one brick in memory (its full brick shape)."""
        return int(np.prod(self.brick_shape)) * self.dtype.itemsize

    def grid(self, level: int) -> Int3:
        """Number of bricks per axis ``(z, y, x)`` at ``level``."""
        return self._grids[level]

    def num_bricks(self, level: int) -> int:
        g = self._grids[level]
        return g[0] * g[1] * g[2]

    def check_key(self, level: int, index) -> Int3:
        """Return ``index`` as an int triple, or raise naming the level and brick if it is outside."""
        if not (0 <= int(level) < len(self.levels)):
            raise ParameterError(f"level: expected 0..{len(self.levels) - 1}, got {level}")
        idx = _int3(index, "brick index")
        g = self._grids[level]
        if any(not (0 <= i < n) for i, n in zip(idx, g)):
            raise ParameterError(f"brick {idx} is outside level {level}, whose grid is {g}")
        return idx

    def brick_voxel_box(self, level: int, index: Int3) -> tuple[Int3, Int3]:
        """``(start, stop)`` voxel indices ``(z, y, x)`` of brick ``index`` at ``level``, clipped to the level."""
        shp = self.levels[level].shape
        start = tuple(i * b for i, b in zip(index, self.brick_shape))
        stop = tuple(min(s + b, n) for s, b, n in zip(start, self.brick_shape, shp))
        return start, stop  # type: ignore[return-value]

    def volume_box(self) -> tuple[np.ndarray, np.ndarray]:
        """World box ``(lo, hi)`` as ``(x, y, z)`` float64 vectors: the cells of all level-0 voxels."""
        sp = np.array(self.spacing[::-1], dtype=np.float64)
        n = np.array(self.shape[::-1], dtype=np.float64)
        return -0.5 * sp, (n - 0.5) * sp

    def node_box(self, level: int, index) -> tuple[np.ndarray, np.ndarray]:
        """World box ``(lo, hi)`` (``(x, y, z)``) of the octree node of brick ``(level, index)``.

        It is the level-0 footprint of the brick (``brick_shape * 2**level`` level-0 voxels per
        axis), clipped to :meth:`volume_box`; children's boxes tile their parent's exactly, which
        the traversal relies on. Works for ``index`` of shape ``(3,)`` or ``(n, 3)`` (``(z, y, x)``).
        """
        idx = np.asarray(index, dtype=np.float64)[..., ::-1]
        sp = np.array(self.spacing[::-1], dtype=np.float64)
        ext = np.array(self.brick_shape[::-1], dtype=np.float64) * 2.0**level
        vlo, vhi = self.volume_box()
        lo = np.maximum(idx * ext * sp - 0.5 * sp, vlo)
        hi = np.minimum((idx + 1) * ext * sp - 0.5 * sp, vhi)
        return lo, hi

    def world_to_brick(self, level: int, point_xyz) -> Int3:
        """Index ``(z, y, x)`` of the brick at ``level`` whose node box holds ``point_xyz``, clamped to the grid."""
        p = np.asarray(point_xyz, dtype=np.float64)[::-1]
        sp = np.array(self.spacing, dtype=np.float64)
        ext = np.array(self.brick_shape, dtype=np.float64) * 2.0**level
        b = np.floor((p / sp + 0.5) / ext).astype(np.int64)
        g = np.array(self._grids[level])
        return tuple(int(v) for v in np.clip(b, 0, g - 1))  # type: ignore[return-value]

    def children(self, level: int, index: Int3) -> Iterator[Int3]:
        """Indices at ``level - 1`` of the (up to 8) children of brick ``(level, index)`` that exist."""
        g = self._grids[level - 1]
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    c = (2 * index[0] + dz, 2 * index[1] + dy, 2 * index[2] + dx)
                    if c[0] < g[0] and c[1] < g[1] and c[2] < g[2]:
                        yield c

    def with_levels(self, n: int) -> "Pyramid":
        """The same pyramid restricted to its first ``n`` levels (for tests and partial stores)."""
        return Pyramid(self.levels[:n], self.brick_shape, self.dtype, self.value_range, self.fill_value, self.filter)


def pad_to_brick(block: np.ndarray, brick_shape: Int3) -> np.ndarray:
    """Pad ``block`` (an edge brick's valid voxels) to ``brick_shape`` by edge replication.

    Edge replication is the loader contract for edge bricks: a renderer sampling trilinearly just
    inside the volume's last voxel then sees that voxel, as ``CLAMP_TO_EDGE`` would give.
    Returns ``block`` itself when it already has the brick shape.
    """
    if block.shape == tuple(brick_shape):
        return block
    if block.ndim != 3 or any(s < 1 or s > b for s, b in zip(block.shape, brick_shape)):
        raise ParameterError(f"pad_to_brick: expected a 3-D block of at most {tuple(brick_shape)}, got shape {block.shape}")
    pad = [(0, b - s) for s, b in zip(block.shape, brick_shape)]
    return np.pad(block, pad, mode="edge")


def _pad_even(block: np.ndarray) -> np.ndarray:
    pad = [(0, s % 2) for s in block.shape]
    if any(p[1] for p in pad):
        block = np.pad(block, pad, mode="edge")
    return block


def _blocks(block: np.ndarray) -> np.ndarray:
    z, y, x = block.shape
    return block.reshape(z // 2, 2, y // 2, 2, x // 2, 2)


def _mean_int(b6: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """floor((S + 4) / 8) of the 8 values of each block, exact for every integer dtype."""
    if dtype.itemsize < 8:
        s = b6.sum(axis=(1, 3, 5), dtype=np.int64)
        return ((s + 4) // 8).astype(dtype)
    # 64-bit integers: split into 32-bit halves so no sum overflows, then recombine exactly.
    if dtype.kind == "u":
        hi = (b6 >> np.uint64(32)).astype(np.int64)
        lo = (b6 & np.uint64(0xFFFFFFFF)).astype(np.int64)
    else:
        hi = b6 >> 32
        lo = b6 & 0xFFFFFFFF
    s_hi = hi.sum(axis=(1, 3, 5), dtype=np.int64)
    s_lo = lo.sum(axis=(1, 3, 5), dtype=np.int64)
    q, r = np.divmod(s_hi, 8)
    low = (r * 2**32 + s_lo + 4) // 8  # < 2**34: fits anywhere
    if dtype.kind == "u":
        return (q.astype(np.uint64) << np.uint64(32)) + low.astype(np.uint64)
    return (q << 32) + low


def _mode(p: np.ndarray) -> np.ndarray:
    """Most frequent value of each 2x2x2 block of the even-shaped ``p``, smallest among ties.

    Edge replication (:func:`_pad_even`) repeats each existing voxel of a partial block equally
    often, so the mode over the padded block is the mode over the voxels that exist.
    """
    v = np.stack([p[z::2, y::2, x::2] for z in (0, 1) for y in (0, 1) for x in (0, 1)], axis=-1)
    v.sort(axis=-1)
    counts = np.zeros(v.shape, dtype=np.int8)
    for j in range(8):  # counts[..., i] = how many of the 8 equal v[..., i]
        counts += v == v[..., j : j + 1]
    first = np.argmax(counts, axis=-1)  # sorted ascending: the first maximum is the smallest tie
    return np.ascontiguousarray(np.take_along_axis(v, first[..., None], axis=-1)[..., 0])


def downsample(block: np.ndarray, filter: str = "mean") -> np.ndarray:
    """Reduce a ``(z, y, x)`` block by 2 on every axis (ceil) with ``filter``; same dtype out.

    * ``mean``: integers give ``floor((sum + 4) / 8)`` of the 8 (edge-replicated) values, exact
      for every width including 64 bits; floats are averaged in float64, NaN ignored (a block of
      only NaN stays NaN).
    * ``max``: the maximum, NaN ignored.
    * ``subsample``: voxel ``2i`` (``B_i = A_{2i}``).
    * ``mode``: the most frequent of the 8 values, the smallest among ties (label volumes: a coarse
      voxel keeps an id that occurs in its block, where a mean would invent one).

    Odd axes: the last block holds the voxels that exist, as if repeated (see module docstring).
    Slabs passed in one at a time give the same result as the whole volume as long as every slab
    but the last has even extent along each axis.
    """
    if block.ndim != 3:
        raise ParameterError(f"downsample: expected a 3-D block, got shape {block.shape}")
    if filter == "subsample":
        return np.ascontiguousarray(block[::2, ::2, ::2])
    if filter not in FILTERS:
        raise ParameterError(f"filter: expected one of {', '.join(FILTERS)}, got {filter!r}")
    dtype = block.dtype
    p = _pad_even(block)
    # Pairwise reductions axis by axis on strided views: an order of magnitude faster than a
    # 6-D reshape + reduce, and bit-identical (the filter dominates bricking time).
    if filter == "mode":
        return _mode(p)
    if filter == "max":
        f = np.fmax if dtype.kind == "f" else np.maximum  # fmax ignores NaN
        m = f(p[:, :, 0::2], p[:, :, 1::2])
        m = f(m[:, 0::2], m[:, 1::2])
        return f(m[0::2], m[1::2])
    if dtype.kind in "iu" and dtype.itemsize <= 4:
        s = p[:, :, 0::2].astype(np.int32 if dtype.itemsize <= 2 else np.int64)
        s += p[:, :, 1::2]
        s = s[:, 0::2] + s[:, 1::2]
        s = s[0::2] + s[1::2]
        s += 4
        s >>= 3  # floor division by 8, also for negative sums
        return s.astype(dtype)
    b6 = _blocks(p)
    if dtype.kind in "iu":
        return _mean_int(b6, dtype)
    b64 = b6.astype(np.float64)
    nan = np.isnan(b64)
    if not nan.any():
        with np.errstate(invalid="ignore"):  # +inf and -inf in one block give NaN, as numpy does
            out = b64.mean(axis=(1, 3, 5))
    else:
        cnt = (~nan).sum(axis=(1, 3, 5))
        s = np.where(nan, 0.0, b64).sum(axis=(1, 3, 5))
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    with np.errstate(over="ignore", invalid="ignore"):
        return out.astype(dtype)
