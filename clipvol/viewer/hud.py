"""The heads-up display: frame statistics as text, rasterised with pillow into an RGBA image.

The viewer uploads the image into a texture and blends it over the frame; the offscreen mode can
composite it onto saved frames. Pillow's bundled font (``ImageFont.load_default(size=...)``) keeps
the HUD free of system font paths. Building the lines (:func:`hud_lines`) and drawing them
(:func:`render_text`) are separate so the text can be tested without pixels.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Iterable, Mapping

import numpy as np

__all__ = ["hud_lines", "point_hud_lines", "render_text", "composite_over", "level_counts", "tf_strip", "stack_images",
           "AlertLine", "ALERT_RGBA", "failed_lines"]

#: colour of the lines about failed bricks
ALERT_RGBA = (255, 70, 70, 255)


class AlertLine(str):
    """A HUD line drawn in :attr:`color` (:data:`ALERT_RGBA`) instead of the HUD's text colour;
    otherwise a plain ``str``, so callers that join or search lines are unchanged."""

    color = ALERT_RGBA


def failed_lines(frame_stats, shown: int = 2) -> list[str]:
    """Red lines for the frame's failed bricks (:attr:`FrameStats.failed_bricks`): how many, how
    many nothing stands in for (a hole in the image), and the first ``shown`` with their causes."""
    failed = list(getattr(frame_stats, "failed_bricks", ()) or ())
    if not failed:
        return []
    holes = sum(1 for f in failed if not f.replaced)
    what = f"{holes} missing from the image" if holes else "drawn from a coarser level"
    head = f"FAILED {len(failed)} brick(s): {what}"
    out = [AlertLine(head)]
    for f in failed[:shown]:
        text = str(f)
        out.append(AlertLine("  " + (text if len(text) <= 100 else text[:97] + "...")))
    if len(failed) > shown:
        out.append(AlertLine(f"  and {len(failed) - shown} more"))
    return out


@lru_cache(maxsize=4)
def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # pillow < 10.1: a fixed bitmap font
        return ImageFont.load_default()


def level_counts(value) -> dict[int, float]:
    """Per-level numbers from a dict ``{level: n}``, a sequence indexed by level, or ``None``."""
    if value is None:
        return {}
    if isinstance(value, Mapping):
        return {int(k): v for k, v in sorted(value.items())}
    try:
        return {i: v for i, v in enumerate(value)}
    except TypeError:
        return {}


def _per_level(d: Mapping[int, float], fmt: str) -> str:
    return " ".join(f"L{k}:{fmt.format(v)}" for k, v in d.items() if v) or "-"


def hud_lines(
    *,
    fps: float | None = None,
    frame_stats=None,
    texture_stats=None,
    settings: Mapping[str, object] | None = None,
    message: str = "",
    orientation: Mapping[str, str] | None = None,
) -> list[str]:
    """The HUD's lines of text.

    Parameters
    ----------
    fps : float, optional
        Frames per second (smoothed by the caller).
    frame_stats : FrameStats, optional
        The render action's ``last_frame_stats`` (bricks drawn per level, uploads, texture bytes).
    texture_stats : ClipTextureStats, optional
        The clip-texture's ``stats`` (resident bytes per level, queue length, loads).
    settings : mapping, optional
        Current viewer settings (mode, level, LOD threshold, MIP/composite, transfer function).
    message : str
        A transient status line (e.g. the last key's effect).
    orientation : mapping, optional
        Anatomical labels of the view's edges (:func:`clipvol.scene.orientation.view_labels`).
    """
    lines: list[str] = []
    if orientation:
        lines.append("  ".join(f"{k} {orientation[k]}" for k in ("left", "right", "top", "bottom") if k in orientation))
    if fps is not None:
        lines.append(f"{fps:5.1f} fps")
    if settings:
        lines.append("  ".join(f"{k} {v}" for k, v in settings.items()))
    if frame_stats is not None:
        drawn = level_counts(getattr(frame_stats, "bricks_drawn", None))
        total = int(sum(drawn.values())) if drawn else 0
        lines.append(f"drawn {total} bricks  {_per_level(drawn, '{:d}')}")
        up = getattr(frame_stats, "bytes_uploaded", None)
        tex = getattr(frame_stats, "texture_bytes", None)
        budget = getattr(frame_stats, "texture_budget", None)
        part = []
        if up is not None:
            part.append(f"uploaded {up / 1e6:.2f} MB")
        if tex is not None:
            part.append(f"texture {tex / 1e6:.1f}" + (f"/{budget / 1e6:.0f} MB" if budget else " MB"))
        conv = getattr(frame_stats, "converged", None)
        if conv is not None:
            part.append("converged" if conv else "refining")
        if part:
            lines.append("  ".join(part))
        lines.extend(failed_lines(frame_stats))
    if texture_stats is not None:
        res = getattr(texture_stats, "resident_bytes_per_level", None)
        if res is None:
            res = getattr(texture_stats, "resident_bytes", None)
        res = level_counts(res)
        if res:
            lines.append(f"resident {sum(res.values()) / 1e6:.1f} MB  {_per_level({k: v / 1e6 for k, v in res.items()}, '{:.1f}')}")
        loading = _loading_line(texture_stats)
        if loading:
            lines.append(loading)
    if message:
        lines.append(message)
    return lines


def render_text(lines: Iterable[str], *, font_size: int = 13, padding: int = 6,
                color=(255, 255, 255, 255), background=(0, 0, 0, 150), width: int | None = None) -> np.ndarray:
    """Rasterise ``lines`` into an ``(h, w, 4)`` uint8 straight-alpha RGBA image, row 0 at top.

    The box is ``width`` wide (or as wide as the longest line) with a translucent background. A
    line with a ``color`` attribute (:class:`AlertLine`) is drawn in that colour.
    """
    from PIL import Image, ImageDraw

    lines = list(lines) or [""]
    font = _font(int(font_size))
    probe = ImageDraw.Draw(Image.new("RGBA", (1, 1)))
    boxes = [probe.textbbox((0, 0), ln or " ", font=font) for ln in lines]
    line_h = max(b[3] - min(b[1], 0) for b in boxes) + 2
    w = width or (max(b[2] for b in boxes) + 2 * padding)
    h = line_h * len(lines) + 2 * padding
    img = Image.new("RGBA", (max(int(w), 1), int(h)), tuple(background))
    draw = ImageDraw.Draw(img)
    for i, ln in enumerate(lines):
        draw.text((padding, padding + i * line_h), ln, font=font, fill=tuple(getattr(ln, "color", color)))
    return np.asarray(img, dtype=np.uint8).copy()


def composite_over(image: np.ndarray, overlay: np.ndarray, origin=(0, 0)) -> np.ndarray:
    """Blend straight-alpha ``overlay`` over ``image`` (both RGBA uint8) at ``origin`` (row, col); new array."""
    out = image.copy()
    r0, c0 = origin
    h = min(overlay.shape[0], image.shape[0] - r0)
    w = min(overlay.shape[1], image.shape[1] - c0)
    if h <= 0 or w <= 0:
        return out
    src = overlay[:h, :w].astype(np.float32) / 255.0
    dst = out[r0:r0 + h, c0:c0 + w].astype(np.float32) / 255.0
    a = src[..., 3:4]
    rgb = src[..., :3] * a + dst[..., :3] * (1 - a)
    alpha = a + dst[..., 3:4] * (1 - a)
    out[r0:r0 + h, c0:c0 + w] = np.clip(np.concatenate([rgb, alpha], axis=-1) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return out


def tf_strip(counts, edges, tf, data_range, *, width: int = 300, height: int = 64, padding: int = 6) -> np.ndarray:
    """The data's histogram with the transfer function over it, as ``(h, w, 4)`` uint8 RGBA.

    Why: the window and opacity ramp only make sense against where the data's values are. The
    x axis spans the histogram's value range; grey bars are ``log(1 + count)`` per bin; a band at
    the bottom shows the colour of each value; the white curve is the opacity (0 at the bottom,
    1 at the top); two yellow ticks mark the window's ends.
    """
    from PIL import Image, ImageDraw

    counts = np.asarray(counts, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.float64)
    w, h = int(width), int(height)
    img = Image.new("RGBA", (w, h), (0, 0, 0, 150))
    draw = ImageDraw.Draw(img)
    x0, x1 = padding, w - padding
    top, band = padding, 8
    base = h - padding - band - 1
    lo, hi = float(edges[0]), float(edges[-1])
    span = (hi - lo) or 1.0
    xs = np.arange(x0, x1)
    values = lo + (xs - x0 + 0.5) / (x1 - x0) * span
    # histogram bars
    if counts.size and counts.max() > 0:
        lc = np.log1p(counts) / np.log1p(counts.max())
        nb = counts.size
        for i in range(nb):
            a = x0 + int(round(i / nb * (x1 - x0)))
            b = x0 + int(round((i + 1) / nb * (x1 - x0))) - 1
            y = base - int(round(lc[i] * (base - top)))
            if lc[i] > 0:
                draw.rectangle([a, y, max(a, b), base], fill=(110, 110, 110, 255))
    # colour band and opacity curve
    rgba = tf.lookup(values, data_range)
    for x, c in zip(xs, rgba):
        draw.line([(int(x), base + 2), (int(x), base + 1 + band)], fill=tuple(int(round(v * 255)) for v in c[:3]) + (255,))
    ys = base - np.round(rgba[:, 3] * (base - top)).astype(int)
    draw.line(list(zip(xs.tolist(), ys.tolist())), fill=(255, 255, 255, 255), width=1)
    wlo, whi = tf.window(data_range)
    for v in (wlo, whi):
        if lo <= v <= hi:
            x = x0 + int(round((v - lo) / span * (x1 - x0)))
            draw.line([(x, top), (x, base)], fill=(255, 220, 0, 255))
    return np.asarray(img, dtype=np.uint8).copy()


def stack_images(images) -> np.ndarray:
    """RGBA images one under the other, left-aligned, on a transparent canvas."""
    images = [np.asarray(i, dtype=np.uint8) for i in images if i is not None]
    w = max(i.shape[1] for i in images)
    h = sum(i.shape[0] for i in images)
    out = np.zeros((h, w, 4), dtype=np.uint8)
    y = 0
    for i in images:
        out[y:y + i.shape[0], : i.shape[1]] = i
        y += i.shape[0]
    return out


def point_hud_lines(*, fps: float | None = None, frame_stats=None, tolerance: float | None = None, size=None,
                    settings: Mapping[str, object] | None = None, texture_stats=None, message: str = "") -> list[str]:
    """The point viewer's HUD: fps, points and nodes drawn, the tolerance, what is loading.

    ``frame_stats`` is :class:`clipvol.render.splat.SplatFrameStats`; ``tolerance`` a fraction of
    the window's larger side (shown with its pixels for a window of ``size``).
    """
    lines: list[str] = []
    if fps is not None:
        lines.append(f"{fps:5.1f} fps")
    if tolerance is not None:
        px = f" = {tolerance * max(size):.1f} px" if size else ""
        lines.append(f"tolerance {100 * tolerance:.3g} % of the screen{px}")
    if settings:
        lines.append("  ".join(f"{k} {v}" for k, v in settings.items()))
    if frame_stats is not None:
        per = getattr(frame_stats, "nodes_per_depth", None) or {}
        depths = " ".join(f"d{d}:{n}" for d, n in sorted(per.items()))
        lines.append(f"points {frame_stats.points_drawn:,}  nodes {frame_stats.nodes_drawn:,}" + (f"  {depths}" if depths else ""))
        state = "converged" if frame_stats.converged else f"refining ({frame_stats.missing} nodes loading)"
        if getattr(frame_stats, "clamped", 0):
            state += f"  {frame_stats.clamped:,} splats clamped to the largest point size"
        lines.append(state)
    loading = _loading_line(texture_stats) if texture_stats is not None else ""
    if loading:
        lines.append(loading)
    if message:
        lines.append(message)
    return lines


def _loading_line(texture_stats) -> str:
    """The clip-texture's loading line of both HUDs: queue, loads/s, MB/s and failures (what it has)."""
    q = getattr(texture_stats, "queued", getattr(texture_stats, "queue_length", None))
    mbs = getattr(texture_stats, "mb_per_s", None)
    lps = getattr(texture_stats, "loads_per_s", None)
    part = []
    if q is not None:
        part.append(f"queue {q}")
    if lps is not None:
        part.append(f"{lps:.0f} loads/s")
    if mbs is not None:
        part.append(f"{mbs:.1f} MB/s")
    nf = getattr(texture_stats, "failures", None)
    nf = len(nf) if isinstance(nf, (dict, list, tuple, set)) else nf
    if nf:
        part.append(f"{nf} failed")
    return "  ".join(part)
