"""``mip``: the largest texel along the ray (Wallis, Miller, Price & Reinking, *Three-dimensional
display in nuclear medicine*, IEEE TMI 1989), mapped through the transfer function on read-back.

Between the per-brick path's boxes the target blends with the ``MAX`` equation (associative: any box
order). A transparent value may still be the largest, so nothing is culled or leapt over.
"""

from __future__ import annotations

import numpy as np

from .base import EXTREME, DrawMode, over_background

__all__ = ["Mip", "map_extreme"]


def map_extreme(m: np.ndarray, hit: np.ndarray, tf, fmt, value_range) -> tuple[np.ndarray, np.ndarray]:
    """Straight ``(rgb, alpha)`` of the extreme texels ``m`` where ``hit`` (transparent elsewhere)."""
    from ..gpu_cache import texel_to_raw  # (the cache's module imports the paging stage)

    rgba = tf.lookup(np.where(hit, texel_to_raw(fmt, m), fmt.b), value_range)
    return rgba[..., :3], np.where(hit, rgba[..., 3], 0.0)


class Mip(DrawMode):
    name = "mip"
    define = "MODE_MIP"
    clear = (-EXTREME, 0.0, 0.0, 0.0)
    sort_last = True
    splats = True

    def set_blend(self, ctx, mgl) -> bool:
        ctx.blend_equation = mgl.MAX
        return True

    def read_back(self, raw, params, tf, fmt, value_range, depth):
        m = raw.astype(np.float64)[..., 0]
        rgb, a = map_extreme(m, m > -0.5 * EXTREME, tf, fmt, value_range)
        return over_background(rgb, a, params.background)

    def sort_last_image(self, raws, fmt, tf, value_range):
        """The groups' maxima, mapped once."""
        from ...scene.decompose import composite_max

        m = composite_max([r[..., 0] for r in raws])
        rgb, alpha = map_extreme(m, m > -EXTREME * 0.5, tf, fmt, value_range)
        return np.concatenate([rgb * alpha[..., None], alpha[..., None]], axis=-1)
