"""LaMar, Hamann & Joy's field-of-view filter: refine nodes that subtend a large angle.

A node inside the frustum is accepted when the angle it subtends from the eye is less than
``fov_fraction`` of the vertical field of view (the paper uses half the field-of-view angle). For
an orthographic camera the angle is replaced by the node's diagonal over the view height.
"""

from __future__ import annotations

import math

import numpy as np

from .base import RefinePolicy

__all__ = ["FieldOfView"]


def subtended(camera, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Fraction of the vertical field of view each box's bounding sphere subtends (eye inside: inf)."""
    centre = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo, axis=1)
    if camera.orthographic:
        return 2.0 * radius / float(camera.height)
    dist = np.linalg.norm(centre - np.asarray(camera.eye, dtype=np.float64), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ang = np.where(dist > radius, 2.0 * np.arcsin(np.clip(radius / np.maximum(dist, 1e-300), 0.0, 1.0)), np.inf)
    return ang / math.radians(float(camera.fov_y))


class FieldOfView(RefinePolicy):
    name = "field-of-view"

    def refine(self, t, level, lo, hi):
        return subtended(t.camera, lo, hi) > self.params.fov_fraction

    def priority(self, t, level, lo, hi):
        return subtended(t.camera, lo, hi)
