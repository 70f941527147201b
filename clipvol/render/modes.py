"""What each render mode needs from the frame around the ray loop: the shader variant, the target's
clear value and blending, and the read-back that turns the float target into the image.

Composite mode draws colour into the target and is resolved on the GL (:mod:`clipvol.render.resolve`).
The other modes write one value (or two) per pixel that the CPU maps through the transfer function,
as MIP always has (Wallis, Miller, Price & Reinking, *Three-dimensional display in nuclear medicine*,
IEEE TMI 1989):

* ``mip`` / ``minip`` - the largest / smallest texel along the ray; between the boxes of the per-brick
  path the target blends with the ``MAX`` / ``MIN`` equation (associative: any box order).
* ``average`` - the mean of the samples inside the volume along the ray, a radiograph-like
  projection. A ray writes ``(sum of texel * delta, sum of delta)``; boxes add up (``ONE, ONE``),
  and the read-back divides. Weighting each sample by its step ``delta`` makes a cut of several
  levels average over the ray's length (a coarse level's samples are farther apart); on one level
  it is the plain sample mean. ``raw = a * texel + b`` is affine, so the mean texel maps to the
  mean value.
* ``iso`` - the first sample at or above ``iso_value`` (placed between it and the sample before by
  linear interpolation), written opaque as ``(t, |g . v| / |g|, texel, 1)``: the per-brick path's
  front-to-back "under" (or back-to-front "over") blending keeps the nearest box's hit, the single
  pass stops the ray there. The surface is lit on read-back with the ``SHADING`` variant's
  Blinn-Phong terms (Levoy, *Display of surfaces from volume data*, IEEE CG&A 1988; the light at
  the eye) and coloured by the transfer function at ``iso_value`` or by the hit's depth.

The projections neither cull bricks the transfer function makes transparent nor leap over empty
cells: in MIP/minIP a transparent value may still be the extreme, and in the average every sample
(air included) counts. An iso-surface does not depend on the table's opacity, but on whether a
value reaches ``iso_value``: :func:`occupancy_tf` is a two-entry table, transparent below the
value and opaque from it, through which the same brick culling and cell flags
(:mod:`clipvol.scene.occupancy`, conservative over each brick's and cell's sampling footprint)
skip whatever lies wholly below the surface's value - no sample there can be a hit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["REDUCED_MODES", "mode_defines", "clear_value", "set_blend", "iso_texel", "depth_range", "reduce_image",
           "occupancy_tf"]

#: modes whose target holds per-pixel values that the read-back maps through the transfer function
REDUCED_MODES = ("mip", "minip", "average", "iso")
#: the target's value where no ray wrote (MIP, minIP): beyond any texel
_EXTREME = 3.0e38
_DEFINES = {"mip": "MODE_MIP", "minip": "MODE_MINIP", "average": "MODE_AVERAGE", "iso": "MODE_ISO"}


def mode_defines(mode: str) -> dict:
    """The shader ``#define`` of ``mode`` (:mod:`clipvol.render.glsl`; composite defines none)."""
    return {name: mode == m for m, name in _DEFINES.items()}


def clear_value(mode: str) -> tuple[float, float, float, float]:
    """The target's clear value for the reduced modes (every other target clears to 0)."""
    if mode == "mip":
        return (-_EXTREME, 0.0, 0.0, 0.0)
    if mode == "minip":
        return (_EXTREME, 0.0, 0.0, 0.0)
    return (0.0, 0.0, 0.0, 0.0)


def set_blend(ctx, mgl, mode: str) -> bool:
    """Set the per-brick path's blending for a projection mode (MIP ``MAX``, minIP ``MIN``, average
    ``ONE, ONE`` addition); False for composite and iso (ordered blending, set by the caller)."""
    if mode == "mip":
        ctx.blend_equation = mgl.MAX
    elif mode == "minip":
        ctx.blend_equation = mgl.MIN
    elif mode == "average":
        ctx.blend_equation = mgl.FUNC_ADD
        ctx.blend_func = mgl.ONE, mgl.ONE
    else:
        return False
    return True


def occupancy_tf(params, tf, data_range):
    """The table whose transparent values the frame may skip: ``tf`` itself (composite), or for
    ``iso`` a two-entry table over the window ``iso_value -+ d`` (``d`` a thousandth of the data's
    range): values below ``iso_value - d / 2`` reach only the transparent entry, every value from
    ``iso_value`` on reaches the opaque one (``GL_LINEAR`` lookup, texel centres at 1/4 and 3/4)."""
    if params.mode != "iso":
        return tf
    from ..scene.transfer import TransferFunction

    lo, hi = (float(v) for v in data_range)
    d = max(1e-3 * (hi - lo), 1e-6 * max(abs(params.iso_value), 1.0))
    table = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0]])
    return TransferFunction(table, value_range=(params.iso_value - d, params.iso_value + d), name="iso")


def iso_texel(fmt, iso_value: float | None) -> float:
    """``iso_value`` as a texel of ``fmt`` (``raw = a * texel + b``, ``a > 0``), clipped to float32."""
    if iso_value is None:
        return 0.0
    return float(np.clip((float(iso_value) - fmt.b) / fmt.a, -3e38, 3e38))


def depth_range(cam, lo, hi) -> tuple[float, float]:
    """``(near, far)`` of the ray parameter ``t`` over the box ``[lo, hi]``: distance from the eye
    (perspective; near at least 0) or signed distance from the plane through the camera centre
    (orthographic), as the shaders measure ``t``. ``iso_color="depth"`` spans its colours over it."""
    c = np.array(np.meshgrid(*zip(lo, hi), indexing="ij"), dtype=np.float64).reshape(3, -1).T  # 8 corners
    f = np.asarray(cam.forward, dtype=np.float64)
    if cam.orthographic:
        t = (c - np.asarray(cam.center, dtype=np.float64)) @ f
        return float(t.min()), float(t.max())
    rel = c - np.asarray(cam.eye, dtype=np.float64)
    return max(0.0, float((rel @ f).min())), float(np.linalg.norm(rel, axis=1).max())


def reduce_image(raw: np.ndarray, params, tf, fmt, value_range, depth: tuple[float, float]) -> np.ndarray:
    """Premultiplied ``(h, w, 4)`` float64 RGBA over ``params.background`` from the float target
    ``raw`` (rows top first) of a reduced mode; ``depth``: :func:`depth_range` of the volume box."""
    from .gpu_cache import texel_to_raw

    mode = params.mode
    r = raw.astype(np.float64)
    if mode == "iso":
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
        rgb = np.minimum(lit, 1.0)
        a = np.where(hit, 1.0, 0.0)  # the surface is opaque
    else:
        if mode == "average":  # a mean of whole numbers need not be whole: not rounded like MIP's texel
            hit = r[..., 1] > 0.0
            value = fmt.a * np.where(hit, r[..., 0] / np.where(hit, r[..., 1], 1.0), 0.0) + fmt.b
        else:
            m = r[..., 0]
            hit = (m > -0.5 * _EXTREME) if mode == "mip" else (m < 0.5 * _EXTREME)
            value = texel_to_raw(fmt, m)
        rgba = tf.lookup(np.where(hit, value, fmt.b), value_range)
        rgb = rgba[..., :3]
        a = np.where(hit, rgba[..., 3], 0.0)
    prem = np.concatenate([rgb * a[..., None], a[..., None]], axis=-1)
    br, bg, bb, ba = params.background
    return prem + (1.0 - a[..., None]) * np.array([br * ba, bg * ba, bb * ba, ba])

