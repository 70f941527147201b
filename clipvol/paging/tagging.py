"""Tagging with a label volume: hide labelled structures by making their voxels absent.

OpenGL Volumizer's tagging shader (Bhaniramka & Demange 2002, section 2.1.3) looks a tag volume
up beside the data. Here the tag is applied where the bricks are paged in: :class:`TaggedLoader`
wraps an image loader and a label loader of the same pyramid and returns float32 bricks in which
every voxel whose label is hidden is NaN. The renderer already treats NaN as *absent* (it
contributes no colour, no opacity and no maximum, and NaN-aware sampling interpolates over the
finite neighbours only), so a hidden label contributes nothing, at every level, through every
render action, with no shader change. Coarse levels hide the voxels whose mode-filtered label
(see :func:`clipvol.bricking.pyramid.downsample`) is hidden.

Changing the hidden set means a new loader (and a new clip-texture): hiding is a data choice, like
picking a time step, not a per-frame setting.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import ParameterError
from .loader import HasBrickRanges, Loader

__all__ = ["TaggedLoader"]


class TaggedLoader:
    """``image`` with the voxels whose ``labels`` id is in ``hidden`` set to NaN (float32).

    Parameters
    ----------
    image, labels : Loader
        Two loaders over pyramids of the same level shapes and brick shape (``clipvol brick
        --labels`` writes such a pair: the store and ``store/labels/NAME``).
    hidden : iterable of int
        Label ids whose voxels are removed.
    """

    def __init__(self, image: Loader, labels: Loader, hidden) -> None:
        pi, pl = image.pyramid, labels.pyramid
        if pi.brick_shape != pl.brick_shape or [lv.shape for lv in pi.levels] != [lv.shape for lv in pl.levels]:
            raise ParameterError(
                f"labels: expected the image's levels {[lv.shape for lv in pi.levels]} and brick {pi.brick_shape}, "
                f"got levels {[lv.shape for lv in pl.levels]} and brick {pl.brick_shape}")
        if np.dtype(pl.dtype).kind not in "iub":
            raise ParameterError(f"labels: expected integer label ids, got dtype {pl.dtype}")
        self.image, self.labels = image, labels
        self.hidden = np.array(sorted({int(h) for h in hidden}), dtype=np.int64)
        self._pyramid = replace(pi, dtype=np.dtype(np.float32))
        # where the image sits in the world (overlays are placed relative to it)
        self.origin, self.unit, self.frame = (getattr(image, k, None) for k in ("origin", "unit", "frame"))

    @property
    def pyramid(self):
        return self._pyramid

    def read_brick(self, level: int, index) -> np.ndarray:
        out = np.asarray(self.image.read_brick(level, index), dtype=np.float32).copy()
        if len(self.hidden):
            lab = np.asarray(self.labels.read_brick(level, index))
            out[np.isin(lab, self.hidden)] = np.nan
        return out

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray | None:
        """The image's bounds, or ``[nan, nan]`` (unknown) where a hidden id may occur."""
        if not isinstance(self.image, HasBrickRanges):
            return None
        img = self.image.brick_ranges(level, indices)
        if img is None:
            return None
        img = np.array(img, dtype=np.float64, copy=True)
        if not len(self.hidden):
            return img
        lab = self.labels.brick_ranges(level, indices) if isinstance(self.labels, HasBrickRanges) else None
        if lab is None:
            img[:] = np.nan
            return img
        lab = np.asarray(lab, dtype=np.float64)
        lo, hi = lab[:, :1], lab[:, 1:2]
        maybe = ((self.hidden[None, :] >= lo) & (self.hidden[None, :] <= hi)).any(axis=1) | np.isnan(lab).any(axis=1)
        img[maybe] = np.nan
        return img
