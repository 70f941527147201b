"""A region of interest per level: the bricks a render action wants paged, handed to the clip-texture.

Why: the clip-texture's default windows are cubes around the centre of interest - right for a
volume view that roams, wasteful for a slice, which touches a thin slab of each level (LaMar,
Hamann & Joy, *Multiresolution cutting planes*). A :class:`Region` lets the action say what it
will draw: per level, the bricks to queue (``None``: the level's whole window, as for a cube). The
clip-texture then fits each windowed level's window around those bricks within the same slots
(:func:`clipvol.paging.toroidal.region_window`) and queues only them, nearest the centre first;
bricks of the window outside the region stay unread unless a frame asks for them
(:meth:`ClipTexture.wait_for` / :meth:`ClipTexture.prioritize`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .slab import slab_mask

__all__ = ["Region"]


@dataclass(frozen=True, eq=False, slots=True)
class Region:
    """Bricks to page per level and the centre of interest they are ordered by.

    Parameters
    ----------
    center : (x, y, z)
        World point the load queue is sorted by (nearest first).
    bricks : tuple
        Per level (index = level), an ``(n, 3)`` int array of brick indices ``(z, y, x)`` to
        queue, or ``None`` to queue the level's whole window.
    slab : tuple, optional
        ``(origin, normal, half_thicknesses)``: the action samples only inside this slab (half-thickness
        per level, :mod:`clipvol.paging.slab`), so a brick outside it is never read by a sample -
        the GPU cache may filter across a face whose neighbours behind it lie outside.
    """

    center: tuple[float, float, float]
    bricks: tuple
    slab: tuple | None = None

    def __post_init__(self) -> None:
        c = np.asarray(self.center, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ParameterError(f"Region.center: expected three finite numbers (x, y, z), got {self.center!r}")
        object.__setattr__(self, "center", tuple(c.tolist()))
        out = []
        for L, b in enumerate(self.bricks):
            if b is None:
                out.append(None)
                continue
            a = np.asarray(b, dtype=np.int64).reshape(-1, 3)
            if len(a) and a.min() < 0:
                raise ParameterError(f"Region.bricks[{L}]: expected brick indices >= 0, got a minimum of {a.min()}")
            a.setflags(write=False)
            out.append(a)
        object.__setattr__(self, "bricks", tuple(out))
        if self.slab is not None:
            o, n, h = self.slab
            h = tuple(float(v) for v in h)
            if len(h) != len(out):
                raise ParameterError(f"Region.slab: expected a half-thickness per level ({len(out)}), got {len(h)}")
            object.__setattr__(self, "slab", (tuple(float(v) for v in o), tuple(float(v) for v in n), h))

    def out_of_reach(self, pyramid, level: int, indices) -> np.ndarray:
        """``(n,)`` bool: bricks of ``level`` no sample of the action reaches (outside its slab)."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        if self.slab is None:
            return np.zeros(len(idx), dtype=bool)
        o, n, h = self.slab
        return ~slab_mask(pyramid, level, idx, o, n, h[level])

    def same_as(self, other: "Region | None") -> bool:
        """Same centre and the same bricks per level (a frame that repeats its region changes nothing)."""
        if other is None or other.center != self.center or other.slab != self.slab \
                or len(other.bricks) != len(self.bricks):
            return False
        for a, b in zip(self.bricks, other.bricks):
            if (a is None) != (b is None):
                return False
            if a is not None and (a.shape != b.shape or not np.array_equal(a, b)):
                return False
        return True

    @classmethod
    def empty(cls, num_levels: int, center=(0.0, 0.0, 0.0)) -> "Region":
        """A region that queues nothing: a clip-texture made with it reads no brick until a render
        action hands it its own region (or :meth:`ClipTexture.set_region` ``(None)`` restores cubes)."""
        none = tuple(np.zeros((0, 3), dtype=np.int64) for _ in range(int(num_levels)))
        return cls(tuple(float(v) for v in center), none)

    @property
    def nbricks(self) -> int:
        """Bricks listed over all levels (levels given as ``None`` count 0)."""
        return sum(len(b) for b in self.bricks if b is not None)
