"""Framing what the transfer function shows: the visible voxels of a volume, and the eye distance that fits them.

Why: a scan's volume box holds much air - the MNI template's box is 197 x 233 x 189 mm around a
brain of about 140 x 175 x 140 - and a view fitted to the sphere around the box shows the brain
in the middle third of the image. A user frames what is visible (ParaView's "reset camera" fits
the bounds of what is shown, a clinical viewer zooms to the anatomy), and so do the report's views
(``clipvol report --frame visible``, the default): :func:`visible_points` finds the surface of the
voxels the table gives any opacity, :func:`fit_points_distance` the distance at which they fill
every view of a path.

:func:`visible_points` reads one small level whole (the finest with at most ``max_voxels`` voxels),
so it costs a fraction of a second; a structure thinner than that level's voxels can be averaged
away there, so each voxel is widened by :data:`MARGIN_VOXELS` of its voxels on every side.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError

__all__ = ["MARGIN_VOXELS", "visible_points", "visible_box", "fit_points_distance"]

#: each visible voxel is widened by this many of its voxels on every side (a structure thinner than
#: the level's voxels may be averaged away there)
MARGIN_VOXELS = 1


def visible_points(loader, tf, max_voxels: int = 1 << 18) -> np.ndarray | None:
    """World points ``(n, 3)`` (``(x, y, z)``) around every voxel to which ``tf`` gives opacity, over
    the pyramid's value range, or None when every voxel is transparent: the corners of each such
    voxel's cube widened by :data:`MARGIN_VOXELS`, for the voxels on the surface of the visible set
    (an inner voxel's corners lie inside the others'), clipped to the volume box.

    Read brick by brick from the finest level with at most ``max_voxels`` voxels (the coarsest if
    none is that small); a voxel is visible unless :meth:`TransferFunction.transparent_mask` says
    alpha is 0 at its value (NaN counts as visible, and so does every voxel of a brick that cannot
    be read: the frames drawn later name it).
    """
    from .overlay import read_level

    pyr = loader.pyramid
    if int(max_voxels) < 1:
        raise ParameterError(f"max_voxels: expected >= 1, got {max_voxels!r}")
    small = [L for L in range(pyr.num_levels) if int(np.prod(pyr.levels[L].shape)) <= int(max_voxels)]
    L = small[0] if small else pyr.num_levels - 1
    # an unreadable brick reads as NaN, which counts as visible (the frames drawn later name it)
    vol = read_level(loader, L, dtype=np.float64, failed=np.nan)
    seen = np.zeros(vol.shape, dtype=bool)
    for z in range(vol.shape[0]):  # a slab at a time: the ranges are (value, value) pairs
        v = vol[z].reshape(-1)
        seen[z] = ~tf.transparent_mask(np.stack([v, v], axis=1), pyr.value_range).reshape(vol.shape[1:])
    if not seen.any():
        return None
    inner = np.pad(seen, 1)  # a voxel whose six neighbours are all visible is not on the surface
    core = seen.copy()
    for ax in range(3):
        for d in (-1, 1):
            core &= np.roll(inner, d, axis=ax)[1:-1, 1:-1, 1:-1]
    idx = np.argwhere(seen & ~core).astype(np.float64)  # (n, 3) z, y, x
    lv = pyr.levels[L]
    scale = np.asarray(lv.scale, dtype=np.float64)
    trans = np.asarray(lv.translation, dtype=np.float64)
    w = 0.5 + MARGIN_VOXELS
    signs = np.array([[a, b, c] for a in (-w, w) for b in (-w, w) for c in (-w, w)])
    pts = (trans + (idx[:, None, :] + signs[None]) * scale).reshape(-1, 3)[:, ::-1]
    vlo, vhi = pyr.volume_box()
    return np.clip(pts, vlo, vhi)


def visible_box(loader, tf, max_voxels: int = 1 << 18) -> tuple[np.ndarray, np.ndarray] | None:
    """World box ``(lo, hi)`` (``(x, y, z)``) of :func:`visible_points`, or None when nothing is visible."""
    pts = visible_points(loader, tf, max_voxels)
    return None if pts is None else (pts.min(axis=0), pts.max(axis=0))


def fit_points_distance(points, center, cameras, margin: float = 1.05) -> float:
    """The smallest eye distance from ``center`` at which every one of ``points`` (world ``(n, 3)``)
    lies inside the view of each of ``cameras`` - perspective cameras looking at ``center``, whose
    direction, up and field of view are what counts, not their distance - with ``margin`` (1.05:
    the points fill at most 1 / 1.05 of the view's half extents); the largest over the cameras, so
    one distance holds along a whole path."""
    q = np.asarray(points, dtype=np.float64).reshape(-1, 3) - np.asarray(center, dtype=np.float64)
    best = 0.0
    for cam in cameras:
        w, h = (int(v) for v in cam.size)
        ty = np.tan(np.radians(float(cam.fov_y)) / 2.0)
        tx = ty * w / h
        x = q @ np.asarray(cam.right, dtype=np.float64)
        y = q @ np.asarray(cam.up, dtype=np.float64)
        z = q @ np.asarray(cam.forward, dtype=np.float64)  # depth beyond the centre
        need = np.maximum(margin * np.abs(x) / tx, margin * np.abs(y) / ty) - z
        best = max(best, float(need.max()) if len(need) else 0.0)
    if not best > 0:
        raise ParameterError(f"points: expected points around the centre with extent, got {len(q)} points")
    return best
