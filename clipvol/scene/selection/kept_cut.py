"""A projected-size cut kept between frames and updated where the camera changed it (pure numpy).

A projected-size cut (Bhaniramka & Demange 2002) depends on the camera through two tests per node:
the frustum and the refine decision ("a voxel covers more than ``lod_threshold`` pixels at the
node's nearest depth"). A camera turning one degree flips them for a thin band of nodes near the
level boundaries and the frustum's sides; walking the octree from the root again, level by level,
re-derives everything else. :class:`KeptCut` keeps the nodes the last traversal visited as flat
arrays (level, index, world box, parent row, the camera-free tests: shape, transparency) and, for a
new camera:

1. re-tests only the **band**: each node keeps its *slack*, how far (in world units) the camera's
   frustum planes and the node's nearest depth may move before either test can flip, and the
   camera it was last tested at; the change from that camera to this one is bounded per node by
   the planes' and the view direction's turn times the node's *reach* (how far its farthest
   corner lies from the volume's centre), plus their shift at the centre (:func:`_turn_shift`;
   :func:`camera_change` is the bound for the whole volume), so a node whose slack exceeds its
   bound keeps its answers untested - and a node near the centre moves less than the corners;
2. propagates "reached" through the parents' answers (one gather per level) from the coarsest
   level whose answers flipped down (the levels above keep theirs), and sets level 0 - most of
   the nodes, never refined - again only under the level-1 nodes whose answer changed;
3. grows the tree below nodes that now refine and had no children yet (the traversal's own
   expansion, per level);
4. reads the leaves off the arrays: reached, kept, not refined, not transparent.

A transparent level-0 node (most of a band beside the frustum's side planes: air around the data)
is never drawn and never refined, so its frustum answer changes nothing but the selection's
counts (frustum-culled, shape-culled or transparent-culled). It is left out of the band, and the
counts it feeds come from :class:`KeptCounts`, which tests those nodes against the frame's camera
only when a count is read: the counts stay exactly ``select``'s, and a frame nobody asks them of
does not pay for them.

The cut it gives equals :func:`~clipvol.scene.selection.select`'s for the same camera exactly (the
tests are the traversal's own functions on the same boxes; ``tests/scene/test_kept_cut.py``
checks it over random camera paths against a fresh selection). With ``ordered=False`` the items
come in depth-first (Morton) order, not back to front: the merge needs only siblings side by side,
and the single pass no order at all; the render action orders the merged boxes where a path draws
them one by one (:func:`~clipvol.scene.selection.coherence.node_order`). Ray-guided renderers
(Crassin et al., *GigaVoxels*, 2009) avoid the walk altogether; this keeps the host's exact cut
and only stops re-deriving what cannot have changed.

What it does not handle (:meth:`KeptCut.update` returns None, and the caller selects from nothing):
a child outside the clip-texture's window (drawn from its parent), a policy with its own ``keep``
test, a budgeted (greedy) cut. Residency is the caller's: the cut is the ideal cut, every leaf
drawn from its own brick (the frame loop uses it only while every brick is on the GPU).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ...rows import unique_rows
from .cut import BrickKeys, DrawItems, Selection
from .octree import Octree
from .order import depth_first, load_order, order_nodes
from .policies.base import RefinePolicy
from .traversal import Traversal

__all__ = ["KeptCounts", "KeptCut", "camera_change"]

#: cameras kept to bound each node's change from the one it was last tested at; past this many,
#: those no node refers to are dropped (and if still more, every node is tested again)
MAX_CAMERAS = 64
#: drop the nodes no longer reached once they outnumber the reached ones and this many (a long
#: fly-through would otherwise keep every node it ever visited)
COMPACT_MIN = 4096


def _camera_terms(camera, centre: np.ndarray) -> np.ndarray:
    """``(7, 4)``: each frustum plane's normal and its value at ``centre``, and the view direction
    and the depth of ``centre``: every test of a node is a function of these and of the node's box
    relative to ``centre`` (:func:`camera_change`)."""
    p = camera._plane_table()  # planes relative to the eye: n . (x - eye) + d
    off = p[:, :3] @ (centre - camera.eye) + p[:, 3]
    f = np.asarray(camera.forward, dtype=np.float64)
    return np.concatenate([np.concatenate([p[:, :3], off[:, None]], axis=1),
                           [[*f, float(f @ (centre - camera.eye))]]])


def camera_change(a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """``(..., 7)``: the most any frustum plane's value (rows 0-5) and any depth (row 6) of a point
    within ``radius`` of the centre can change between cameras with terms ``a`` and ``b``
    (:func:`_camera_terms`; ``a`` may hold many cameras, ``(..., 7, 4)``): ``|dn| radius +
    |d(value at centre)|``, each point's value being ``n . (x - centre)`` plus the value at the
    centre."""
    turn, shift = _turn_shift(a, b)
    return turn * radius + shift


def _turn_shift(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(..., 7)`` each: the turn ``|dn|`` of each frustum plane's normal and of the view direction
    between cameras with terms ``a`` and ``b``, and the change of their value at the centre: a point
    at distance ``r`` from the centre changes by at most ``turn * r + shift``
    (:func:`camera_change` with ``r`` the volume's radius)."""
    d = np.asarray(b) - np.asarray(a)
    return np.linalg.norm(d[..., :3], axis=-1), np.abs(d[..., 3])


