"""The converged picture: what every frame's error is measured against.

A setting's error used to be measured against clipvol's own full-resolution frame (level 0 at the
frame's step, one ray per pixel). That frame is itself off the picture the data holds: a sharp
transfer function sampled every half voxel misses thin shells between samples (wood-grain rings,
broken skull), and one ray per pixel aliases the edges. A faster setting can then look worse or
better than it is, and an error budget ("<= 5 % of pixels visibly different") means "close to
another approximation". The *converged picture* is the limit those approximations tend to:
level 0, a fine step (:data:`CONVERGED_STEP`, a quarter of a voxel), supersampled - drawn at ``k``
times the image's width and height and box-filtered down (each pixel the mean of the ``k x k``
rays inside it: the pixel's area, not its centre). Issue 41 measures it this way; so do Younesy,
Moller & Carr, *Improving the quality of multi-resolution volume rendering* (2006), whose error is
against a high-quality reference rendering rather than a level-0 frame at the same sampling.

It is drawn once per view (and transfer function) and cached (:class:`ConvergedPictures`); the
full-resolution frame's own error against it is shown beside every setting's, so the reader sees
how much of a setting's error the full-resolution frame shares.

The box filter (:func:`box_filter`) is pure numpy; the drawing goes through any ``render(camera,
params) -> image`` callable, so the report (a :class:`~clipvol.app.session.RenderSession`) and the
benchmarks (a bare :class:`~clipvol.render.action.ClipRenderAction`) share it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Hashable

import numpy as np

from ..errors import ParameterError

__all__ = ["CONVERGED_STEP", "CONVERGED_SUPERSAMPLE", "box_filter", "supersampled", "converged_params",
           "ConvergedPictures"]

#: sample spacing (voxels of level 0) of the converged picture
CONVERGED_STEP = 0.25
#: rays per pixel along each axis of the converged picture (2 on a CPU rasteriser; 4 where affordable)
CONVERGED_SUPERSAMPLE = 2


def _factor(k) -> int:
    if isinstance(k, bool) or int(k) != k or int(k) < 1:
        raise ParameterError(f"supersample: expected an integer >= 1, got {k!r}")
    return int(k)


def supersampled(camera, k: int):
    """``camera`` drawing ``k`` times as many pixels along each axis over the same field of view.

    The pixel grid of the result tiles each pixel of ``camera`` with ``k x k`` pixels, so that
    :func:`box_filter` of its image is the area average of each original pixel."""
    k = _factor(k)
    w, h = camera.size
    return replace(camera, size=(int(w) * k, int(h) * k))


def box_filter(img: np.ndarray, k: int) -> np.ndarray:
    """Mean of each ``k x k`` block of a straight (non-premultiplied) RGBA image, as straight RGBA.

    The colours are averaged premultiplied (the colour a pixel composites to is the mean of what
    its rays composite to) and divided by the mean opacity again; a block with no opacity stays
    transparent black. ``uint8`` in, ``uint8`` out (rounded); float in ``[0, 1]`` in, float out.
    """
    k = _factor(k)
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] != 4:
        raise ParameterError(f"img: expected an (h, w, 4) RGBA image, got shape {a.shape}")
    h, w = a.shape[0] // k, a.shape[1] // k
    if h * k != a.shape[0] or w * k != a.shape[1]:
        raise ParameterError(f"img: its size {a.shape[1]}x{a.shape[0]} is not a multiple of the factor {k}")
    f = a.astype(np.float64) / 255.0 if a.dtype == np.uint8 else a.astype(np.float64)
    prem = np.concatenate([f[..., :3] * f[..., 3:4], f[..., 3:4]], axis=-1)
    mean = prem.reshape(h, k, w, k, 4).mean(axis=(1, 3))
    alpha = mean[..., 3:4]
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.where(alpha > 0, mean[..., :3] / np.where(alpha > 0, alpha, 1.0), 0.0)
    out = np.concatenate([np.clip(rgb, 0.0, 1.0), alpha], axis=-1)
    if a.dtype == np.uint8:
        return np.rint(out * 255.0).astype(np.uint8)
    return out


def converged_params(params, *, level: int = 0, step: float = CONVERGED_STEP):
    """``params`` drawing the converged picture: ``level`` fixed (0 unless the caller's cap forbids
    it), ``step`` voxels, and no approximation that trades image for time (adaptive image
    sampling off, no block or texel budget, no error budget)."""
    ch = dict(policy="fixed", level=int(level), step=float(step), block_budget=None, max_error=None,
              max_texels_drawn=None)
    if hasattr(params, "refine_tolerance"):
        ch["refine_tolerance"] = 0.0
    return replace(params, **ch)


class ConvergedPictures:
    """The converged picture of each view, drawn on first use and cached.

    Parameters
    ----------
    render : callable
        ``render(camera, params) -> (h, w, 4) uint8`` straight RGBA: draws one converged frame
        (waiting for every brick) with the given parameters.
    base : RenderParams
        The parameters of the frames it is compared with (mode, transfer function's window,
        lighting, background); :func:`converged_params` turns them into the reference's.
    supersample : int
        ``k``: rays per pixel along each axis (:data:`CONVERGED_SUPERSAMPLE`).
    step : float
        Sample spacing of the reference in voxels (:data:`CONVERGED_STEP`).
    level : int
        The level drawn (0; a coarser one only where level 0 exceeds what may be held).
    """

    def __init__(self, render: Callable, base, *, supersample: int = CONVERGED_SUPERSAMPLE,
                 step: float = CONVERGED_STEP, level: int = 0) -> None:
        self.render = render
        self.k = _factor(supersample)
        if not (np.isfinite(step) and step > 0):
            raise ParameterError(f"step: expected a sample spacing > 0 voxels, got {step!r}")
        self.step = float(step)
        self.level = int(level)
        self.params = converged_params(base, level=self.level, step=self.step)
        self._cache: dict = {}

    def describe(self) -> str:
        """One line naming the picture, for reports: level, step and supersampling."""
        return (f"level {self.level} at step {self.step:g} voxel, {self.k}x{self.k} rays per pixel "
                "box-filtered")

    def get(self, camera, key: Hashable = None) -> np.ndarray:
        """The converged picture of ``camera`` at ``camera.size`` (``(h, w, 4)`` uint8, straight RGBA).

        ``key`` names the view for the cache (e.g. ``(view, transfer function)``); default the
        camera itself (cameras are frozen dataclasses)."""
        key = camera if key is None else key
        if key not in self._cache:
            big = self.render(supersampled(camera, self.k), self.params)
            self._cache[key] = box_filter(big, self.k)
        return self._cache[key]
