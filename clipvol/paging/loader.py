"""The custom-loader contract: read this file to plug any data source into clipvol.

A loader describes a brick pyramid (:class:`~clipvol.bricking.pyramid.Pyramid`: levels with shape, scale
and translation; brick shape; dtype; value range; fill value) and reads one brick at a time. The
clip-texture calls :meth:`Loader.read_brick` from several loader threads at once, so a loader must
be safe to call concurrently (reading files and decoding is; a shared file handle with ``seek`` is
not). Everything else in clipvol - paging, selection, rendering - sees data only through here.

Contract of ``read_brick(level, (bz, by, bx))``:

* returns an array of exactly ``pyramid.brick_shape`` and ``pyramid.dtype``;
* an edge brick (one that reaches past the level's shape) holds the level's voxels in its first
  ``stop - start`` entries per axis and is padded by **edge replication** beyond them
  (:func:`clipvol.bricking.pyramid.pad_to_brick` does it), so trilinear sampling at the border behaves
  like ``CLAMP_TO_EDGE``;
* a brick with no data (never written, all background) holds ``pyramid.fill_value``;
* it may raise any exception; the clip-texture retries, then marks the brick failed and renders
  a coarser level there. It must not return a view into memory it will later change.

Optional: a loader that knows value bounds per brick without reading it (a store's statistics, an
analytic generator) also implements :class:`HasBrickRanges`; the render action then skips bricks
the transfer function makes fully transparent without ever loading them, and the clip-texture
never reads an empty brick. A loader may also offer ``read_brick_into(level, index, out)``, which
writes the brick straight into the clip-texture's slot ``out`` (same contract, no copy).

A loader that reads from storage may also hold a ``read_counter``
(:class:`clipvol.paging.readcount.ReadCounter`) and count the bytes of every read where it reads
them; the clip-texture and the render actions then report bytes read per frame and per slice.

``clipvol.testing.LoaderTests`` is a conformance suite every loader (yours too) can run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ..bricking.pyramid import Int3, Pyramid
from ..errors import LoaderError

__all__ = ["Loader", "HasBrickRanges", "HasReadPlan", "HasSpread", "BrickKey", "check_brick"]


@dataclass(frozen=True, slots=True, order=True)
class BrickKey:
    """A brick's address: ``level`` (0 = finest) and ``index`` ``(bz, by, bx)`` in that level's grid."""

    level: int
    index: Int3

    def __post_init__(self) -> None:
        object.__setattr__(self, "level", int(self.level))
        object.__setattr__(self, "index", tuple(int(i) for i in self.index))
        if self.level < 0 or len(self.index) != 3 or min(self.index) < 0:
            raise ValueError(f"BrickKey: expected level >= 0 and three indices >= 0, got {self.level}, {self.index}")

    def parent(self) -> "BrickKey":
        return BrickKey(self.level + 1, tuple(i // 2 for i in self.index))  # type: ignore[arg-type]

    def __str__(self) -> str:
        return f"brick (level {self.level}, {self.index[0]}, {self.index[1]}, {self.index[2]})"


@runtime_checkable
class Loader(Protocol):
    """What the clip-texture needs from a data source.

    Attributes
    ----------
    pyramid : Pyramid
        Levels, brick shape, dtype, value range and fill value of the data.
    """

    @property
    def pyramid(self) -> Pyramid: ...

    def read_brick(self, level: int, index: Int3) -> np.ndarray:
        """Return brick ``index`` ``(bz, by, bx)`` of ``level`` (see the module docstring)."""
        ...


@runtime_checkable
class HasBrickRanges(Protocol):
    """Optional: per-brick value bounds without reading the bricks (for empty-space skipping)."""

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray | None:
        """``(n, 2)`` float64 ``[min, max]`` of the values of each brick in ``indices``
        (``(n, 3)`` ints, ``(bz, by, bx)``), or ``None`` when unknown. Bounds may be loose (a
        bound that contains the true range is fine). A brick holding NaN gives ``[nan, nan]``
        (unknown), one holding ±Inf gives infinite bounds. ``[fill, fill]`` therefore means the
        brick is *empty*: the clip-texture fills it without calling ``read_brick``, and the
        render action skips it when the transfer function makes that value transparent.
        """
        ...


@runtime_checkable
class HasSpread(Protocol):
    """Optional: the spread beside the coarse levels (:mod:`clipvol.bricking.spread`), read with each
    brick of those levels by the clip-texture so that the renderer can classify a coarse voxel by the
    distribution beneath it (:mod:`clipvol.scene.consistent`). A loader without it is drawn by its means."""

    spread_levels: tuple[int, ...]

    def read_spread(self, level: int, index: tuple[int, int, int]) -> np.ndarray | None:
        """The brick's spread (brick shape, :func:`~clipvol.bricking.spread.spread_dtype`), or None."""
        ...


@runtime_checkable
class HasReadPlan(Protocol):
    """Optional: told which bricks are about to be read, so that a loader that can fetch several
    bricks in one request (neighbouring inner chunks of a zarr shard) fetches those, not others."""

    def plan_reads(self, level: int, indices: np.ndarray | None) -> None:
        """The bricks ``indices`` (``(n, 3)`` ints, ``(bz, by, bx)``) of ``level`` are queued for
        reading now (``None``: no plan; any neighbour may be). A hint, replaced by the next call:
        it must be cheap (the clip-texture calls it under its lock each time it re-sorts its
        queue) and never changes what ``read_brick`` returns."""
        ...


def check_brick(loader: Loader, level: int, index: Int3, brick: object) -> np.ndarray:
    """Return ``brick`` if it honours the contract, else raise :class:`LoaderError` naming all three."""
    pyr = loader.pyramid
    if not isinstance(brick, np.ndarray):
        raise LoaderError(
            f"{type(loader).__name__}.read_brick returned {type(brick).__name__} for {BrickKey(level, index)}; "
            "expected a numpy array"
        )
    if brick.shape != pyr.brick_shape or brick.dtype != pyr.dtype:
        raise LoaderError(
            f"{type(loader).__name__}.read_brick returned shape {brick.shape} dtype {brick.dtype} for "
            f"{BrickKey(level, index)}; expected shape {pyr.brick_shape} dtype {pyr.dtype}"
        )
    return brick
