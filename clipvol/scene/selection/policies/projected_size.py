"""Refine while a voxel projects to more than ``lod_threshold`` pixels (OpenGL Volumizer's rule).

Bhaniramka & Demange (2002) choose each region's level from its projected size: a brick is replaced
by its children while one of its voxels covers more than a pixel threshold on screen, measured at
the brick's nearest depth so a brick straddling the eye plane is always refined.

**Evened out.** Level by level, where the rule refines some nodes of a sibling group (the children
of one node) and not the others, every one of them is refined when that grows the group's part of
the cut by at most :data:`EVEN_OUT_GROWTH` (the image policy's constant) times (:func:`even_out`);
then the same test over all the level's nodes, so a level that is mostly refined is refined whole. Why: a cut of
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

__all__ = ["ProjectedSize", "TexelBudget", "even_out", "even_rule"]


def even_out(refine: np.ndarray, groups: np.ndarray | None = None, growth: float = EVEN_OUT_GROWTH,
             children: int = 8) -> np.ndarray:
    """``refine`` (nodes of one level) with every node of a sibling group refined when some of the
    group are and refining all of them grows the group's part of the cut at most ``growth`` times:
    ``children * n <= growth * ((n - r) + children * r)`` for ``r`` of its ``n`` nodes refined
    (``children``: 8 per node, an octree's inner nodes; a node at the volume's edge has fewer,
    which the rule does not count). ``groups``: ``(n,)`` a key per node, equal for siblings (their
    parent); None: one group. Per sibling group, so a smaller threshold never draws a region
    coarser than a larger one does (a group evened at the larger is evened at the smaller)."""
    refine = np.asarray(refine, dtype=bool)
    if len(refine) == 0:
        return refine
    if groups is None:  # one group: two counts
        return refine | bool(even_rule(len(refine), int(np.count_nonzero(refine)), growth, children))
    _, inv = np.unique(groups, return_inverse=True)
    return _even_groups(refine, inv.reshape(-1), growth, children)


def _even_groups(refine: np.ndarray, inv: np.ndarray, growth: float = EVEN_OUT_GROWTH, children: int = 8) -> np.ndarray:
    """:func:`even_out` with the groups given as a dense index per node (``0 .. groups - 1``)."""
    n = np.bincount(inv)
    r = np.bincount(inv, weights=refine.astype(np.float64))
    return refine | even_rule(n, r, growth, children)[inv]


def even_rule(n, r, growth: float = EVEN_OUT_GROWTH, children: int = 8):
    """Is a group of ``n`` nodes, ``r`` of which the rule refines, refined whole (:func:`even_out`)?
    Vectorised over arrays of groups; what a kept cut asks of the few groups a move changed."""
    return (r > 0) & (r < n) & (children * n <= growth * ((n - r) + children * r))


class ProjectedSize(RefinePolicy):
    name = "projected-size"

    def refine(self, t, level, lo, hi):
        return self.even(t, level, lo, self.need(t, level, lo, hi))

    def need(self, t, level, lo, hi) -> np.ndarray:
        """The rule node by node, before evening out: a voxel covers more than ``lod_threshold``
        pixels at the node's nearest depth (what :meth:`depth_threshold` states as a depth limit)."""
        return np.asarray(t.projected_voxel(level, lo, hi) > self.params.lod_threshold, dtype=bool).reshape(len(lo))

    def even(self, t, level, lo, need, groups: np.ndarray | None = None) -> np.ndarray:
        """``need`` (every node of ``level`` the traversal reached and kept) evened out: per sibling
        group, then the level as a whole (one level merges into one box); the greedy form as it is.
        ``groups``: :meth:`sibling_groups` of these nodes, where the caller kept them (``lo`` is
        then not read)."""
        if self.params.max_texels_drawn is not None or len(need) < 2:  # the greedy form: the budget decides
            return need
        if groups is None:
            groups = self.sibling_groups(t, level, lo)
        return even_out(_even_groups(np.asarray(need, dtype=bool), groups))

    def evens(self, n, r):
        """:func:`even_rule` (the greedy form is never evened, and no kept cut keeps it): a kept cut
        evens out only the sibling groups and the level counts a move changed, as :meth:`even`
        evens out a whole level (per sibling group, then the level as one group)."""
        return even_rule(n, r)

    def sibling_groups(self, t, level, lo) -> np.ndarray:
        """A dense index per node of ``level`` (boxes' low corners ``lo``), equal for siblings: what
        :meth:`even` groups by. It depends on the nodes alone, not on the camera, so a kept cut
        keeps it while a level's reached nodes are the same (a sort of the level per frame cost
        the 512^3 head's 4 096 level-1 nodes most of their evening out)."""
        tree = t.tree
        idx = np.rint((np.asarray(lo) + 0.5 * tree.sp) / (tree.brick * 2.0**level * tree.sp)).astype(np.int64)
        parent = idx // 2
        _, inv = np.unique(parent[:, 0] * (1 << 42) + parent[:, 1] * (1 << 21) + parent[:, 2], return_inverse=True)
        return inv.reshape(-1)

    def depth_threshold(self, camera, voxel: float) -> float:
        """The nearest depth below which a node of ``voxel``-sized voxels is refined (perspective):
        ``refine`` is this limit on the node's nearest depth, which lets a kept cut re-test only the
        nodes near it when the camera moves (:class:`~clipvol.scene.selection.kept_cut.KeptCut`)."""
        return float(voxel * camera.pixels_per_unit(1.0) / self.params.lod_threshold)


class TexelBudget(ProjectedSize):
    """Projected size, always greedy: the largest projected voxels are refined first until the
    next refinement would exceed ``max_texels_drawn`` (required)."""

    name = "texel-budget"

    def cut(self, t) -> None:
        t.greedy(self.params.max_texels_drawn)
