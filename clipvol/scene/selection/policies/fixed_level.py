"""One level everywhere (``level``), ancestors as fallback while it loads."""

from __future__ import annotations

import numpy as np

from ...page_table import block_cells
from .base import RefinePolicy

__all__ = ["FixedLevel", "SUBTREE_BRICKS"]

#: most bricks of the fixed level under one node that :meth:`FixedLevel.subtree_empty` looks at (a
#: culled node of a huge volume's upper levels holds millions: it is taken as not empty), and 16
#: times that for all nodes of one call
SUBTREE_BRICKS = 4096


class FixedLevel(RefinePolicy):
    name = "fixed"

    def cut(self, t) -> None:
        super().cut(t)
        t.counts["level"] = self.params.level

    def camera_free(self) -> bool:
        """One level everywhere: the camera only culls (the greedy texel budget ranks by projected size)."""
        return self.params.max_texels_drawn is None

    def subtree_empty(self, t, level: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """``(n,)`` True where the node of ``level`` with box ``lo``/``hi`` draws nothing at any
        camera: every brick of the fixed level under it is transparent under the transfer function
        and every brick between it and that level lies in the clip-texture's window (so none is
        drawn from its parent). Such a node may come into view without changing the cut, so the
        traversal leaves it out of the boxes a replayed cut must keep out of view
        (:mod:`clipvol.scene.selection.coherence`): an orbit whose frustum sweeps over the air
        around a head keeps its cut."""
        out = np.zeros(len(lo), dtype=bool)
        Lf = self.params.level
        if t.transparent is None or len(lo) == 0 or level < Lf or level > t.tree.top:
            return out
        pyr = t.tree.pyr
        vlo, _ = pyr.volume_box()
        ext = np.array(pyr.brick_shape[::-1], dtype=np.float64) * 2.0 ** level * np.array(pyr.spacing[::-1])
        idx = np.clip(np.rint((np.asarray(lo) - vlo) / ext).astype(np.int64)[:, ::-1], 0,
                      np.asarray(pyr.grid(level), dtype=np.int64) - 1)
        ok = np.ones(len(lo), dtype=bool)
        f = 1 << (level - Lf)
        under = np.prod(np.minimum(idx * f + f, np.asarray(pyr.grid(Lf), dtype=np.int64)) - idx * f, axis=1)
        # a larger node, or nodes past the budget of one call, are not tested: they stay boxes a
        # replayed cut must keep out of view (a frame then selects anew when they come into it)
        small = under <= SUBTREE_BRICKS
        ok &= small & (np.cumsum(np.where(small, under, 0)) <= 16 * SUBTREE_BRICKS)
        idx, lo = idx[ok], lo[ok]
        if not len(idx):
            return ok
        sub = np.ones(len(idx), dtype=bool)
        for m in range(level, Lf - 1, -1):  # the node's bricks at each level down to the fixed one
            f = 1 << (level - m)
            first = idx * f
            count = np.minimum(first + f, np.asarray(pyr.grid(m), dtype=np.int64)) - first
            block, local = block_cells(count)
            bricks = first[block] + local
            bad = ~t.in_window(m, bricks) if m < level else np.zeros(len(bricks), dtype=bool)
            if m == Lf:
                bad |= ~np.asarray(t.transparent(m, bricks), dtype=bool).reshape(len(bricks))
            sub &= np.bincount(block[bad], minlength=len(idx)) == 0
        ok[ok] = sub
        return ok

    def refine(self, t, level, lo, hi):
        return np.full(len(lo), level > self.params.level)
