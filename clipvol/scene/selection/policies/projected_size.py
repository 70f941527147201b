"""Refine while a voxel projects to more than ``lod_threshold`` pixels (OpenGL Volumizer's rule).

Bhaniramka & Demange (2002) choose each region's level from its projected size: a brick is replaced
by its children while one of its voxels covers more than a pixel threshold on screen, measured at
the brick's nearest depth so a brick straddling the eye plane is always refined.

**Evened out.** Level by level, where the rule refines some of the nodes of a level and not the
others, every one of them is refined when that grows the cut by at most :data:`EVEN_OUT_GROWTH`
(the image policy's constant) times the size of the mixed cut (:func:`even_out`). Why: a cut of
one level merges into one box (:func:`~clipvol.scene.selection.merge_items`), and the renderer's
rays restart at every box or page-table node they cross, which on a CPU rasteriser costs more than
the samples coarser bricks save. Measured on the MNI ICBM152 T1 template (32³ bricks, ``bone``,
256², Mesa llvmpipe; ``tools/bench/bench_cut_boxes.py``, docs/benchmarks.md, "Multi-level cuts"):
``lod_threshold`` 4's cut of 36-45 level-1 and level-2 bricks (8 boxes) drew in 1.55-2.37x the time
of the 48 level-1 bricks in one box, slower than the full-resolution frame; the same 48 level-1
bricks as 48 page-table nodes took 1.44-1.49x the one box. Evening out only refines (a finer node
is nearer level 0), and every leaf's voxel still projects to at most ``lod_threshold`` pixels.
``max_texels_drawn`` (the greedy form) is not evened out: its budget chooses the cut.
"""

from __future__ import annotations

import numpy as np

from .base import RefinePolicy
from .image_based import EVEN_OUT_GROWTH

__all__ = ["ProjectedSize", "TexelBudget", "even_out"]


def even_out(refine: np.ndarray, growth: float = EVEN_OUT_GROWTH, children: int = 8) -> np.ndarray:
    """``refine`` (one level's nodes) with every node refined when some are and refining all of them
    grows the cut at most ``growth`` times: ``children * n <= growth * ((n - r) + children * r)``
    for ``r`` of ``n`` nodes refined (``children``: 8 per node, an octree's inner nodes; a node at
    the volume's edge has fewer, which the rule does not count)."""
    refine = np.asarray(refine, dtype=bool)
    n, r = len(refine), int(refine.sum())
    if 0 < r < n and children * n <= growth * ((n - r) + children * r):
        return np.ones(n, dtype=bool)
    return refine


class ProjectedSize(RefinePolicy):
    name = "projected-size"

    def refine(self, t, level, lo, hi):
        need = t.projected_voxel(level, lo, hi) > self.params.lod_threshold
        if self.params.max_texels_drawn is not None:  # the greedy form: the budget decides
            return need
        return even_out(need)


class TexelBudget(ProjectedSize):
    """Projected size, always greedy: the largest projected voxels are refined first until the
    next refinement would exceed ``max_texels_drawn`` (required)."""

    name = "texel-budget"

    def cut(self, t) -> None:
        t.greedy(self.params.max_texels_drawn)
