"""The octree of a pyramid's bricks: node boxes, children, split planes (pure numpy).

With one brick shape across levels, brick ``(L+1, b)`` covers bricks ``(L, 2b + {0,1}^3)``. If the top
level has more than one brick, virtual levels above it complete the tree until one node holds
everything; they are only traversed, never drawn (they have no data).
"""

from __future__ import annotations

import numpy as np

from ...bricking.pyramid import Pyramid

__all__ = ["Octree", "OFFSETS"]

#: the eight child offsets ``(dz, dy, dx)``
OFFSETS = np.array([[dz, dy, dx] for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], dtype=np.int64)


class Octree:
    """The octree of ``pyramid``, with virtual levels above its top (``root`` is the single node)."""

    def __init__(self, pyramid: Pyramid) -> None:
        self.pyr = pyramid
        self.top = pyramid.num_levels - 1
        grids = [pyramid.grid(lv) for lv in range(pyramid.num_levels)]
        while grids[-1] != (1, 1, 1):
            grids.append(tuple((g + 1) // 2 for g in grids[-1]))
        self.grids = [np.array(g, dtype=np.int64) for g in grids]
        self.root = len(grids) - 1
        self.sp = np.array(pyramid.spacing[::-1], dtype=np.float64)  # (x, y, z)
        self.brick = np.array(pyramid.brick_shape[::-1], dtype=np.float64)
        self.texels = int(np.prod(pyramid.brick_shape))

    def boxes(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World ``(lo, hi)`` boxes ``(n, 3)`` ``(x, y, z)`` of nodes ``idx`` ``(n, 3)`` ``(z, y, x)``."""
        lo, hi = self.pyr.node_box(level, idx.reshape(-1, 3))
        return np.atleast_2d(lo), np.atleast_2d(hi)

    def split(self, level: int, idx: np.ndarray) -> np.ndarray:
        """World ``(x, y, z)`` of the planes that split nodes ``idx`` of ``level`` into children."""
        ext = self.brick * 2.0**level
        return ((idx[:, ::-1] * 2 + 1) * ext * 0.5 - 0.5) * self.sp

    def children(self, level: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Existing children of nodes ``idx`` at ``level``: ``(child indices (m, 3), parent row (m,))``."""
        c = (2 * idx[:, None, :] + OFFSETS[None]).reshape(-1, 3)
        parent = np.repeat(np.arange(len(idx)), 8)
        ok = np.all(c < self.grids[level - 1], axis=1)
        return c[ok], parent[ok]

    def n_children(self, level: int, idx: np.ndarray) -> np.ndarray:
        """How many children each node ``idx`` of ``level`` has (fewer than 8 at the grid's far edges)."""
        g = self.grids[level - 1]
        return np.prod(np.clip(g - 2 * idx, 0, 2), axis=1)

    def voxel(self, level):
        """The largest voxel size of a real level (world units); of each level of an integer array,
        an array (what a test of many levels' nodes at once gives per node)."""
        if np.ndim(level) == 0:
            return max(self.pyr.levels[level].scale)
        table = np.array([max(lv.scale) for lv in self.pyr.levels], dtype=np.float64)
        return table[np.asarray(level, dtype=np.int64)]
