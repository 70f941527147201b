"""The cutting-plane policy of LaMar, Hamann & Joy: nodes the plane crosses, fine near a point of interest.

After *Multiresolution cutting planes* (LaMar, Hamann & Joy; sections 4.1-4.3). Three steps over
the shared traversal:

1. **Select** (``keep`` + ``refine``): only nodes the plane crosses are kept; a node is refined
   while one of its voxels covers more than ``lod_threshold`` slice pixels *and*, when a point of
   interest (``RenderParams.focus``) is set, the node is closer to that point than
   ``distance_factor`` times its diagonal. The paper measures from the node's centre; we measure
   from the node's nearest point, so the nodes holding the point are always refined and the
   point itself is at full resolution for any ``distance_factor``. Without a point of interest the
   slice is as fine as its pixels need; with ``RenderParams.level`` set, every node is drawn at
   that level (``--level 0``: full resolution).
2. **Balance** (:func:`~clipvol.scene.selection.balance.balance`): leaves are split until no two
   26-neighbours are two levels apart (children outside the clip-texture's window cannot be
   split into: those pairs stay as they are and stay unbalanced; ``counts["balance_splits"]`` counts the splits made).
3. **Blend ratios** (:func:`~clipvol.scene.selection.balance.blend_ratios`): per-corner ratios
   towards coarser neighbours, in :attr:`node_data` keyed by ``(level, index)``.

The cut is always level by level (``max_texels_drawn`` is not used: a slice's cost is its tiles,
bounded by the plane's area). The plane comes with the policy instance (``PlaneCut(params, plane)``, built by the slice render
action); the registry name ``"plane"`` makes it a valid ``RenderParams.policy``.
"""

from __future__ import annotations

import numpy as np

from ....errors import ParameterError
from ..balance import balance, blend_ratios
from .base import RefinePolicy

__all__ = ["PlaneCut"]


class PlaneCut(RefinePolicy):
    name = "plane"

    def __init__(self, params, plane=None) -> None:
        super().__init__(params)
        self.plane = plane
        self.node_data: dict = {}
        self.leaves: set = set()

    def keep(self, t, level, lo, hi):
        return self.plane.crosses(lo, hi)

    def refine(self, t, level, lo, hi):
        if self.params.level is not None:
            return np.full(len(lo), level > self.params.level)
        fine = t.projected_voxel(level, lo, hi) > self.params.lod_threshold
        if self.params.focus is not None:
            p = np.asarray(self.params.focus, dtype=np.float64)
            diag = np.linalg.norm(hi - lo, axis=1)
            near = np.linalg.norm(np.clip(p, lo, hi) - p, axis=1)  # 0 for the nodes holding the point
            fine &= near < self.params.distance_factor * diag
        return fine

    def cut(self, t) -> None:
        if self.plane is None:
            raise ParameterError("policy: 'plane' needs a cutting plane; use clipvol.render.slice_action.SliceAction "
                                 "(or PlaneCut(params, plane)) rather than RenderParams(policy='plane') alone")
        t.descend()
        tree = t.tree
        fixed = [r for r in t.rec if r[0] != r[2]]  # drawn from a parent: its child is outside the window
        own = [r for r in t.rec if r[0] == r[2]]
        leaves = {(int(r[0]), tuple(int(i) for i in b)) for r in own for b in r[1]}
        fixed_keys = {(int(r[2]), tuple(int(i) for i in b)) for r in fixed for b in r[3]}
        top = tree.top

        def split(level: int, b: tuple) -> list:
            if level == 0 or (level, b) in fixed_keys:
                return []
            kids, _ = tree.children(level, np.array([b], dtype=np.int64))
            lo, hi = tree.boxes(level - 1, kids)
            kids = kids[t._keep_mask(level - 1, lo, hi)]
            if not len(kids) or not t.in_window(level - 1, kids).all():
                return []
            return [(level - 1, tuple(int(i) for i in k)) for k in kids]

        balanced = balance(leaves | fixed_keys, tree.grids, top, split)
        self.leaves = balanced
        self.node_data = {k: v for k, v in blend_ratios(balanced, tree.grids, top).items() if k not in fixed_keys}
        t.counts["balance_splits"] = len(balanced - leaves - fixed_keys)
        t.rec = list(fixed)
        own_keys = sorted(balanced - fixed_keys)
        for L in sorted({k[0] for k in own_keys}):
            idx = np.array([b for lv, b in own_keys if lv == L], dtype=np.int64)
            t.leaves(L, idx)
