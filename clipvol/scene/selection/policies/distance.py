"""LaMar, Hamann & Joy's distance filter: finer near a point, coarser away from it.

A node is accepted (not refined) when the distance from the point to its centre exceeds its
diagonal (times ``distance_factor``); the point is ``focus`` or, by default, the eye. Each level
then covers a shell about twice as wide as the finer one inside it, independent of the view
direction: useful for roaming, where the user may turn at any time.
"""

from __future__ import annotations

import numpy as np

from .base import RefinePolicy

__all__ = ["Distance"]


class Distance(RefinePolicy):
    name = "distance"

    def refine(self, t, level, lo, hi):
        p = np.asarray(self.params.focus if self.params.focus is not None else t.camera.eye, dtype=np.float64)
        centre = 0.5 * (lo + hi)
        diag = np.linalg.norm(hi - lo, axis=1)
        return np.linalg.norm(centre - p, axis=1) <= self.params.distance_factor * diag

    def priority(self, t, level, lo, hi):
        p = np.asarray(self.params.focus if self.params.focus is not None else t.camera.eye, dtype=np.float64)
        diag = np.linalg.norm(hi - lo, axis=1)
        return diag / np.maximum(np.linalg.norm(0.5 * (lo + hi) - p, axis=1), 1e-300)
