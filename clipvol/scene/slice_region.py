"""The region of interest of a cutting plane: per level, the bricks a multiresolution slice draws.

Why: the clip-texture reads what it is asked to page. Asked for cube windows it reads most of each
level for one slice; handed this region it reads the slab the slice crosses, fine only near the
point of interest (LaMar, Hamann & Joy, *Multiresolution cutting planes*). Pure numpy.

The rule mirrors the ``"plane"`` selection policy (:class:`~clipvol.scene.selection.policies.plane.PlaneCut`)
without a traversal:

* level ``L`` is in the region where its parent node (level ``L + 1``) would be refined: one voxel
  of ``L + 1`` covers more than ``lod_threshold`` pixels of ``pixel_size`` and, with a point of
  interest, the parent's box comes closer to it than ``distance_factor`` times the parent's
  diagonal; the coarsest level always is (the fallback under everything);
* with ``RenderParams.level`` fixed, that level and the coarsest one;
* with an image size, only the bricks under the image rectangle (a zoomed view of a large plane
  reads what it shows, as the traversal culls what the view does not);
* at each level only the bricks whose box meets the slab of half-thickness half a voxel of that
  level along the normal (:mod:`clipvol.paging.slab`): the trilinear footprint of the samples on
  the plane. The blended parents of a level's tiles are bricks of the next level's slab.

A tile at the edge of a level's part filters across its faces only into neighbours that are
paged (others are clamped, as at any face whose neighbour is missing); there the slice blends
towards the coarser level anyway, so the region does not pay for a ring of neighbours.

``ahead`` (world units along the normal) widens every slab towards where the plane is scrolling,
so the next slice's bricks are queued behind the current ones. Balancing may still want a few
bricks outside the region; the frame asks for them and the clip-texture reads them on demand.
"""

from __future__ import annotations

import math

import numpy as np

from ..paging.region import Region
from ..paging.slab import slab_bricks

__all__ = ["slice_region"]


def _half_voxel(pyramid, level: int, normal: np.ndarray) -> float:
    """Half a voxel of ``level`` measured along ``normal`` (anisotropic voxels: their extent along it)."""
    scale = np.asarray(pyramid.levels[level].scale[::-1], dtype=np.float64)  # (x, y, z)
    return 0.5 * float(np.abs(normal) @ scale)


def _in_view(pyramid, level: int, bricks: np.ndarray, plane, size, pixel_size: float) -> np.ndarray:
    """``(n,)`` bool: bricks whose boxes' extents along the plane's right and up axes meet the image
    rectangle (``size`` pixels of ``pixel_size`` centred on the plane's origin)."""
    if not len(bricks):
        return np.zeros(0, dtype=bool)
    lo, hi = pyramid.node_box(level, bricks)
    c, r = (lo + hi) * 0.5 - np.asarray(plane.origin, dtype=np.float64), (hi - lo) * 0.5
    ok = np.ones(len(bricks), dtype=bool)
    for axis, pixels in ((np.asarray(plane.right, dtype=np.float64), size[0]), (np.asarray(plane.up), size[1])):
        ok &= np.abs(c @ axis) <= 0.5 * pixels * pixel_size + r @ np.abs(axis)
    return ok


def slice_region(pyramid, plane, params, pixel_size: float, *, size=None, ahead: float = 0.0) -> Region:
    """The :class:`~clipvol.paging.region.Region` of ``plane`` drawn with ``params`` at ``pixel_size``;
    with ``size`` (``(w, h)`` pixels), only bricks under the image (a zoomed view of a huge plane)."""
    n = np.asarray(plane.normal, dtype=np.float64)
    top = pyramid.num_levels - 1
    focus = None if params.focus is None else np.asarray(params.focus, dtype=np.float64)
    origin = np.asarray(plane.origin, dtype=np.float64) + 0.5 * float(ahead) * n
    widen = 0.5 * abs(float(ahead))
    empty = np.zeros((0, 3), dtype=np.int64)
    bricks: list[np.ndarray] = [empty] * pyramid.num_levels

    def slab(level: int, point=None, radius: float = math.inf) -> np.ndarray:
        b = slab_bricks(pyramid, level, origin, n, _half_voxel(pyramid, level, n) + widen, point=point, radius=radius)
        return b if size is None else b[_in_view(pyramid, level, b, plane, size, pixel_size)]

    if params.level is not None:
        for L in {int(params.level), top}:
            bricks[L] = slab(L)
    else:
        bricks[top] = slab(top)
        for L in range(top - 1, -1, -1):
            voxel = max(pyramid.levels[L + 1].scale)  # the traversal's projected voxel of the parent level
            if not voxel / float(pixel_size) > params.lod_threshold:
                break  # the parents are not refined: neither this level nor any finer one is drawn
            if focus is None:
                bricks[L] = slab(L)
                continue
            # candidates near enough that their parent can be, then the policy's own test on the parent
            plo, phi = pyramid.node_box(L + 1, np.zeros((1, 3), dtype=np.int64))
            pdiag = float(np.linalg.norm(phi - plo))  # the largest parent diagonal (an interior node)
            cand = slab(L, focus, (params.distance_factor + 1.0) * pdiag)
            if not len(cand):
                break
            lo, hi = pyramid.node_box(L + 1, cand // 2)
            near = np.linalg.norm(np.clip(focus, lo, hi) - focus, axis=1)
            keep = near < params.distance_factor * np.linalg.norm(hi - lo, axis=1)
            if not keep.any():
                break
            bricks[L] = cand[keep]
    center = focus if focus is not None else np.asarray(plane.origin, dtype=np.float64)
    # the samples lie on this plane: bricks beyond half a voxel of it are never read by them
    halves = tuple(_half_voxel(pyramid, L, n) for L in range(pyramid.num_levels))
    return Region(tuple(center.tolist()), tuple(bricks), slab=(tuple(plane.origin), tuple(n.tolist()), halves))
