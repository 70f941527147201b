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

:func:`march_occlusion` computes the layers on the CPU: it ray-casts a coarse level (a few
hundred thousand voxels) into the small image with samples on planes of constant depth, so the
opacity in front of *every* depth plane comes out of one pass (one cumulative product per ray) and
the layers can be as fine as the samples - where the GL estimate needs one render per layer.

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
from .visible_edges import EDGE_ALPHA, edge_map

__all__ = ["OcclusionLayers", "summed_area_table", "rect_mean", "screen_rects", "box_depths", "march_occlusion", "trilinear",
           "view_close"]


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
    """Accumulated opacity in front of ``depths`` (``(K,)`` ascending, ``depths[0] = 0`` - orthographic: the
    volume's signed near depth - with an empty
    map) as ``alpha`` ``(K, h, w)`` in ``[0, 1]`` (row 0 at the top) for ``camera`` (its pixel size
    may differ from the maps': rectangles are scaled)."""

    camera: Camera
    depths: np.ndarray
    alpha: np.ndarray
    key: object = None  # what the estimate depends on besides the view (e.g. the transfer function)
    _sat: np.ndarray | None = field(default=None, repr=False)
    _edge_sat: np.ndarray | None = field(default=None, repr=False)
    _edges_sat: tuple | None = field(default=None, repr=False)

    def visibility(self, lo, hi, camera: Camera | None = None) -> np.ndarray:
        """``(n,)`` estimated visibility ``1 - mean alpha in front`` of boxes ``lo``/``hi`` ``(n, 3)``."""
        cam = camera or self.camera
        if self._sat is None:
            self._sat = summed_area_table(np.clip(self.alpha, 0.0, 1.0))
        x0, y0, x1, y1, behind = self._map_rects(cam, lo, hi)
        near, _ = box_depths(cam, lo, hi)
        k = np.clip(np.searchsorted(self.depths, near, side="right") - 1, 0, len(self.depths) - 1)
        k[behind] = 0
        s = self._sat
        tot = s[k, y1, x1] - s[k, y0, x1] - s[k, y1, x0] + s[k, y0, x0]
        mean = tot / ((x1 - x0) * (y1 - y0))
        return np.clip(1.0 - mean, 0.0, 1.0)

    def silhouette(self, lo, hi, camera: Camera | None = None) -> np.ndarray:
        """``(n,)`` fraction of each box's screen rectangle on the silhouette: map pixels where the
        total accumulated opacity (the last layer) crosses 0.5 against a 4-neighbour. A coarse level
        shifts the blurred edge there by about a pixel, which the box's mean colour and opacity
        (diluted by the air it also holds) do not show (see :mod:`clipvol.scene.selection.policies.image_based`)."""
        cam = camera or self.camera
        if self._edge_sat is None:
            a = np.asarray(self.alpha[-1]) >= 0.5
            e = np.zeros_like(a)
            dx, dy = a[:, 1:] != a[:, :-1], a[1:] != a[:-1]
            e[:, 1:] |= dx
            e[:, :-1] |= dx
            e[1:] |= dy
            e[:-1] |= dy
            self._edge_sat = summed_area_table(e.astype(np.float64))
        x0, y0, x1, y1, _ = self._map_rects(cam, lo, hi)
        s = self._edge_sat
        return (s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0]) / ((x1 - x0) * (y1 - y0))

    def footprint(self, lo, hi, camera: Camera | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(shown, edges)``, each ``(n,)``: the share of each box's map rectangle that shows something
        (total opacity above :data:`~clipvol.scene.visible_edges.EDGE_ALPHA`), and the share of those
        pixels on an edge of the total opacity (:func:`clipvol.scene.visible_edges.edge_map`; 0 where
        nothing is shown) - how much of the image a box's pixels are, and how many edges lie in front
        of them, where a coarse level's error sits (:func:`~clipvol.scene.visible_edges.edge_difference`)."""
        cam = camera or self.camera
        if self._edges_sat is None:
            a = np.asarray(self.alpha[-1])
            self._edges_sat = (summed_area_table((a > EDGE_ALPHA).astype(np.float64)),
                               summed_area_table(edge_map(a).astype(np.float64)))
        x0, y0, x1, y1, _ = self._map_rects(cam, lo, hi)
        n, e = ((s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0]) for s in self._edges_sat)
        return n / ((x1 - x0) * (y1 - y0)), np.where(n > 0.5, e / np.maximum(n, 1.0), 0.0)

    def _map_rects(self, cam: Camera, lo, hi):
        """Boxes' screen rectangles in map pixels ``x0, y0, x1, y1`` (non-empty) and ``behind``."""
        rect, behind = screen_rects(cam, lo, hi)
        _, h, w = self.alpha.shape
        W, H = cam.size
        sx, sy = w / W, h / H
        x0 = np.clip(np.floor(rect[:, 0] * sx), 0, w - 1).astype(np.int64)
        y0 = np.clip(np.floor(rect[:, 1] * sy), 0, h - 1).astype(np.int64)
        x1 = np.clip(np.ceil(rect[:, 2] * sx), x0 + 1, w).astype(np.int64)
        y1 = np.clip(np.ceil(rect[:, 3] * sy), y0 + 1, h).astype(np.int64)
        return x0, y0, x1, y1, behind

    def reusable(self, camera: Camera, key=None, max_angle: float = 3.0, max_move: float = 0.02,
                 scale: float = 1.0, centre=None) -> bool:
        """Whether this estimate still serves ``camera``: the same ``key``, the same projection and
        image size, a view direction within ``max_angle`` degrees, and an eye moved less than
        ``max_move * scale`` (``scale``: e.g. the volume's diagonal) - or, with ``centre`` (e.g. the
        volume's), an eye whose direction from ``centre`` turned less than ``max_angle`` and whose
        distance to it changed by less than the fraction ``max_move`` (see :func:`view_close`)."""
        return key == self.key and view_close(self.camera, camera, max_angle, max_move * scale, centre, max_move)


