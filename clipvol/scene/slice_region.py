"""The region of interest of a cutting plane: per level, the bricks a multiresolution slice draws.

Why: the clip-texture reads what it is asked to page. Asked for cube windows it reads most of each
level for one slice; handed this region it reads the slab the slice crosses, fine only near the
point of interest (LaMar, Hamann & Joy, *Multiresolution cutting planes*). Pure numpy.

The region is what the slice action's cut draws, without a traversal:

* with a point of interest (``RenderParams.focus``) and no fixed level, the per-brick cover of
  :mod:`clipvol.scene.slice_cover` - each part of the plane at the finest level whose brick is
  within ``distance_factor`` of its parent's diagonals of the point, or coarser where the store's
  summary tables show the coarser data looks the same (``stand_in``) - and the parents its blending
  tiles blend towards, over the coarsest level's slab (the fallback under everything);
* without a point of interest, one level: the finest whose parent level's voxel covers more than
  ``lod_threshold`` pixels of ``pixel_size`` (the plane policy's cut), and the coarsest;
* with ``RenderParams.level`` fixed, that level and the coarsest one;
* with an image size, only the bricks under the image rectangle (a zoomed view of a large plane
  reads what it shows, as the traversal culls what the view does not);
* at each level only the bricks whose box meets the slab of half-thickness half a voxel of that
  level along the normal (:mod:`clipvol.paging.slab`): the trilinear footprint of the samples on
  the plane.

A tile at the edge of a level's part filters across its faces only into neighbours that are
paged (others are clamped, as at any face whose neighbour is missing), so the region does not pay
for a ring of neighbours.

**Bytes, not bricks.** On a store whose manifest records each chunk's size
(:meth:`~clipvol.bricking.manifest.Manifest.sizes`), :func:`stored_sizes` and :func:`region_bytes`
price a region in the bytes its chunks hold on disk: a brick that only holds the fill value costs
nothing (it is never read), and a coarse brick that holds tissue where the level-0 bricks it
covers hold background costs more than they do. Without a manifest a region is priced by its
bricks (a brick's bytes each): where the full-resolution slab is small (a 197 x 233 x 189 volume
in 32³ bricks), the parents the cover's tiles blend towards can outnumber the level-0 bricks it
saves.
The slice action draws the full-resolution slice where its region holds no more bytes than the
multiresolution one: the better image for no more bytes read
(:class:`~clipvol.render.slice_action.SliceAction`).

``ahead`` (world units along the normal) widens every slab towards where the plane is scrolling,
so the next slice's bricks are queued behind the current ones.
"""

from __future__ import annotations

import math

import numpy as np

from ..paging.region import Region
from ..paging.slab import slab_bricks
from .slice_cover import finest_level, half_voxel, in_view_mask, slice_cover

__all__ = ["slice_region", "stored_sizes", "region_bytes", "in_view_mask"]


def slice_region(pyramid, plane, params, pixel_size: float, *, size=None, ahead: float = 0.0,
                 stand_in=None) -> Region:
    """The :class:`~clipvol.paging.region.Region` of ``plane`` drawn with ``params`` at ``pixel_size``;
    with ``size`` (``(w, h)`` pixels), only bricks under the image (a zoomed view of a huge plane);
    ``stand_in``: the cover's bricks that may stand for their children
    (:func:`~clipvol.scene.slice_cover.slice_cover`)."""
    n = np.asarray(plane.normal, dtype=np.float64)
    top = pyramid.num_levels - 1
    focus = None if params.focus is None else np.asarray(params.focus, dtype=np.float64)
    origin = np.asarray(plane.origin, dtype=np.float64) + 0.5 * float(ahead) * n
    widen = 0.5 * abs(float(ahead))
    empty = np.zeros((0, 3), dtype=np.int64)
    bricks: list[np.ndarray] = [empty] * pyramid.num_levels

    def slab(level: int, point=None, radius: float = math.inf) -> np.ndarray:
        b = slab_bricks(pyramid, level, origin, n, half_voxel(pyramid, level, n) + widen, point=point, radius=radius)
        return b if size is None else b[in_view_mask(pyramid, level, b, plane, size, pixel_size)]

    if params.level is not None:
        for L in {int(params.level), top}:
            bricks[L] = slab(L)
    elif focus is not None:  # the per-brick cover (clipvol.scene.slice_cover) and its blend parents
        view = None if size is None else (lambda L, b: in_view_mask(pyramid, L, b, plane, size, pixel_size))
        got = slice_cover(pyramid, plane, params, pixel_size, in_view=view, ahead=ahead, stand_in=stand_in).bricks()
        bricks = list(got)
        if not len(bricks[top]):
            bricks[top] = slab(top)
        else:  # the coarsest level's slab under everything: the fallback while finer bricks load
            bricks[top] = np.unique(np.concatenate([bricks[top], slab(top)]), axis=0)
    else:  # one level everywhere: the finest the pixels need (the plane policy's cut), over the coarsest
        bricks[top] = slab(top)
        finest = finest_level(pyramid, params, pixel_size)
        bricks[finest] = slab(finest)
    center = focus if focus is not None else np.asarray(plane.origin, dtype=np.float64)
    # the samples lie on this plane: bricks beyond half a voxel of it are never read by them
    halves = tuple(half_voxel(pyramid, L, n) for L in range(pyramid.num_levels))
    return Region(tuple(center.tolist()), tuple(bricks), slab=(tuple(plane.origin), tuple(n.tolist()), halves))


class _PerBrick:
    """The bytes of one level's bricks as a source without a manifest hands them over: a whole
    brick each (a loader returns the brick shape, an edge brick padded), indexed like a
    ``(gz, gy, gx)`` array with three index arrays without holding one (a huge store's grid)."""

    def __init__(self, nbytes: int) -> None:
        self.nbytes = int(nbytes)

    def __getitem__(self, index) -> np.ndarray:
        return np.full(np.shape(index[0]), self.nbytes, dtype=np.int64)


def stored_sizes(loader) -> tuple:
    """Per level, ``(gz, gy, gx)`` int64 bytes a read of each brick takes from storage: the chunk's
    size from the store's verified manifest, 0 for a chunk not stored or holding only the fill value
    (the clip-texture fills those without a read). Without a manifest (a procedural or in-memory
    source, an unverified store) every brick costs a brick's bytes: a region is then priced by its
    bricks, and a multiresolution slice whose coarse bricks outnumber the level-0 bricks they
    replace is drawn at full resolution all the same."""
    manifest = getattr(loader, "manifest", None)
    sizes = getattr(manifest, "sizes", None)
    pyr = loader.pyramid
    if sizes is None:
        return tuple(_PerBrick(pyr.brick_nbytes) for _ in range(pyr.num_levels))
    fill = pyr.fill_value
    out = []
    for L in range(pyr.num_levels):
        t = manifest.tables[L]
        out.append(np.where((t["min"] == fill) & (t["max"] == fill), 0, np.asarray(sizes(L), dtype=np.int64)))
    return tuple(out)


def region_bytes(region: Region, sizes) -> int:
    """Bytes the bricks of ``region`` hold in storage, by :func:`stored_sizes`'s ``sizes``."""
    total = 0
    for L, b in enumerate(region.bricks):
        if b is not None and len(b):
            total += int(sizes[L][b[:, 0], b[:, 1], b[:, 2]].sum())
    return total
