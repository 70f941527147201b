"""Brick outlines coloured by level (as OpenGL Volumizer shows its clip-texture levels), drawn over a rendered image.

Each :class:`~clipvol.scene.selection.DrawItem` box is projected with the camera's view-projection
matrix; its 12 edges are clipped against the near plane in homogeneous coordinates (so boxes
around or behind the eye still draw correctly) and rasterised with pillow. Doing this on the
image rather than in GL keeps it identical in the window and in offscreen frames, and testable.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

__all__ = ["LEVEL_COLORS", "level_color", "project_points", "box_segments", "clip_segment", "draw_outlines"]

#: level 0 first: warm colours for fine levels, cold for coarse ones
LEVEL_COLORS = (
    (255, 64, 64), (255, 160, 32), (240, 230, 40), (80, 220, 80), (40, 220, 230),
    (70, 120, 255), (200, 90, 255), (255, 255, 255),
)

_EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7))


def level_color(level: int) -> tuple[int, int, int]:
    """RGB colour of ``level``'s outlines."""
    return LEVEL_COLORS[min(int(level), len(LEVEL_COLORS) - 1)]


def _corners(lo, hi) -> np.ndarray:
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    i = np.arange(8)
    return np.stack([np.where(i & 1, hi[0], lo[0]), np.where(i & 2, hi[1], lo[1]), np.where(i & 4, hi[2], lo[2])], axis=-1)


def _to_clip(camera, points: np.ndarray) -> np.ndarray:
    m = np.asarray(camera.view_projection(), dtype=np.float64)
    ph = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)
    return ph @ m.T


def _clip_to_pixels(clip: np.ndarray, size) -> np.ndarray:
    w, h = size
    ndc = clip[..., :2] / clip[..., 3:4]
    col = (ndc[..., 0] + 1.0) * 0.5 * w
    row = (1.0 - ndc[..., 1]) * 0.5 * h
    return np.stack([col, row], axis=-1)


def project_points(camera, points) -> np.ndarray:
    """Pixel ``(col, row)`` positions (row 0 at top, pixel centres at ``+0.5``) of world points ``(..., 3)``.

    Points behind the eye give meaningless positions; use :func:`box_segments` for clipping.
    """
    return _clip_to_pixels(_to_clip(camera, np.asarray(points, dtype=np.float64)), camera.size)


def box_segments(camera, lo, hi) -> list[tuple[float, float, float, float]]:
    """The 12 edges of box ``(lo, hi)`` as pixel segments ``(c0, r0, c1, r1)``, clipped to the near plane."""
    clip = _to_clip(camera, _corners(lo, hi))
    out = []
    for a, b in _EDGES:
        pa, pb = clip[a], clip[b]
        # near plane in OpenGL clip space: z >= -w, i.e. d = z + w >= 0
        da, db = pa[2] + pa[3], pb[2] + pb[3]
        if da < 0 and db < 0:
            continue
        if da < 0 or db < 0:
            t = da / (da - db)
            q = pa + t * (pb - pa)
            if da < 0:
                pa = q
            else:
                pb = q
        if pa[3] <= 1e-12 or pb[3] <= 1e-12:
            continue
        (c0, r0), (c1, r1) = _clip_to_pixels(np.stack([pa, pb]), camera.size)
        out.append((float(c0), float(r0), float(c1), float(r1)))
    return out


def clip_segment(seg, rect):
    """Liang-Barsky: the part of segment ``(c0, r0, c1, r1)`` inside ``rect`` ``(cmin, rmin, cmax, rmax)``, or None."""
    c0, r0, c1, r1 = seg
    dc, dr = c1 - c0, r1 - r0
    t0, t1 = 0.0, 1.0
    for p, q in ((-dc, c0 - rect[0]), (dc, rect[2] - c0), (-dr, r0 - rect[1]), (dr, rect[3] - r0)):
        if p == 0:
            if q < 0:
                return None
            continue
        t = q / p
        if p < 0:
            t0 = max(t0, t)
        else:
            t1 = min(t1, t)
        if t0 > t1:
            return None
    return (c0 + t0 * dc, r0 + t0 * dr, c0 + t1 * dc, r0 + t1 * dr)


def draw_outlines(image: np.ndarray, camera, items: Iterable, width: int = 1, alpha: int = 255) -> np.ndarray:
    """Return a copy of ``image`` (``(h, w, 4)`` uint8, row 0 at top) with every item's box outlined.

    ``items`` are objects with ``level``, ``lo`` and ``hi`` (``DrawItem``) drawn in their level's
    colour (:data:`LEVEL_COLORS`).
    """
    from PIL import Image, ImageDraw

    img = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), mode="RGBA")
    draw = ImageDraw.Draw(img)
    w, h = camera.size
    for it in items:
        color = level_color(it.level) + (int(alpha),)
        for seg in box_segments(camera, it.lo, it.hi):
            seg = clip_segment(seg, (-2.0, -2.0, w + 2.0, h + 2.0))
            if seg is None:
                continue
            c0, r0, c1, r1 = seg
            # pixel centres are at +0.5; pillow's integer coordinates are pixel centres
            draw.line([(c0 - 0.5, r0 - 0.5), (c1 - 0.5, r1 - 0.5)], fill=color, width=int(width))
    return np.asarray(img, dtype=np.uint8).copy()
