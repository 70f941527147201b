"""The cover of a multiresolution slice: per brick, the finest level in reach of the point of interest.

Why: a cutting plane is a 2D picture, so it needs neither whole-node refinement nor the 2:1
balance a volume cut keeps (LaMar, Hamann & Joy, *Multiresolution cutting planes*). Refining whole
octree nodes around the point of interest reads every sibling of a refined brick in the plane's
slab, and balancing adds rings at every level: on a 1024³ store of 64³ bricks the slice through
the centre read 249 chunks at ``distance_factor`` 1.0, 97 at 0.5 and 97 at 0.25 against 513 for
the full-resolution slice (225, 97 and 33 with this cover).
Here each brick decides for itself, and each pixel reads the finest level in reach for it. Pure
numpy, no traversal.

The rule
--------
With a point of interest ``p`` (``RenderParams.focus``) and no fixed ``level``:

* a brick ``b`` of level ``L`` is **in reach** when its box comes closer to ``p`` than
  ``distance_factor`` times its parent's diagonal (twice its own inside the volume; the nearest
  point of the box, so the bricks holding ``p`` are always in reach: the point is at full
  resolution for any factor), and ``L`` is not finer than the pixels need (the level below the
  first whose parent level's voxel covers no more than ``lod_threshold`` pixels is never drawn, as
  for the plane policy); every brick of the coarsest level is in reach. A brick in reach has its
  parent in reach (the parent's box holds it and the grandparent's diagonal is no shorter than the
  parent's), so the bricks in reach form a tree;
* with **stand-ins** (``stand_in``: per level the bricks whose data looks the same as the level-0
  data beneath them under the slice's colours, from the store's summary tables,
  :mod:`clipvol.scene.slice_exact`), a brick in reach whose parent may stand for it leaves reach:
  the parent draws there. Stand-ins are closed under descent, so the bricks left in reach still
  form a tree, and the cover is nowhere finer than by distance alone;
* only bricks in the plane's **slab** count: at level ``L`` those within half a voxel of ``L``
  of the plane (:mod:`clipvol.paging.slab`), the trilinear footprint of samples on it; with an
  image size, only those under the image rectangle;
* the **cover**: an in-reach brick none of whose children (in the slab) is in reach is drawn
  whole at its level; an in-reach brick with children in reach is drawn only over its children
  that are not, each of those child boxes drawn from the parent's data. Every point of the plane
  lies in exactly one drawn box (children tile their parent), and its level is the finest one in
  reach there. Neighbouring boxes may be several levels apart (no balancing).

**Blending.** A tile drawn whole next to a coarser box blends towards its parent's data (the
paper's high and low tiles): per corner a ratio, 1 where a box drawn from coarser data touches the
corner and no box showing the tile's own level there does (a finer box, which blends up to this
level at its faces, or a child box drawn from this level's data, which does not blend), else 0,
interpolated across the tile (a coarser box drawn from a stand-in shows the tile's picture and does
not count as coarser). The parent brick is read too - only the parents of such tiles, not
their sibling groups. Where a tile meets a box one level coarser over a whole face, the image is
continuous across the level change. Without balancing it steps in three places: where a box meets
one two or more levels coarser (the tile reaches its parent's level, not the neighbour's: a jump
of ``k`` levels shows ``k - 1`` levels' difference), where a child box drawn from its parent's data
meets a coarser box (it does not blend), and near a corner kept at the tile's own level because a
finer box touches it too. No step is larger than the difference between the levels on its sides.

**The factor.** The reach at a given ``distance_factor`` is the plane policy's, which refines a
node - draws its children - when the node's box comes within the factor times the node's
diagonal, and the same unit as a volume's point of interest (the distance policy refines a node
within the factor times the node's diagonal, measured from the node's centre): a user's setting
keeps its meaning. Measured per brick rather than per node, a brick in reach is a child of a node
the plane policy refines at the same factor, so the cover is never finer than that cut anywhere
and reads fewer bricks (no siblings beyond reach, no balancing rings).

:class:`CoverCut` hands the cover to the shared traversal as a cut (so residency, coarser
fallback while bricks load, windows and merging stay those of every other cut), and
:func:`clipvol.scene.slice_region.slice_region` pages exactly the cover's bricks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..paging.slab import slab_bricks, slab_mask
from ..rows import rows_in
from .selection.policies.base import RefinePolicy
from .selection.policies.plane import PlaneCut

__all__ = ["SliceCover", "slice_cover", "CoverCut", "slice_cut", "in_reach", "finest_level", "half_voxel",
           "in_view_mask", "plane_crosses"]

#: offsets (z, y, x) of a brick's 8 children
_CHILD = np.array([(z, y, x) for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=np.int64)


@dataclass(frozen=True, eq=False, slots=True)
class SliceCover:
    """A slice's cover: which data draws which box.

    Attributes
    ----------
    records : tuple
        ``(data_level, data_index (n, 3), box_level, box_index (n, 3))`` per group of boxes: the
        node boxes of ``box_level`` drawn from bricks of ``data_level`` (``data_level ==
        box_level``: a brick drawn whole; ``data_level == box_level + 1``: a child box drawn from
        its parent's data). Indices are ``(z, y, x)``.
    ratios : dict
        ``{(level, (bz, by, bx)): (2, 2, 2) corner ratios}`` of the whole-brick tiles that blend
        towards their parent (index ``[cz, cy, cx]``, 1: the parent's value at that corner).
    num_levels : int
    """

    records: tuple
    ratios: dict
    num_levels: int

    def drawn(self) -> tuple[np.ndarray, ...]:
        """Per level, the distinct bricks whose data is drawn ``(n, 3)``."""
        out = []
        for L in range(self.num_levels):
            parts = [d for dl, d, _, _ in self.records if dl == L and len(d)]
            out.append(np.unique(np.concatenate(parts), axis=0) if parts else np.zeros((0, 3), dtype=np.int64))
        return tuple(out)

    def bricks(self) -> tuple[np.ndarray, ...]:
        """Per level, the bricks the slice reads: the drawn ones and the parents blended towards."""
        drawn = list(self.drawn())
        for L in range(self.num_levels):
            par = [(k[1][0] // 2, k[1][1] // 2, k[1][2] // 2) for k in self.ratios if k[0] == L - 1]
            if par:
                both = np.concatenate([drawn[L], np.array(par, dtype=np.int64).reshape(-1, 3)])
                drawn[L] = np.unique(both, axis=0)
        return tuple(drawn)


def half_voxel(pyramid, level: int, normal: np.ndarray) -> float:
    """Half a voxel of ``level`` measured along ``normal`` (anisotropic voxels: their extent along it)."""
    scale = np.asarray(pyramid.levels[level].scale[::-1], dtype=np.float64)  # (x, y, z)
    return 0.5 * float(np.abs(normal) @ scale)


def in_view_mask(pyramid, level: int, bricks: np.ndarray, plane, size, pixel_size: float) -> np.ndarray:
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


def in_reach(pyramid, level: int, bricks: np.ndarray, focus: np.ndarray, distance_factor: float) -> np.ndarray:
    """``(n,)`` bool: bricks of ``level`` whose boxes come closer to ``focus`` than ``distance_factor``
    times their parents' diagonals (every brick of the coarsest level).

    The parent's diagonal, not the brick's own: the plane policy and the volume's distance policy
    refine a node - draw its children - within the factor times the node's diagonal, and a user's
    ``distance_factor`` keeps that reach. A brick in reach has a parent those policies refine at the
    same factor (its parent's box holds its own, so it is at least as near), so the cover never draws
    a brick they would not. The parent's box is clipped to the volume like any node box.
    """
    bricks = np.asarray(bricks, dtype=np.int64).reshape(-1, 3)
    if level >= pyramid.num_levels - 1:
        return np.ones(len(bricks), dtype=bool)
    if not len(bricks):
        return np.zeros(0, dtype=bool)
    lo, hi = pyramid.node_box(level, bricks)
    plo, phi = pyramid.node_box(level + 1, bricks // 2)
    lo, hi, plo, phi = (np.atleast_2d(a) for a in (lo, hi, plo, phi))
    near = np.linalg.norm(np.clip(focus, lo, hi) - focus, axis=1)
    return near < float(distance_factor) * np.linalg.norm(phi - plo, axis=1)


def finest_level(pyramid, params, pixel_size: float) -> int:
    """The finest level a slice at ``pixel_size`` draws: below it the parent level's voxel covers
    no more than ``lod_threshold`` pixels (the plane policy's projected-size test)."""
    L = pyramid.num_levels - 1
    while L > 0 and max(pyramid.levels[L].scale) / float(pixel_size) > params.lod_threshold:
        L -= 1
    return L


def slice_cover(pyramid, plane, params, pixel_size: float, *, in_view=None, ahead: float = 0.0,
                stand_in=None) -> SliceCover:
    """The :class:`SliceCover` of ``plane`` drawn with ``params`` (the rule in the module docstring).

    Parameters
    ----------
    pyramid : Pyramid
    plane : Plane
    params : RenderParams
        ``focus`` (required), ``distance_factor``, ``lod_threshold``; ``level`` must be None.
    pixel_size : float
        World units per pixel.
    in_view : callable, optional
        ``in_view(level, bricks) -> (n,) bool``: the bricks under the image (all when None).
    ahead : float
        World units along the normal the slab is widened by towards where the plane scrolls
        (:func:`clipvol.scene.slice_region.slice_region`).
    stand_in : sequence of ndarray, optional
        Per level, grid-shaped bool: the bricks whose data may stand for their children's under the
        slice's colours (:func:`clipvol.scene.slice_exact.stand_ins`). A brick in reach whose parent
        may stand for it is left out of reach: the parent draws there. None: distance alone.
    """
    if params.focus is None or params.level is not None:
        raise ParameterError("slice_cover: expected a point of interest (focus) and no fixed level, got "
                             f"focus={params.focus!r}, level={params.level!r}")
    n = np.asarray(plane.normal, dtype=np.float64)
    origin = np.asarray(plane.origin, dtype=np.float64) + 0.5 * float(ahead) * n
    widen = 0.5 * abs(float(ahead))
    focus = np.asarray(params.focus, dtype=np.float64)
    df = float(params.distance_factor)
    top = pyramid.num_levels - 1
    finest = finest_level(pyramid, params, pixel_size)
    empty = np.zeros((0, 3), dtype=np.int64)

    def half(L: int) -> float:
        return half_voxel(pyramid, L, n) + widen

    def keep_view(L: int, b: np.ndarray) -> np.ndarray:
        return b if in_view is None or not len(b) else b[np.asarray(in_view(L, b), dtype=bool)]

    # the bricks in reach per level (the coarsest: all of its slab)
    reach: list = [empty] * (top + 1)
    reach[top] = keep_view(top, slab_bricks(pyramid, top, origin, n, half(top)))
    for L in range(finest, top):
        lo0, hi0 = pyramid.node_box(L + 1, np.zeros((1, 3), dtype=np.int64))
        radius = df * float(np.linalg.norm(np.atleast_2d(hi0 - lo0), axis=1)[0])  # the longest parent diagonal
        cand = slab_bricks(pyramid, L, origin, n, half(L), point=focus, radius=radius)
        cand = cand[in_reach(pyramid, L, cand, focus, df)]
        if stand_in is not None and len(cand):  # where the parent looks the same, the parent draws
            par = cand // 2
            cand = cand[~np.asarray(stand_in[L + 1])[par[:, 0], par[:, 1], par[:, 2]]]
        reach[L] = keep_view(L, cand)

    records: list = []
    nodes = reach[top]
    for L in range(top, finest, -1):
        if not len(nodes):
            break
        # the children of this level's nodes in the finer slab
        kids = (2 * nodes[:, None, :] + _CHILD[None]).reshape(-1, 3)
        parent = np.repeat(np.arange(len(nodes)), 8)
        ok = np.all(kids < np.asarray(pyramid.grid(L - 1)), axis=1)
        kids, parent = kids[ok], parent[ok]
        ok = slab_mask(pyramid, L - 1, kids, origin, n, half(L - 1))
        if in_view is not None and ok.any():
            ok[ok] = np.asarray(in_view(L - 1, kids[ok]), dtype=bool)
        kids, parent = kids[ok], parent[ok]
        near = rows_in(kids, reach[L - 1])
        refined = np.zeros(len(nodes), dtype=bool)
        refined[parent[near]] = True
        records.append((L, nodes[~refined], L, nodes[~refined]))
        coarse = ~near & refined[parent]  # children of refined nodes left uncovered by finer bricks
        records.append((L, nodes[parent[coarse]], L - 1, kids[coarse]))
        nodes = kids[near]
    else:
        if len(nodes):
            records.append((finest, nodes, finest, nodes))
    records = [r for r in records if len(r[1])]
    drawn = [plane_crosses(pyramid, bl, bidx, plane) for _, _, bl, bidx in records]
    return SliceCover(tuple(records), _blend_ratios(records, top, stand_in, drawn), pyramid.num_levels)


def plane_crosses(pyramid, level: int, bricks: np.ndarray, plane) -> np.ndarray:
    """``(n,)`` bool: the node boxes of ``bricks`` (level ``level``) that draw part of ``plane`` - those
    :meth:`Plane.box_polygons <clipvol.scene.plane.Plane.box_polygons>` gives a polygon, as the draw
    does (on a box face the box on the plane's negative side draws it) - and not a box the slab holds
    for the half voxel of its samples' footprint without the plane passing through it."""
    if not len(bricks):
        return np.zeros(0, dtype=bool)
    lo, hi = pyramid.node_box(level, bricks)
    return plane.box_polygons(lo, hi)[1] >= 3


def _touching(corners: np.ndarray, level: int, box_level: int, boxes: np.ndarray) -> np.ndarray:
    """``(m,)`` bool: which corner points (grid coordinates of ``level``, ``(m, 3)``) lie in one of the
    closed node boxes ``boxes`` of ``box_level``."""
    if not len(boxes) or not len(corners):
        return np.zeros(len(corners), dtype=bool)
    k = box_level - level
    # the boxes whose closed extent holds a point: the one it starts and, on a face, the one before
    cand = (corners[:, None, :] << -k if k < 0 else corners[:, None, :]) - _CHILD[None]
    if k > 0:
        cand = cand >> k
    return rows_in(cand.reshape(-1, 3), boxes).reshape(len(corners), 8).any(axis=1)


def _blend_ratios(records: list, top: int, stand_in=None, drawn=None) -> dict:
    """Corner ratios of the whole-brick tiles next to coarser boxes (module docstring).

    Only boxes that draw part of the plane take part (``drawn``: per record, the
    :func:`plane_crosses` mask of its boxes, computed once; all when None): the slab holds, for the
    trilinear footprint, boxes half a voxel of their level off the plane, and such a box - a coarse
    one under a plane on its level's brick face, say - draws nothing, yet it touches the corners of
    the tiles beside it: counted, it blended every tile of the plane towards its parent.

    A coarser box drawn from data that may stand for the level-0 data beneath it (``stand_in``,
    :func:`slice_cover`) shows the picture the finer levels would: no level change to hide, and
    blending a tile towards its parent there would draw the parent's difference across the tile.
    Such boxes do not make a corner coarse.

    A corner is 1 where a box drawn from coarser data touches it and no box that shows this
    tile's level there does: a finer box (which blends up to this level at its faces) or a
    box drawn from this level's data over a child box (which does not blend). Where both
    touch a corner, the corner keeps the tile's own level: the tiles stay continuous with the
    finer side and the step of one level is left at the coarser face.
    """
    boxes = records if drawn is None else [(dl, d[m], bl, b[m]) for (dl, d, bl, b), m in zip(records, drawn)]
    out: dict = {}
    for L in range(top):
        tiles = [d for dl, d, bl, _ in records if dl == L and bl == L]
        if not tiles:
            continue
        tiles = np.concatenate(tiles)
        corners = (tiles[:, None, :] + _CHILD[None]).reshape(-1, 3)  # [cz, cy, cx] order of _CHILD
        coarse = np.zeros(len(corners), dtype=bool)
        pinned = np.zeros(len(corners), dtype=bool)
        for dl, didx, bl, bidx in boxes:
            if dl > L:
                if stand_in is not None:  # only boxes whose data differs from level 0's
                    bidx = bidx[~np.asarray(stand_in[dl])[didx[:, 0], didx[:, 1], didx[:, 2]]]
                coarse |= _touching(corners, L, bl, bidx)
            elif dl < L or bl < L:
                pinned |= _touching(corners, L, bl, bidx)
        ratio = (coarse & ~pinned).reshape(len(tiles), 2, 2, 2).astype(np.float64)
        for i in np.nonzero(ratio.reshape(len(tiles), 8).any(axis=1))[0]:
            out[(L, tuple(int(v) for v in tiles[i]))] = ratio[i]
    return out


class CoverCut(RefinePolicy):
    """The cover as a cut of the shared traversal (:mod:`clipvol.scene.selection.traversal`).

    Its boxes are culled like any cut's (frustum, ``RenderParams.shape``); a data brick outside
    the clip-texture's window is replaced by its nearest ancestor inside it (that tile then does not
    blend); transparent data bricks are dropped. ``node_data`` holds the blend ratios of the tiles
    kept whole, keyed by ``(level, index)`` as the slice action reads them.
    """

    name = "plane"

    def __init__(self, params, plane, cover: SliceCover) -> None:
        super().__init__(params)
        self.plane = plane
        self.cover = cover
        self.node_data: dict = {}

    def refine(self, t, level, lo, hi):  # pragma: no cover - the cut is the cover, not a descent
        return np.zeros(len(lo), dtype=bool)

    def cut(self, t) -> None:
        self.node_data = {}
        for dl, didx, bl, bidx in self.cover.records:
            lo, hi = t.tree.boxes(bl, bidx)
            keep = t._keep_mask(bl, lo, hi)
            dl_arr = np.full(int(keep.sum()), dl, dtype=np.int64)
            d, b = didx[keep].copy(), bidx[keep]
            for L in range(dl, t.tree.top):  # into the window: the nearest ancestor the clip-texture holds
                rows = np.nonzero(dl_arr == L)[0]
                if not len(rows):
                    continue
                out = rows[~t.in_window(L, d[rows])]
                dl_arr[out] += 1
                d[out] //= 2
            t.counts["outside_window"] += int((dl_arr != dl).sum())
            for L in np.unique(dl_arr):
                rows = dl_arr == L
                dd, bb = d[rows], b[rows]
                if int(L) == bl:
                    t.leaves(bl, bb)
                    continue
                ok = t.opaque(int(L), dd)
                if ok.any():
                    t.rec.append((int(L), dd[ok], bl, bb[ok]))
            if dl == bl:
                whole = b[dl_arr == dl]
                for row in whole:
                    key = (bl, tuple(int(v) for v in row))
                    r = self.cover.ratios.get(key)
                    if r is not None:
                        self.node_data[key] = r
        t.counts["balance_splits"] = 0


def slice_cut(pyramid, plane, params, pixel_size: float, size=None, cover: SliceCover | None = None,
              stand_in=None):
    """The cut a slice draws: with a point of interest and no fixed level, the per-brick cover
    (:class:`CoverCut`; ``cover`` if given, else computed for the bricks under ``size`` pixels, with
    ``stand_in`` as :func:`slice_cover` takes it);
    else the plane policy (:class:`~clipvol.scene.selection.policies.plane.PlaneCut`: one level
    everywhere, the finest the pixels need or ``level``)."""
    if params.focus is None or params.level is not None:
        return PlaneCut(params, plane)
    if cover is None:
        view = None if size is None else (lambda L, b: in_view_mask(pyramid, L, b, plane, size, pixel_size))
        cover = slice_cover(pyramid, plane, params, pixel_size, in_view=view, stand_in=stand_in)
    return CoverCut(params, plane, cover)
