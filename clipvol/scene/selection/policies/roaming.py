"""Roaming: one level for the whole frame, the finest that the clip-texture's window holds.

OpenGL Volumizer's roaming mode (Bhaniramka & Demange 2002) draws a single resolution around the
centre of interest. From the top down, the chosen level is the finest whose visible
(non-transparent) bricks all lie in the residency window and fit ``max_texels_drawn``; the descent
stops early at the first level whose voxels all project to at most ``lod_threshold`` pixels (finer
levels would not be seen) or whose visible bricks would exceed :data:`ROAMING_MAX_BRICKS`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Roaming", "ROAMING_MAX_BRICKS"]

#: roaming stops descending when a level's visible bricks exceed this count
ROAMING_MAX_BRICKS = 1 << 20


class Roaming:
    name = "roaming"

    def __init__(self, params) -> None:
        self.params = params

    def refine(self, t, level, lo, hi):  # one level for all: the cut decides per level, not per node
        return t.projected_voxel(level, lo, hi) > self.params.lod_threshold

    def cut(self, t) -> None:
        tree, params = t.tree, self.params
        level, idx = tree.root, np.zeros((1, 3), dtype=np.int64)
        while level > tree.top and len(idx):
            idx, _, _ = t.cull(level, idx)
            idx = tree.children(level, idx)[0]
            level -= 1
        idx, lo, hi = t.cull(level, idx)
        chosen = (level, idx)
        while len(idx):
            vis = idx[t.opaque(level, idx)]
            ok = bool(t.in_window(level, vis).all())
            if params.max_texels_drawn is not None and len(vis) * tree.texels > params.max_texels_drawn:
                ok = False
            if not ok and level != tree.top:
                break
            chosen = (level, idx)
            if level == 0 or not self.refine(t, level, lo, hi).any() or len(idx) * 8 > ROAMING_MAX_BRICKS:
                break
            t.counts["refined"] += len(idx)
            idx = tree.children(level, idx)[0]
            idx, lo, hi = t.cull(level - 1, idx)
            level -= 1
        t.counts["level"] = chosen[0]
        t.leaves(*chosen)
