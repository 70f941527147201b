"""Failed bricks of a frame: which of the wanted cut could not be drawn, why, and where on screen.

A brick whose loads failed (a checksum, a corrupt chunk, a broken level ``zarr.json``: see
:class:`~clipvol.paging.cliptexture.ClipTexture`) is drawn from its nearest ancestor that loaded -
an ancestor that loaded has passed the same checks, so it is verified data, only coarser. A frame
must never pass off a hole as data, though: :func:`failed_bricks` lists every wanted brick that
failed, with its cause and the ancestor drawn in its place (None: nothing stands in, the region
is missing from the image), and :func:`hatch_failed` marks the regions without a stand-in on the
image, for a caller who writes it anyway (``--allow-partial``).

Pure numpy: the footprint of a brick is the convex hull of its world points (the box's corners, or
a slice plane's section through it) projected by the camera's view-projection matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FailedBrick", "failed_bricks", "describe_failed", "footprint_mask", "hatch_failed", "HATCH_RGBA"]

#: colour of the hatching over regions that could not be drawn (opaque red)
HATCH_RGBA = (255, 0, 0, 255)
#: stripe period in pixels (half red, half the image)
HATCH_PERIOD = 6
#: causes are cut to this many characters (one line each)
CAUSE_CHARS = 300


@dataclass(frozen=True, slots=True)
class FailedBrick:
    """A wanted brick of a frame that failed to load.

    ``cause`` is the first line of the loader's error; ``stand_in`` the ``(level, index)`` of the
    ancestor drawn over its region, or None where nothing was (the region is missing)."""

    level: int
    index: tuple[int, int, int]
    cause: str
    stand_in: tuple[int, tuple[int, int, int]] | None = None

    @property
    def replaced(self) -> bool:
        return self.stand_in is not None

    def __str__(self) -> str:
        z, y, x = self.index
        name = f"brick (level {self.level}, {z}, {y}, {x})"
        return self.cause if name in self.cause else f"{name}: {self.cause}"


def _cause(err: BaseException) -> str:
    """The first line of ``err``; a foreign exception (a plug-in loader's) keeps its type's name."""
    from ..errors import ClipvolError

    text = str(err).strip()
    line = text.splitlines()[0] if text else ""
    if not isinstance(err, ClipvolError):
        line = f"{type(err).__name__}: {line}" if line else type(err).__name__
    return line if len(line) <= CAUSE_CHARS else line[: CAUSE_CHARS - 3] + "..."


def failed_bricks(selection, clip_texture) -> tuple[FailedBrick, ...]:
    """The wanted bricks of ``selection`` that ``clip_texture`` holds as failed, each with the
    drawn ancestor that covers it (None if no item of the selection does)."""
    from ..paging.cliptexture import BrickState

    snapshot = getattr(clip_texture, "failure_snapshot", None)
    failures = snapshot() if snapshot is not None else dict(getattr(clip_texture, "failures", {}))
    if not failures:
        return ()
    wanted = selection.wanted_keys()
    if not len(wanted):
        return ()
    by_key = {(k.level, tuple(k.index)): e for k, e in failures.items()}
    items = selection.item_keys()
    span = np.asarray(selection.items.span, dtype=np.int64)
    single = {tuple(r) for r in items[span == 1].tolist()}  # one brick each: a set lookup
    merged_items, merged_span = items[span > 1], span[span > 1]  # few: scanned
    top = int(items[:, 0].max(initial=-1))
    out = []
    for L, z, y, x in wanted.tolist():
        err = by_key.get((L, (z, y, x)))
        if err is None or clip_texture.state(L, (z, y, x)) != BrickState.FAILED:
            continue
        stand_in = None
        for La in range(L + 1, top + 1):
            a = (z >> (La - L), y >> (La - L), x >> (La - L))
            if (La, *a) in single:
                stand_in = (La, a)
                break
            cover = (merged_items[:, 0] == La) & np.all(
                (merged_items[:, 1:] <= a) & (np.asarray(a) < merged_items[:, 1:] + merged_span[:, None]), axis=1)
            if cover.any():
                stand_in = (La, tuple(int(v) for v in merged_items[np.argmax(cover), 1:]))
                break
        out.append(FailedBrick(L, (z, y, x), _cause(err), stand_in))
    return tuple(out)


def describe_failed(failed, shown: int = 3) -> str:
    """``failed`` bricks as one line: the first ``shown`` with their causes, then a count."""
    failed = list(failed)
    text = "; ".join(str(f) for f in failed[:shown])
    if len(failed) > shown:
        text += f"; and {len(failed) - shown} more"
    return text


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D ``points`` in counter-clockwise order (monotone chain)."""
    pts = np.unique(np.round(points, 9), axis=0)
    if len(pts) < 3:
        return pts
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]

    def cross(o, a, b) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    def half(seq):
        h: list = []
        for p in seq:
            while len(h) >= 2 and cross(h[-2], h[-1], p) <= 0:
                h.pop()
            h.append(p)
        return h

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def footprint_mask(camera, world_points, size) -> np.ndarray:
    """``(h, w)`` bool: pixels whose centres lie in the convex hull of ``world_points`` (``(k, 3)``
    ``(x, y, z)``) as ``camera`` projects them (row 0 at the top). A point at or behind the eye of a
    perspective camera makes the whole image count (the hull is unbounded on screen)."""
    w, h = (int(v) for v in size)
    pts = np.atleast_2d(np.asarray(world_points, dtype=np.float64))
    mask = np.zeros((h, w), dtype=bool)
    if not len(pts):
        return mask
    clip = np.c_[pts, np.ones(len(pts))] @ camera.view_projection().T
    if np.any(clip[:, 3] <= 1e-12):
        mask[:] = True
        return mask
    ndc = clip[:, :2] / clip[:, 3:4]
    px = np.c_[(ndc[:, 0] + 1.0) * 0.5 * w, (1.0 - ndc[:, 1]) * 0.5 * h]
    hull = _hull(px)
    if len(hull) < 3:
        return mask
    x0, y0 = np.floor(hull.min(axis=0)).astype(int)
    x1, y1 = np.ceil(hull.max(axis=0)).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x0 >= x1 or y0 >= y1:
        return mask
    cx, cy = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
    inside = np.ones(cx.shape, dtype=bool)
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        inside &= (b[0] - a[0]) * (cy - a[1]) - (b[1] - a[1]) * (cx - a[0]) >= 0
    mask[y0:y1, x0:x1] = inside
    return mask


def box_corners(lo, hi) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of the box ``[lo, hi]``."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    sel = np.array([[(i >> a) & 1 for a in range(3)] for i in range(8)], dtype=bool)
    return np.where(sel, hi, lo)


def hatch_failed(image: np.ndarray, camera, pyramid, failed, plane=None) -> np.ndarray:
    """A copy of ``image`` (``(h, w, 4)`` uint8) with diagonal red stripes over the footprint of
    every failed brick that nothing stood in for (``plane``: a slice, whose footprint is the plane's
    section through the brick)."""
    out = np.array(image, copy=True)
    h, w = out.shape[:2]
    mask = np.zeros((h, w), dtype=bool)
    for f in failed:
        if f.replaced:
            continue
        lo, hi = pyramid.node_box(f.level, f.index)
        pts = box_corners(lo, hi) if plane is None else plane.box_polygon(lo, hi)
        mask |= footprint_mask(camera, pts, (w, h))
    yy, xx = np.mgrid[0:h, 0:w]
    stripes = ((xx + yy) // (HATCH_PERIOD // 2)) % 2 == 0
    out[mask & stripes] = HATCH_RGBA
    return out
