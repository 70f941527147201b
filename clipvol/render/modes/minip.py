"""``minip``: the smallest texel along the ray, mapped through the transfer function on read-back.

Between the per-brick path's boxes the target blends with the ``MIN`` equation (associative). A
transparent value may still be the smallest, so nothing is culled or leapt over.
"""

from __future__ import annotations

import numpy as np

from .base import EXTREME, DrawMode, over_background
from .mip import map_extreme

__all__ = ["MinIp"]


class MinIp(DrawMode):
    name = "minip"
    define = "MODE_MINIP"
    clear = (EXTREME, 0.0, 0.0, 0.0)

    def set_blend(self, ctx, mgl) -> bool:
        ctx.blend_equation = mgl.MIN
        return True

    def read_back(self, raw, params, tf, fmt, value_range, depth):
        m = raw.astype(np.float64)[..., 0]
        rgb, a = map_extreme(m, m < 0.5 * EXTREME, tf, fmt, value_range)
        return over_background(rgb, a, params.background)
