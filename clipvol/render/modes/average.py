"""``average``: the mean of the samples inside the volume along the ray, a radiograph-like projection.

A ray writes ``(sum of texel * delta, sum of delta)``; the per-brick path's boxes add up (``ONE,
ONE``) and the read-back divides. Weighting each sample by its step ``delta`` makes a cut of several
levels average over the ray's length (a coarse level's samples are farther apart); on one level it
is the plain sample mean. ``raw = a * texel + b`` is affine, so the mean texel maps to the mean
value. Every sample (air included) counts: nothing is culled or leapt over.
"""

from __future__ import annotations

import numpy as np

from .base import DrawMode, over_background

__all__ = ["Average"]


class Average(DrawMode):
    name = "average"
    define = "MODE_AVERAGE"

    def set_blend(self, ctx, mgl) -> bool:
        ctx.blend_equation = mgl.FUNC_ADD
        ctx.blend_func = mgl.ONE, mgl.ONE
        return True

    def read_back(self, raw, params, tf, fmt, value_range, depth):
        r = raw.astype(np.float64)
        hit = r[..., 1] > 0.0  # a mean of whole numbers need not be whole: not rounded like MIP's texel
        value = fmt.a * np.where(hit, r[..., 0] / np.where(hit, r[..., 1], 1.0), 0.0) + fmt.b
        rgba = tf.lookup(np.where(hit, value, fmt.b), value_range)
        return over_background(rgba[..., :3], np.where(hit, rgba[..., 3], 0.0), params.background)
