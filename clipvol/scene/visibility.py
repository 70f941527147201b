"""Per-brick visibility from occlusion maps: the CPU half of the visibility estimate (pure numpy).

After Wang, Garcia & Shen (2007, section IV-E). A cheap low-resolution front-to-back pass
(:mod:`clipvol.render.visibility`) leaves *occlusion layers*: for depths ``d_0 = 0 < d_1 < ... <
d_{K-1}`` along the view axis, the opacity accumulated by everything nearer than ``d_k``, per pixel of
a small image. A brick's visibility is ``1 - mean(alpha)`` over its screen footprint (the bounding
rectangle of its projected corners) in the last layer in front of the brick's nearest point - the
opacity in front of the brick, on average (not the minimum: this is an estimate for ranking, not a
conservative occlusion test). The mean over any rectangle is four look-ups in a summed-area table,
so a frame's thousands of bricks cost one ``cumsum`` per layer.

A brick that reaches the eye plane (a corner at or behind the eye) gets visibility 1.

References
----------
C. Wang, A. Garcia, H.-W. Shen, "Interactive Level-of-Detail Selection Using Image-Based Quality
Metric for Large Volume Visualization", IEEE TVCG 13(1), 2007.
F. C. Crow, "Summed-area tables for texture mapping", SIGGRAPH 1984.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera

__all__ = ["OcclusionLayers", "summed_area_table", "rect_mean", "screen_rects", "box_depths"]


def summed_area_table(img: np.ndarray) -> np.ndarray:
    """``(..., h + 1, w + 1)`` float64 table ``S`` with ``S[..., y, x] = img[..., :y, :x].sum()``."""
    a = np.asarray(img, dtype=np.float64)
    s = np.zeros(a.shape[:-2] + (a.shape[-2] + 1, a.shape[-1] + 1))
    s[..., 1:, 1:] = a.cumsum(-2).cumsum(-1)
    return s


def rect_mean(sat: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    """Mean of the image over pixel rectangles ``[x0, x1) x [y0, y1)`` (integer arrays, non-empty) of ``sat`` (2-D)."""
    tot = sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0]
    return tot / np.maximum((x1 - x0) * (y1 - y0), 1)


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    lo, hi = np.atleast_2d(lo), np.atleast_2d(hi)
    c = np.empty((len(lo), 8, 3))
    for k in range(8):
        c[:, k] = np.where([(k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1], hi, lo)
    return c


def box_depths(camera: Camera, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """``(nearest, farthest)`` depth along the view axis of each box's corners (``(n,)``, world units)."""
    c = box_corners(np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64))
    d = (c - camera.eye) @ np.asarray(camera.forward, dtype=np.float64)
    return d.min(axis=1), d.max(axis=1)


def screen_rects(camera: Camera, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Pixel bounding rectangles ``(n, 4)`` ``x0, y0, x1, y1`` (float, row 0 at the top, clipped to
    the image) of boxes' projections, and ``(n,)`` bool: the box reaches the eye plane (its rectangle
    is then the whole image)."""
    c = box_corners(np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64))
    n = len(c)
    w, h = camera.size
    hom = np.concatenate([c, np.ones((n, 8, 1))], axis=2) @ camera.view_projection().T  # (n, 8, 4)
    if camera.orthographic:
        behind = np.zeros(n, dtype=bool)
        ww = hom[..., 3]
    else:
        ww = hom[..., 3]
        behind = np.any(ww <= 1e-9 * max(camera.near, 1e-30), axis=1)
        ww = np.where(ww <= 0, 1.0, ww)
    x = (hom[..., 0] / ww + 1.0) * 0.5 * w
    y = (1.0 - hom[..., 1] / ww) * 0.5 * h
    r = np.stack([x.min(1), y.min(1), x.max(1), y.max(1)], axis=1)
    r = np.clip(r, 0.0, [w, h, w, h])
    r[behind] = (0.0, 0.0, w, h)
    return r, behind


@dataclass
class OcclusionLayers:
    """Accumulated opacity in front of ``depths`` (``(K,)`` ascending, ``depths[0] = 0`` with an empty
    map) as ``alpha`` ``(K, h, w)`` in ``[0, 1]`` (row 0 at the top) for ``camera`` (its pixel size
    may differ from the maps': rectangles are scaled)."""

    camera: Camera
    depths: np.ndarray
    alpha: np.ndarray
    key: object = None  # what the estimate depends on besides the view (e.g. the transfer function)
    _sat: np.ndarray | None = field(default=None, repr=False)

    def visibility(self, lo, hi, camera: Camera | None = None) -> np.ndarray:
        """``(n,)`` estimated visibility ``1 - mean alpha in front`` of boxes ``lo``/``hi`` ``(n, 3)``."""
        cam = camera or self.camera
        if self._sat is None:
            self._sat = summed_area_table(np.clip(self.alpha, 0.0, 1.0))
        rect, behind = screen_rects(cam, lo, hi)
        near, _ = box_depths(cam, lo, hi)
        k = np.clip(np.searchsorted(self.depths, near, side="right") - 1, 0, len(self.depths) - 1)
        k[behind] = 0
        K, h, w = self.alpha.shape
        W, H = cam.size
        sx, sy = w / W, h / H
        x0 = np.clip(np.floor(rect[:, 0] * sx), 0, w - 1).astype(np.int64)
        y0 = np.clip(np.floor(rect[:, 1] * sy), 0, h - 1).astype(np.int64)
        x1 = np.clip(np.ceil(rect[:, 2] * sx), x0 + 1, w).astype(np.int64)
        y1 = np.clip(np.ceil(rect[:, 3] * sy), y0 + 1, h).astype(np.int64)
        s = self._sat
        tot = s[k, y1, x1] - s[k, y0, x1] - s[k, y1, x0] + s[k, y0, x0]
        mean = tot / ((x1 - x0) * (y1 - y0))
        return np.clip(1.0 - mean, 0.0, 1.0)

    def reusable(self, camera: Camera, key=None, max_angle: float = 3.0, max_move: float = 0.02,
                 scale: float = 1.0) -> bool:
        """Whether this estimate still serves ``camera``: the same ``key``, the same projection and
        image size, a view direction within ``max_angle`` degrees and an eye moved less than
        ``max_move * scale`` (``scale``: e.g. the volume's diagonal)."""
        c = self.camera
        if key != self.key or c.orthographic != camera.orthographic or tuple(c.size) != tuple(camera.size):
            return False
        if (c.fov_y, c.width, c.height) != (camera.fov_y, camera.width, camera.height):
            return False
        cosang = float(np.clip(np.dot(c.forward, camera.forward), -1.0, 1.0))
        if math.degrees(math.acos(cosang)) > max_angle:
            return False
        return float(np.linalg.norm(np.subtract(c.eye, camera.eye))) <= max_move * scale