class KeptCounts(Mapping):
    """A kept cut's :attr:`Selection.counts <clipvol.scene.selection.cut.Selection>` for one camera:
    the counts of the tested nodes, and those of the transparent level-0 nodes (never drawn, never
    refined: only the counts ask their frustum answers) added on the first read.

    It holds the arrays those need as they were at the update (the kept cut replaces its box
    arrays rather than writing into them; ``reached`` is copied), so a count read frames later is
    still its own camera's. Read-only; :meth:`copy` gives itself (what ``dict.copy`` is to a dict).
    """

    def __init__(self, base: dict, camera, lo, hi, inside, mute, reached) -> None:
        self._base, self._late = base, (camera, lo, hi, inside, mute, reached)
        self._all: dict | None = None

    def _counts(self) -> dict:
        if self._all is None:
            camera, lo, hi, inside, mute, reached = self._late
            rows = np.nonzero(reached & mute)[0]
            infr = np.all(camera._box_reach(lo[rows], hi[rows], 6) >= 0, axis=1)  # (the traversal's test)
            ins = inside[rows]
            out = dict(self._base)
            out["culled_frustum"] += int((~infr).sum())
            out["culled_shape"] += int((infr & ~ins).sum())
            out["culled_transparent"] += int((infr & ins).sum())
            self._all, self._late = out, None
        return self._all

    def __getitem__(self, key):
        if key in self._base and key not in ("culled_frustum", "culled_shape", "culled_transparent"):
            return self._base[key]
        return self._counts()[key]

    def __iter__(self):
        return iter(self._base)

    def __len__(self) -> int:
        return len(self._base)

    def __repr__(self) -> str:
        return f"KeptCounts({self._counts()!r})"

    def copy(self) -> "KeptCounts":
        return self


