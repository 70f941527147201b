"""Text on rendered frames: anatomical edge labels (R/L, A/P, S/I) for movies and offscreen frames.

The window's HUD draws its own text; offscreen frames and movies have no HUD, so a view of a
patient-frame store is labelled here, at the middle of each image edge, the way radiology viewers
mark their images. Pillow only (its bundled font), no GL.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["label_edges", "present"]


def label_edges(img: np.ndarray, labels: Mapping[str, str], *, size: int = 0, colour=(255, 255, 80, 255)) -> np.ndarray:
    """A copy of RGBA ``img`` with ``labels['left'|'right'|'top'|'bottom']`` written at its edges.

    ``size`` is the font size in pixels (default: about 1/16 of the smaller image side, >= 9).
    """
    from PIL import Image, ImageDraw, ImageFont

    h, w = img.shape[:2]
    size = size or max(9, min(h, w) // 16)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # pillow < 10.1
        font = ImageFont.load_default()
    im = Image.fromarray(np.ascontiguousarray(img), "RGBA")
    draw = ImageDraw.Draw(im)
    pad = max(2, size // 4)
    for edge, text in labels.items():
        if edge not in ("left", "right", "top", "bottom") or not text:
            continue
        x0, y0, x1, y1 = draw.textbbox((0, 0), text, font=font)
        tw, th = x1 - x0, y1 - y0
        pos = {
            "left": (pad, (h - th) // 2),
            "right": (w - tw - pad, (h - th) // 2),
            "top": ((w - tw) // 2, pad),
            "bottom": ((w - tw) // 2, h - th - pad),
        }[edge]
        draw.text((pos[0] - x0, pos[1] - y0), text, font=font, fill=colour, stroke_width=1, stroke_fill=(0, 0, 0, 255))
    return np.asarray(im)


def present(img: np.ndarray, cam, frame=None, *, labels: bool = True) -> np.ndarray:
    """The image a user sees of a frame rendered with ``cam``: flipped left-right for a store whose
    array axes mirror the patient (:func:`clipvol.scene.views.mirrored`) and, for a patient-frame
    store, with its edge letters unless ``labels`` is False. Every offscreen entry point (render,
    movies, the notebook) passes its frames through here, so they agree."""
    from ..scene.views import edge_labels, is_anatomical, mirrored

    out = np.ascontiguousarray(img[:, ::-1]) if mirrored(frame) else img
    if labels and is_anatomical(frame):
        out = label_edges(out, edge_labels(cam, frame))
    return out
