"""Refine while a voxel projects to more than ``lod_threshold`` pixels (OpenGL Volumizer's rule).

Bhaniramka & Demange (2002) choose each region's level from its projected size: a brick is replaced
by its children while one of its voxels covers more than a pixel threshold on screen, measured at
the brick's nearest depth so a brick straddling the eye plane is always refined.
"""

from __future__ import annotations

from .base import RefinePolicy

__all__ = ["ProjectedSize", "TexelBudget"]


class ProjectedSize(RefinePolicy):
    name = "projected-size"

    def refine(self, t, level, lo, hi):
        return t.projected_voxel(level, lo, hi) > self.params.lod_threshold

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
