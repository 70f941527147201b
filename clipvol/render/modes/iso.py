"""``iso``: the first sample at or above ``iso_value`` along the ray, lit on read-back.

The hit is placed between that sample and the one before by linear interpolation and written opaque
as ``(t, |g . v| / |g|, texel, 1)``: the per-brick path's front-to-back "under" (or back-to-front
"over") blending keeps the nearest box's hit, the single pass stops the ray there. The surface is
lit on read-back with the ``SHADING`` variant's Blinn-Phong terms (Levoy, *Display of surfaces from
volume data*, IEEE CG&A 1988; the light at the eye) and coloured by the transfer function at
``iso_value`` or by the hit's depth.

An iso-surface does not depend on the table's opacity but on whether a value reaches
``iso_value``: :meth:`Iso.occupancy_tf` is a two-entry table, transparent below the value and opaque
from it, through which the same brick culling and cell flags (:mod:`clipvol.scene.occupancy`,
conservative over each brick's and cell's sampling footprint) skip whatever lies wholly below the
surface's value - no sample there can be a hit.
"""

from __future__ import annotations

import numpy as np

from ..uniforms import uset
from .base import DrawMode, over_background

__all__ = ["Iso", "iso_texel"]


def iso_texel(fmt, iso_value: float | None) -> float:
    """``iso_value`` as a texel of ``fmt`` (``raw = a * texel + b``, ``a > 0``), clipped to float32."""
    if iso_value is None:
        return 0.0
    return float(np.clip((float(iso_value) - fmt.b) / fmt.a, -3e38, 3e38))


class Iso(DrawMode):
    name = "iso"
    define = "MODE_ISO"
    ordered = True
    culls = True
    requires = ("iso_value",)

    def occupancy_tf(self, params, tf, data_range):
        """A two-entry table over the window ``iso_value -+ d`` (``d`` a thousandth of the data's
        range): values below ``iso_value - d / 2`` reach only the transparent entry, every value
        from ``iso_value`` on reaches the opaque one (``GL_LINEAR`` lookup, texel centres at 1/4
        and 3/4)."""
        from ...scene.transfer import TransferFunction

        lo, hi = (float(v) for v in data_range)
        d = max(1e-3 * (hi - lo), 1e-6 * max(abs(params.iso_value), 1.0))
        table = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]])
        return TransferFunction(table, value_range=(params.iso_value - d, params.iso_value + d), name="iso")

    def uniforms(self, prog, fmt, params) -> None:
        uset(prog, "u_iso", iso_texel(fmt, params.iso_value))

    def read_back(self, raw, params, tf, fmt, value_range, depth):
        r = raw.astype(np.float64)
        hit = r[..., 3] > 0.5
        if params.iso_color == "depth":
            near, far = depth
            t = (r[..., 0] - near) / (far - near) if far > near else np.zeros(r.shape[:2])
            lo, hi = tf.window(value_range)  # the table's colours from its bottom (near) to its top (far)
            rgba = tf.lookup(lo + np.clip(t, 0.0, 1.0) * (hi - lo), value_range)
        else:
            rgba = tf.lookup(np.full(r.shape[:2], float(params.iso_value)), value_range)
        d = r[..., 1]
        lit = rgba[..., :3] * (params.ambient + params.diffuse * d)[..., None] \
            + (params.specular * d ** params.shininess)[..., None]
        return over_background(np.minimum(lit, 1.0), np.where(hit, 1.0, 0.0), params.background)  # opaque