def view_close(a: Camera, b: Camera, max_angle: float, max_move: float, centre=None, zoom: float = 0.02) -> bool:
    """Whether view ``b`` is close to view ``a``: the same projection and image size, a view direction
    within ``max_angle`` degrees, and an eye moved by at most ``max_move`` (world units).

    With ``centre``, an eye that moved further still counts as close when, seen from ``centre``, it
    turned by at most ``max_angle`` degrees and its distance changed by at most the fraction
    ``zoom``: an orbit about the volume is judged by its angle (as Wang, Garcia & Shen judge the
    view direction), so the test scales with the zoom instead of with the volume's size.
    """
    if a.orthographic != b.orthographic or tuple(a.size) != tuple(b.size):
        return False
    if (a.fov_y, a.width, a.height) != (b.fov_y, b.width, b.height):
        return False
    if _degrees(a.forward, b.forward) > max_angle:
        return False
    if float(np.linalg.norm(np.subtract(a.eye, b.eye))) <= max_move:
        return True
    if centre is None:
        return False
    ra, rb = np.subtract(a.eye, centre), np.subtract(b.eye, centre)
    na, nb = float(np.linalg.norm(ra)), float(np.linalg.norm(rb))
    if na <= 0 or nb <= 0 or abs(nb - na) > zoom * na:
        return False
    return _degrees(ra / na, rb / nb) <= max_angle


def _degrees(u, v) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(u, v), -1.0, 1.0))))


