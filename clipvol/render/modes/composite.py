"""``composite``: front-to-back emission-absorption along the ray (the default mode).

Each sample is classified by the transfer function on the GL and composited; the per-brick path
blends its boxes in visibility order ("under" front to back with early ray termination, "over" back
to front) and the target is resolved on the GL (:mod:`clipvol.render.resolve`). Bricks and cells
the table makes wholly transparent are culled and leapt over (:mod:`clipvol.scene.occupancy`).
"""

from __future__ import annotations

import numpy as np

from .base import DrawMode

__all__ = ["Composite"]


class Composite(DrawMode):
    name = "composite"
    classifies = True
    ordered = True
    culls = True
    sort_last = True
    splats = True

    def sort_last_image(self, raws: list, fmt, tf, value_range) -> np.ndarray:
        """The groups' premultiplied targets "over" each other, back to front."""
        from ...scene.decompose import composite_over

        return composite_over(raws)