class KeptCut:
    """The nodes a projected-size traversal visited, kept as flat arrays, and updated per camera.

    Parameters
    ----------
    pyramid, params, policy, residency, transparent
        As for :func:`~clipvol.scene.selection.select`; ``residency`` is asked only which children
        lie in the clip-texture's window (``in_window_mask``), never to reserve anything.

    Use :meth:`update` for each camera; :attr:`supported` is False (and every update None) for a
    cut it cannot keep exactly (module docstring).
    """

    def __init__(self, pyramid, params, policy, residency=None, transparent=None) -> None:
        self.tree = tree = Octree(pyramid)
        self.params, self.policy = params, policy
        self._t = Traversal(tree, None, params, policy, residency, transparent)
        self.transparent, self.shape = transparent, params.shape
        # a policy whose cut is the level-by-level descent and whose refine answer is a nearest-depth
        # limit per level (it says so with ``depth_threshold``): the projected size
        self.supported = (getattr(policy, "keep", None) is None and params.max_texels_drawn is None
                          and getattr(policy, "depth_threshold", None) is not None
                          and getattr(policy, "need", None) is not None and getattr(policy, "even", None) is not None
                          and getattr(type(policy), "cut", None) is RefinePolicy.cut)
        vlo, vhi = pyramid.volume_box()
        self.centre = (vlo + vhi) / 2.0
        self.radius = float(np.linalg.norm(vhi - vlo)) / 2.0
        # the rows: one per visited node (parents before children)
        self.lv = np.zeros(1, dtype=np.int64)
        self.lv[0] = tree.root
        self.idx = np.zeros((1, 3), dtype=np.int64)
        self.lo, self.hi = tree.boxes(tree.root, self.idx)
        self.reach = self._reach(self.lo, self.hi)  # how far each node's corners lie from the centre
        self.parent = np.full(1, -1, dtype=np.int64)
        self.expanded = np.zeros(1, dtype=bool)
        self.inside = self._inside(self.lv, self.lo, self.hi)  # not outside the shape (camera-free)
        self.opaque = self._opaque(self.lv, self.idx)
        #: transparent level-0 nodes: only the counts ask their frustum answers (:class:`KeptCounts`)
        self.mute = self._mute(self.lv, self.opaque)
        self.infr = np.zeros(1, dtype=bool)
        self.ref = np.zeros(1, dtype=bool)  # the rule node by node (policy.need), tested in the band
        self.eff = np.zeros(1, dtype=bool)  # refined: ``ref`` evened out over each level (policy.even)
        self.slack = np.full((1, 2), -np.inf)  # (frustum, depth) slack against the reference camera
        self.reached = np.ones(1, dtype=bool)
        self.cam_id = np.zeros(1, dtype=np.int64)  # the camera (in _cams) each node was last tested at
        self._cams: list[np.ndarray] = []
        self.camera = None
        self.retested = 0  # nodes re-tested by the last update (the band), for benchmarks and tests
        self.selection: Selection | None = None
        #: per row, drawn by :attr:`selection` (None: not known row by row, after a compaction)
        self.drawn: np.ndarray | None = None
        #: ``(lv, rows of each level)`` for the ``lv`` array it was made from, and per level the
        #: last evening out ``(live rows, their answers, evened, their sibling groups)``: :meth:`_propagate`
        #: evens again only a level whose reached nodes or answers changed (most of a small move's
        #: levels keep both), and keeps the groups while the nodes are the same
        self._levels: tuple | None = None
        self._evened: dict = {}
        #: the policy's sibling groups of a level's nodes (camera-free), where it tells them apart
        self._groups = getattr(policy, "sibling_groups", None)
        #: level 0's ``reached`` was set by a full pass over the rows :attr:`_levels` holds (a new row
        #: or a renumbering sets it again in full)
        self._level0 = False

    # -- the camera-free tests -------------------------------------------------------------------
    def _reach(self, lo, hi) -> np.ndarray:
        """``(n,)``: the farthest any corner of each box lies from the centre (an upper bound)."""
        return np.linalg.norm((lo + hi) * 0.5 - self.centre, axis=1) + np.linalg.norm(hi - lo, axis=1) * 0.5

    def _inside(self, lv, lo, hi) -> np.ndarray:
        if self.shape is None or self.shape.is_everything:
            return np.ones(len(lv), dtype=bool)
        return ~np.asarray(self.shape.boxes_outside(lo, hi), dtype=bool).reshape(len(lv))

    def _opaque(self, lv, idx) -> np.ndarray:
        out = np.ones(len(lv), dtype=bool)
        if self.transparent is None:
            return out
        for L in np.unique(lv[lv <= self.tree.top]).tolist():
            m = lv == L
            out[m] = ~np.asarray(self.transparent(L, idx[m]), dtype=bool).reshape(int(m.sum()))
        return out

    @staticmethod
    def _mute(lv, opaque) -> np.ndarray:
        return (lv == 0) & ~opaque

    # -- the camera's tests ----------------------------------------------------------------------
    def _test(self, rows: np.ndarray, camera) -> None:
        """The frustum and refine answers of ``rows`` for ``camera`` (the last of ``_cams``), and
        their slacks: how much either may change before an answer can flip. Transparent level-0 rows
        are not tested (their answers are only counted, :class:`KeptCounts`): their slack is
        infinite, so no band holds them."""
        mute = self.mute[rows]
        if mute.any():
            self.slack[rows[mute]] = np.inf
            rows = rows[~mute]
        if not len(rows):
            return
        t, tree = self._t, self.tree
        lo, hi, lv = self.lo[rows], self.hi[rows], self.lv[rows]
        reach = camera._box_reach(lo, hi, 6)  # what boxes_in_frustum tests
        infr = np.all(reach >= 0, axis=1)
        ref = np.zeros(len(rows), dtype=bool)
        dslack = np.full(len(rows), np.inf)
        f = np.asarray(camera.forward, dtype=np.float64)
        up = np.nonzero(lv > 0)[0]  # (level 0, most of a band, is never refined: no answer, no depth slack)
        if len(up):
            ulv = lv[up]
            for L in np.unique(ulv).tolist():
                m = up[ulv == L]
                if L > tree.top:
                    ref[m] = True  # virtual levels are always entered
                else:
                    ref[m] = self.policy.need(t, L, lo[m], hi[m])
                    dslack[m] = self._depth_slack(camera, f, L, lo[m], hi[m])
        # a kept node flips when its smallest reach crosses 0, a culled one when its most negative does
        fslack = np.where(infr, reach.min(axis=1), -np.where(reach < 0, reach, 0).min(axis=1))
        self.infr[rows], self.ref[rows] = infr, ref
        # rounding of the tests themselves: a node this close to flipping is always re-tested
        self.slack[rows] = np.stack([fslack, dslack], axis=1) - 1e-9 * max(1.0, self.radius)
        self.cam_id[rows] = len(self._cams) - 1

    def _depth_slack(self, camera, f, level: int, lo, hi) -> np.ndarray:
        """How far a node's nearest depth may move before the projected-size policy's answer can
        flip (infinite where it cannot: level 0; every box of an orthographic camera)."""
        if camera.orthographic:  # the answer does not depend on depth (the lens is checked in update)
            return np.full(len(lo), np.inf)
        c, h = (lo + hi) * 0.5 - camera.eye, (hi - lo) * 0.5
        dc, dh = c @ f, h @ np.abs(f)
        dmin, dmax = dc - dh, dc + dh
        limit = self.policy.depth_threshold(camera, self.tree.voxel(level))
        # refined while 0 < dmin < limit or dmin <= 0 (the eye plane crosses it); not once dmax <= 0
        return np.minimum(np.abs(dmin - limit), np.abs(dmax)) - 1e-9 * max(1.0, abs(limit))

    # -- the update ------------------------------------------------------------------------------
    def _grow(self, camera, propagated: bool = False) -> bool:
        """Expand every reached, kept, refined node without children yet, level by level (the
        traversal's own expansion), propagating after each round (the new level's nodes decide,
        evened out together, what is refined there); False where a child lies outside the window.
        ``propagated``: the answers were propagated since they last changed (no first round)."""
        tree = self.tree
        coarsest = None  # (the first round: any level may have changed)
        while True:
            if not propagated:
                self._propagate(coarsest)
            propagated = False
            go = self.reached & self.infr & self.inside & self.eff & ~self.expanded
            rows = np.nonzero(go)[0]
            if not len(rows):
                return True
            new_lv, new_idx, new_par = [], [], []
            for L in np.unique(self.lv[rows]).tolist():
                r = rows[self.lv[rows] == L]
                c, p = tree.children(L, self.idx[r])
                if L <= tree.top and not self._t.in_window(L - 1, c).all():
                    return False  # a child drawn from its parent: the traversal's records, not kept here
                new_lv.append(np.full(len(c), L - 1, dtype=np.int64))
                new_idx.append(c)
                new_par.append(r[p])
            self.expanded[rows] = True
            lv, idx, par = np.concatenate(new_lv), np.concatenate(new_idx), np.concatenate(new_par)
            lo, hi = np.empty((len(lv), 3)), np.empty((len(lv), 3))
            for L in np.unique(lv).tolist():
                m = lv == L
                lo[m], hi[m] = tree.boxes(L, idx[m])
            n0 = len(self.lv)
            self.lv = np.concatenate([self.lv, lv])
            self.idx = np.concatenate([self.idx, idx])
            self.lo, self.hi = np.concatenate([self.lo, lo]), np.concatenate([self.hi, hi])
            self.reach = np.concatenate([self.reach, self._reach(lo, hi)])
            self.parent = np.concatenate([self.parent, par])
            self.expanded = np.concatenate([self.expanded, np.zeros(len(lv), dtype=bool)])
            self.inside = np.concatenate([self.inside, self._inside(lv, lo, hi)])
            opaque = self._opaque(lv, idx)
            self.opaque = np.concatenate([self.opaque, opaque])
            self.mute = np.concatenate([self.mute, self._mute(lv, opaque)])
            self.infr = np.concatenate([self.infr, np.zeros(len(lv), dtype=bool)])
            self.ref = np.concatenate([self.ref, np.zeros(len(lv), dtype=bool)])
            self.eff = np.concatenate([self.eff, np.zeros(len(lv), dtype=bool)])
            self.slack = np.concatenate([self.slack, np.zeros((len(lv), 2))])
            self.cam_id = np.concatenate([self.cam_id, np.zeros(len(lv), dtype=np.int64)])
            self.reached = np.concatenate([self.reached, np.ones(len(lv), dtype=bool)])
            if self.drawn is not None:
                self.drawn = np.concatenate([self.drawn, np.zeros(len(lv), dtype=bool)])
            if self._levels is not None:  # the new rows join their levels' rows (the others keep theirs)
                rows_of = list(self._levels[1])
                for L in np.unique(lv).tolist():
                    rows_of[L] = np.concatenate([rows_of[L], n0 + np.nonzero(lv == L)[0]])
                self._levels = (self.lv, rows_of)
            self._test(np.arange(n0, len(self.lv)), camera)
            # the next round propagates from the new rows' level down: the levels above keep their
            # answers, and a new child of level 0 is reached (its parent is reached and refined)
            coarsest = int(lv.max())

    def _propagate(self, coarsest: int | None = None) -> None:
        """Reached: the root, and every child of a reached, kept, refined node; refined (``eff``):
        the rule's answers of the reached, kept nodes of a level evened out together, as the
        traversal's ``refine`` does (one gather and one evening per level, top down).

        ``coarsest``: the coarsest level whose nodes' answers changed since the last propagation
        (None: any may have). The levels above it keep what they had; level 0 (most of the rows,
        never refined) is set again only under the level-1 nodes whose "reached and refined"
        changed, while its rows are the ones the last full pass set."""
        kept = self.infr & self.inside
        t, top, root = self._t, self.tree.top, self.tree.root
        if self._levels is None or self._levels[0] is not self.lv:  # the rows of each level (kept with them)
            order = np.argsort(self.lv, kind="stable")
            ends = np.searchsorted(self.lv[order], np.arange(root + 2))
            self._levels = (self.lv, [order[ends[L]:ends[L + 1]] for L in range(root + 1)])
            self._evened = {}
            self._level0 = False
            coarsest = None
        if coarsest is None:
            coarsest = root
        rows_of = self._levels[1]
        r1 = rows_of[1] if root >= 1 else rows_of[0][:0]
        open1 = self.reached[r1] & self.eff[r1]  # the level-1 nodes' answers to their children, before
        for L in range(min(coarsest, root), 0, -1):
            r = rows_of[L]
            if not len(r):
                continue
            if L == root:
                self.reached[r] = self.parent[r] < 0
            else:
                p = self.parent[r]
                self.reached[r] = np.where(p >= 0, self.reached[np.maximum(p, 0)] & self.eff[np.maximum(p, 0)], True)
            self.eff[r] = False
            live = r[self.reached[r] & kept[r]]
            ref = self.ref[live]
            if L > top or not len(live):
                self.eff[live] = ref
                continue
            last = self._evened.get(L)  # a level whose nodes and answers did not change evens out the same
            same = last is not None and np.array_equal(last[0], live)
            if same and np.array_equal(last[1], ref):
                self.eff[live] = last[2]
                continue
            # the same nodes, other answers: their sibling groups kept (the camera does not move them)
            groups = last[3] if same else None
            if groups is None and self._groups is not None:
                groups = self._groups(t, L, self.lo[live])
            eff = self.policy.even(t, L, self.lo[live], ref) if groups is None else \
                self.policy.even(t, L, None, ref, groups=groups)
            self._evened[L] = (live, ref, eff, groups)
            self.eff[live] = eff
        # level 0: reached where its parent is reached and refined (never refined itself: no answer)
        r0 = rows_of[0]
        if not len(r0):
            return
        if root == 0:
            self.reached[r0] = self.parent[r0] < 0
            return
        if self._level0:  # only the children of level-1 nodes whose answer changed
            moved = r1[open1 != (self.reached[r1] & self.eff[r1])]
            if not len(moved):
                return
            flag = np.zeros(len(self.lv), dtype=bool)
            flag[moved] = True
            r0 = r0[flag[self.parent[r0]]]
        p = self.parent[r0]
        self.reached[r0] = np.where(p >= 0, self.reached[np.maximum(p, 0)] & self.eff[np.maximum(p, 0)], True)
        self._level0 = True

    def _compact(self) -> None:
        """Keep only the reached nodes (a reached node's parent is reached: the tree stays whole); a
        node whose children go is marked unexpanded, to grow again if it refines again."""
        keep = self.reached
        new = np.cumsum(keep) - 1
        for name in ("lv", "idx", "lo", "hi", "reach", "expanded", "inside", "opaque", "mute", "infr", "ref", "eff", "slack",
                     "cam_id", "reached"):
            setattr(self, name, getattr(self, name)[keep])
        self.drawn = None  # (a dropped row may have been drawn: the next selection compares keys anew)
        self._levels = None  # (rows renumbered)
        parent = self.parent[keep]
        self.parent = np.where(parent >= 0, new[np.maximum(parent, 0)], -1)
        self.expanded &= self.infr & self.inside & self.eff  # (else its children were not reached)

    def update(self, camera, ordered: bool = True) -> Selection | None:
        """The cut :func:`~clipvol.scene.selection.select` makes for ``camera`` (residency apart:
        every leaf drawn from its own brick), or None where this cut cannot be kept (module
        docstring). The same :class:`Selection` object comes back while no tested node's answer
        changed (its ``counts`` replaced by this camera's :class:`KeptCounts`);
        with ``ordered=False``, a new one holding the same ``items`` and ``wanted`` objects while no
        leaf changed, so that what a caller made of the items stays valid.

        ``ordered``: items in back-to-front order and ``wanted`` in load order, as ``select``
        gives them; False: both in depth-first order (no visibility order, no distances), and the
        selection's ``ordered`` is False.
        """
        if not self.supported:
            return None
        if self.selection is not None and not ordered and not self.selection.ordered and \
                (camera is self.camera or camera == self.camera):
            self.retested = 0  # a still camera: every answer is the one it gave last
            return self.selection
        terms = _camera_terms(camera, self.centre)
        last = self.camera
        if last is not None and (last.orthographic != camera.orthographic
                                 or float(last.pixels_per_unit(1.0)) != float(camera.pixels_per_unit(1.0))):
            self.slack[:] = -np.inf  # another lens or image size: the depth limits moved, test everything
        if len(self._cams) > MAX_CAMERAS:  # forget the cameras no node was last tested at
            used, self.cam_id = np.unique(self.cam_id, return_inverse=True)
            self._cams = [self._cams[i] for i in used.tolist()]
            if len(self._cams) > MAX_CAMERAS:
                self.slack[:] = -np.inf
        turn, shift = _turn_shift(np.asarray(self._cams).reshape(-1, 7, 4), terms) if self._cams \
            else (np.zeros((1, 7)), np.zeros((1, 7)))
        # each node's bound from the camera it was last tested at: the turn of the planes (and of the
        # view direction) times the node's reach from the centre, plus their shift at the centre
        # (per camera first, then gathered: a node near the centre moves less than the volume's corners)
        cid = self.cam_id
        band = np.nonzero((self.slack[:, 0] <= turn[:, :6].max(axis=1)[cid] * self.reach + shift[:, :6].max(axis=1)[cid])
                          | (self.slack[:, 1] <= turn[:, 6][cid] * self.reach + shift[:, 6][cid]))[0]
        self._cams.append(terms)
        was = (self.infr[band].copy(), self.ref[band].copy())
        self._t.camera = self.camera = camera
        self._test(band, camera)
        self.retested = len(band)
        flipped = (was[0] != self.infr[band]) | (was[1] != self.ref[band])
        changed = self.selection is None or bool(flipped.any())
        if not changed and not ordered and not self.selection.ordered:
            # (the same object; its counts this camera's: a transparent level-0 node's may differ)
            self.selection.counts = self._counts(camera, self.selection.counts._base)
            return self.selection
        if changed:  # (from the coarsest level whose answers flipped down)
            self._propagate(None if self.selection is None else int(self.lv[band[flipped]].max()))
            n_out = len(self.lv) - int(self.reached.sum())
            if n_out > max(COMPACT_MIN, len(self.lv) - n_out):
                self._compact()
            if not self._grow(camera, propagated=True):
                self.supported = False
                return None
        self.selection = self._selection(camera, ordered)
        return self.selection

    def _counts(self, camera, base: dict) -> KeptCounts:
        """The counts for ``camera``: ``base`` (the tested nodes') and the transparent level-0
        nodes', these read off the arrays as they are now when first asked."""
        return KeptCounts(base, camera, self.lo, self.hi, self.inside, self.mute, self.reached.copy())

    def _selection(self, camera, ordered: bool) -> Selection:
        tree = self.tree
        kept = self.reached & self.infr & self.inside
        real = self.lv <= tree.top
        leaf = kept & ~self.eff
        mask = leaf & self.opaque
        draw = np.nonzero(mask)[0]
        tested = self.reached & ~self.mute  # (the transparent level-0 nodes are counted by KeptCounts)
        counts = self._counts(camera, dict(
            visited=int(self.reached.sum()), culled_frustum=int((tested & ~self.infr).sum()),
            culled_shape=int((tested & self.infr & ~self.inside).sum()),
            culled_transparent=int((leaf & ~self.opaque & ~self.mute).sum()), culled_policy=0,
            refined=int((kept & self.eff & real & (self.lv > 0)).sum()), outside_window=0,
            fallback=0, missing=0, texels=len(draw) * tree.texels, level=-1))
        last, was = self.selection, self.drawn
        self.drawn = mask
        node_data = getattr(self.policy, "node_data", None)
        node_data = dict(node_data) if node_data else {}
        if not ordered and last is not None and not last.ordered and was is not None and np.array_equal(mask, was):
            # the band's answers flipped but no leaf did (a node culled or refined on another side):
            # the same items and wanted keys, kept objects, so that whatever was made of them (the
            # merge, the page table, the GPU check) is kept with them; only the counts are new
            return Selection(last.items, last.wanted, counts, self.params.policy, node_data, None, ordered=False)
        lv, idx = self.lv[draw], self.idx[draw]
        keys = np.concatenate([lv[:, None], idx], axis=1)
        if ordered:
            u = unique_rows(keys) if len(keys) else keys
            wanted = u[load_order(tree, camera, u[:, 0], u[:, 1:])]
            o = order_nodes(tree, camera, lv, idx)
        else:
            o = depth_first(lv, idx)
            wanted = keys[o]
        items = DrawItems(keys[o], self.lo[draw][o], self.hi[draw][o])
        return Selection(items, BrickKeys(wanted), counts, self.params.policy, node_data, None, ordered=ordered)