def trilinear(volume: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(m,)`` float32: ``volume`` (``(z, y, x)``) interpolated trilinearly at ``points`` (``(m, 3)``
    voxel coordinates ``(z, y, x)``, already clamped to ``[0, shape - 1]``). numpy only, so the core
    needs no scipy (the tests check it against ``scipy.ndimage.map_coordinates(order=1)``)."""
    vol = np.ascontiguousarray(volume, dtype=np.float32)
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    top = np.asarray(vol.shape, dtype=np.int64) - 1
    i0 = np.minimum(np.floor(p).astype(np.int64), np.maximum(top - 1, 0))  # i0 + 1 stays inside
    f = p - i0.astype(np.float32)
    fz, fy, fx = f.T
    # the eight corners as one flat gather each from the voxel base (a step of 0 on an axis of one
    # voxel): faster than indexing with three index arrays per corner
    nz, ny, nx = vol.shape
    sz, sy, sx = (ny * nx if nz > 1 else 0), (nx if ny > 1 else 0), (1 if nx > 1 else 0)
    base = (i0[:, 0] * ny + i0[:, 1]) * nx + i0[:, 2]
    flat = vol.ravel()

    def at(offset: int) -> np.ndarray:
        return flat.take(base + offset)

    c00 = at(0) * (1 - fx) + at(sx) * fx
    c01 = at(sy) * (1 - fx) + at(sy + sx) * fx
    c10 = at(sz) * (1 - fx) + at(sz + sx) * fx
    c11 = at(sz + sy) * (1 - fx) + at(sz + sy + sx) * fx
    return (c00 * (1 - fy) + c01 * fy) * (1 - fz) + (c10 * (1 - fy) + c11 * fy) * fz


def march_occlusion(volume: np.ndarray, scale_zyx, translation_zyx, camera: Camera, alpha_of, depths,
                    ref_length: float, step: float = 1.0, shape=None) -> np.ndarray:
    """``(K, h, w)`` opacity accumulated in front of each of ``depths`` (ascending, along the view
    axis) per pixel of ``camera``, by front-to-back ray casting of ``volume`` on the CPU.

    Parameters
    ----------
    volume : ndarray
        ``(z, y, x)`` voxels of one level; voxel ``i`` has its centre at ``translation + i * scale``.
    scale_zyx, translation_zyx : sequence of float
        The level's voxel-to-world transform (``(z, y, x)``).
    camera : Camera
        The (small) view; row 0 of the maps is the top of its image.
    alpha_of : callable
        ``alpha_of(values) -> opacity`` per reference length (the transfer function's alpha).
    depths : array-like
        ``(K,)`` depths along :attr:`Camera.forward` from the eye.
    ref_length : float
        The length the transfer function's opacity is defined for (the level-0 voxel).
    step : float
        Sample spacing in voxels of ``volume`` (depth planes ``step * min(scale)`` apart).
    shape : Shape, optional
        Samples outside it are empty.

    Samples lie on planes of constant depth ``d_j`` (``j + 1/2`` steps past the volume's nearest
    depth), trilinearly interpolated (edges clamped, outside the volume empty), with opacity corrected
    for the ray's length between two planes (``1 - (1 - a) ** (length / ref_length)``). Layer ``k``
    holds ``1 - prod (1 - a_j)`` over the samples with ``d_j < depths[k]``.
    """
    vol = np.asarray(volume, dtype=np.float32)
    sc = np.asarray(scale_zyx, dtype=np.float64)[::-1]  # (x, y, z)
    tr = np.asarray(translation_zyx, dtype=np.float64)[::-1]
    n_xyz = np.asarray(vol.shape[::-1], dtype=np.float64)
    depths = np.asarray(depths, dtype=np.float64)
    w, h = camera.size
    out = np.zeros((len(depths), h, w))
    lo, hi = tr - 0.5 * sc, tr + (n_xyz - 0.5) * sc
    near, far = box_depths(camera, lo[None], hi[None])
    d0 = float(near[0]) if camera.orthographic else max(float(near[0]), 0.0)  # (orthographic depths are signed)
    d1 = float(far[0])
    dd = float(step) * float(sc.min())
    if d1 <= d0 or dd <= 0:
        return out
    n = int(math.ceil((d1 - d0) / dd))
    dj = d0 + (np.arange(n) + 0.5) * dd  # (n,)
    origins, dirs = camera.rays()
    f = np.asarray(camera.forward, dtype=np.float64)
    eye = np.asarray(camera.eye, dtype=np.float64)
    cos = np.maximum(dirs @ f, 1e-6)  # (h, w)
    o_depth = (origins - eye) @ f
    # voxel coordinates (z, y, x) of each ray's sample on each plane: start + t * slope, in float32
    start = ((origins - o_depth[..., None] / cos[..., None] * dirs - tr) / sc)[..., ::-1].astype(np.float32)
    slope = (dirs / cos[..., None] / sc)[..., ::-1].astype(np.float32)
    coords = start[None] + dj.astype(np.float32)[:, None, None, None] * slope[None]  # (n, h, w, 3)
    n_zyx = np.asarray(vol.shape, dtype=np.float32)
    inside = np.all((coords >= -0.5) & (coords <= n_zyx - 0.5), axis=-1)
    if shape is not None and not shape.is_everything:
        world = coords[..., ::-1].astype(np.float64) * sc + tr
        inside &= shape.contains(world.reshape(-1, 3)).reshape(inside.shape)
    np.clip(coords, 0.0, n_zyx - 1.0, out=coords)
    a = np.zeros(inside.shape, dtype=np.float32)
    vals = trilinear(vol, coords[inside])  # only samples inside
    a[inside] = alpha_of(vals)
    # opacity for the ray's length between two planes: 1 - (1 - a) ** ratio
    ratio = (dd / cos / float(ref_length)).astype(np.float32)
    a = -np.expm1(ratio[None] * np.log1p(-np.minimum(a, np.float32(1.0 - 1e-7))))
    trans = np.cumprod(1.0 - a, axis=0)  # transmittance after each sample
    for k, d in enumerate(depths):
        m = int(np.searchsorted(dj, d, side="left"))  # samples with d_j < d
        if m > 0:
            out[k] = 1.0 - trans[m - 1]
    return out
