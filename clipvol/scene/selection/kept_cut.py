"""A projected-size cut kept between frames and updated where the camera changed it (pure numpy).

A projected-size cut (Bhaniramka & Demange 2002) depends on the camera through two tests per node:
the frustum and the refine decision ("a voxel covers more than ``lod_threshold`` pixels at the
node's nearest depth"). A camera turning one degree flips them for a thin band of nodes near the
level boundaries and the frustum's sides; walking the octree from the root again, level by level,
re-derives everything else. :class:`KeptCut` keeps the nodes the last traversal visited as flat
arrays (level, index, world box, parent row, the camera-free tests: shape, transparency) and, for a
new camera:

1. re-tests only the **band**: each node keeps its *slack* in three channels (the frustum's side
   planes, its near and far planes, the nearest depth), how far (in world units) each may move
   before a test can flip; a camera change moves them at a node by at most the planes' and the view
   direction's turn times the node's *reach* (how far its farthest corner lies from the volume's
   centre) plus their shift at the centre (:func:`_turn_shift`; :func:`camera_change` is the bound
   for the whole volume). Summed frame by frame, these bounds give each node a *deadline* in
   accumulated motion, fixed when it is tested (:class:`~clipvol.scene.selection.band.MotionBand`):
   a frame takes the nodes whose deadline passed (a multiply-compare per node and channel, over
   the nodes whose deadline is finite) and re-tests them exactly. The re-test is the frustum's
   box reach and the nearest and farthest depth: a node's refine answer is the side of its
   level's depth limit it lies on (the policy's ``depth_threshold``), and the rule itself
   (``policy.need``, a fixed ~0.1-0.2 ms a call) is asked only of the nodes within rounding of
   their limit. The near and far planes are a channel of their own: fitted to the volume each
   frame, they shift back and forth while an orbit's side planes only turn;
2. propagates from the nodes whose answers flipped only: a flip changes the evening out
   (``ProjectedSize.even``: per sibling group, then the level as one group) of its own sibling group
   and the level's two counts, and ``reached`` only below the nodes whose "reached and refined"
   changed, walked down through each node's children (a contiguous run of rows); a level whose
   count flips its whole-level evening is set again whole (``ProjectedSize.evens``, the rule per
   group of ``n`` nodes, ``r`` refined). A flip at level 0, or of a node live (reached, in the frustum,
   inside the shape) neither before nor after it, moves nothing there and is left out. The
   selection's counts and its drawn leaves follow by the
   difference over the rows whose answers this changed (:meth:`KeptCut._settle`: each row's key,
   its camera-free kind and its three flags, looked up before and after in one table);
3. grows the tree below nodes that now refine and had no children yet (the traversal's own
   expansion, per level);
4. reads the leaves off the arrays (reached, kept, not refined, not transparent) where one changed.

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
from .band import MotionBand, sorted_unique
from .cut import BrickKeys, DrawItems, Selection
from .octree import Octree
from .order import depth_first, load_order, order_nodes
from .policies.base import RefinePolicy
from .traversal import Traversal

__all__ = ["KeptCounts", "KeptCut", "camera_change"]

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


def _runs(first: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The rows ``first[i] .. first[i] + count[i] - 1`` of every ``i``, concatenated (a node's
    children are one such run)."""
    if not len(count):
        return np.zeros(0, dtype=np.int64)
    c = int(count[0])
    if c and not np.count_nonzero(count != c):  # (every node with as many children: most of an octree)
        return (first[:, None] + np.arange(c, dtype=np.int64)).reshape(-1)
    ends = np.cumsum(count)
    total = int(ends[-1])
    if not total:
        return np.zeros(0, dtype=np.int64)
    return np.arange(total, dtype=np.int64) + np.repeat(first - (ends - count), count)


#: the selection's counts kept by differences over the touched rows (:meth:`KeptCut._tally`)
_TALLIED = ("visited", "culled_frustum", "culled_shape", "culled_transparent", "refined", "drawn")


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
        # a policy whose cut is the level-by-level descent, whose refine answer is a nearest-depth
        # limit per level (it says so with ``depth_threshold``) and whose evening out is per sibling
        # group and then per level (``evens``): the projected size
        self.supported = (getattr(policy, "keep", None) is None and params.max_texels_drawn is None
                          and getattr(policy, "depth_threshold", None) is not None
                          and getattr(policy, "need", None) is not None and getattr(policy, "even", None) is not None
                          and getattr(policy, "evens", None) is not None
                          and getattr(type(policy), "cut", None) is RefinePolicy.cut)
        vlo, vhi = pyramid.volume_box()
        self.centre = (vlo + vhi) / 2.0
        self.radius = float(np.linalg.norm(vhi - vlo)) / 2.0
        # the rows: one per visited node (parents before children; a node's children one run of rows)
        self.lv = np.zeros(1, dtype=np.int64)
        self.lv[0] = tree.root
        self.idx = np.zeros((1, 3), dtype=np.int64)
        self.lo, self.hi = tree.boxes(tree.root, self.idx)
        self.reach = self._reach(self.lo, self.hi)  # how far each node's corners lie from the centre
        self.parent = np.full(1, -1, dtype=np.int64)
        self.first = np.full(1, -1, dtype=np.int64)  # each node's first child row (-1: none)
        self.nchild = np.zeros(1, dtype=np.int64)  # and how many children rows follow it
        self.expanded = np.zeros(1, dtype=bool)
        self.inside = self._inside(self.lv, self.lo, self.hi)  # not outside the shape (camera-free)
        self.opaque = self._opaque(self.lv, self.idx)
        #: transparent level-0 nodes: only the counts ask their frustum answers (:class:`KeptCounts`)
        self.mute = self._mute(self.lv, self.opaque)
        #: the camera-free part of each row's key into the counts' table (:meth:`_kind`)
        self.kind = self._kind(self.lv, self.inside, self.opaque, self.mute)
        self.infr = np.zeros(1, dtype=bool)
        self.ref = np.zeros(1, dtype=bool)  # the rule node by node (policy.need), tested in the band
        self.eff = np.zeros(1, dtype=bool)  # refined: ``ref`` evened out over each level (policy.even)
        self.reached = np.ones(1, dtype=bool)
        #: what the evening out counted: reached and kept (``live``), and ``ref`` evened out in its
        #: sibling group (``geven``); per level, how many of each (``_lvl``): a flip evens again only
        #: its own group and the level's two counts
        self.live = np.zeros(1, dtype=bool)
        self.geven = np.zeros(1, dtype=bool)
        self._lvl = np.zeros((tree.root + 1, 2), dtype=np.int64)
        self._band = MotionBand(3)  # each node's deadlines in accumulated motion
        self._band.grow(self.reach)
        self._terms: np.ndarray | None = None  # the last camera's terms (_camera_terms)
        self.camera = None
        self.retested = 0  # nodes re-tested by the last update (the band), for benchmarks and tests
        self.selection: Selection | None = None
        #: per row, drawn by :attr:`selection` (None: not counted yet)
        self.drawn: np.ndarray | None = None
        self._count = np.zeros(len(_TALLIED), dtype=np.int64)  # the tested rows' counts (_TALLIED)
        self._leaves_changed = True  # a drawn flag changed since the last selection's items
        #: the rows an update touched, with their (reached, infr, eff) before it: the counts and the
        #: drawn flags follow by the difference over these rows alone (:meth:`_settle`)
        self._touched: list = []
        self._seen = np.full(1, -1, dtype=np.int64)
        self._serial = 0
        self._limits: tuple | None = None  # (the lens's pixels per unit at depth 1, depth limit per level)
        #: ``(lv, rows of each level)`` for the ``lv`` array it was made from
        self._levels: tuple | None = None
        #: the policy's sibling groups of a level's nodes (camera-free), where it tells them apart
        self._groups = getattr(policy, "sibling_groups", None)

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

    def _level_rows(self) -> list:
        """The rows of each level (kept with the ``lv`` array they were found in)."""
        if self._levels is None or self._levels[0] is not self.lv:
            order = np.argsort(self.lv, kind="stable")
            ends = np.searchsorted(self.lv[order], np.arange(self.tree.root + 2))
            self._levels = (self.lv, [order[ends[L]:ends[L + 1]] for L in range(self.tree.root + 1)])
        return self._levels[1]

    # -- the camera's tests ----------------------------------------------------------------------
    def _test(self, rows: np.ndarray, camera, ask_all: bool = False) -> np.ndarray:
        """The frustum and refine answers of ``rows`` for ``camera``, all levels at once, and their
        slacks: how much either may change before an answer can flip (their deadlines in the
        band). Transparent level-0 rows are not tested (their answers are only counted,
        :class:`KeptCounts`): their slack is infinite, so no band holds them. Returns which rows'
        answers changed; only those are noted for the counts (:meth:`_touch`: most of a band's
        rows keep their answers, and a settle over them would move nothing).

        The refine answer is the side of its level's depth limit a node lies on
        (:meth:`_depth_slack`; the policy's ``depth_threshold`` states its rule as that limit on the
        nearest depth); the rule itself (``policy.need``, a fixed cost of ~0.1-0.2 ms a call) is
        asked only of the nodes within rounding of their limit, and with ``ask_all`` of every node
        (new rows, another lens)."""
        mute = self.mute[rows]
        some = bool(mute.any())  # (a band never holds a transparent level-0 row; every row may)
        tested = rows[~mute] if some else rows
        slack = np.full((3, len(rows)), np.inf)  # (side planes, near and far, depth) per row
        flipped = np.zeros(len(rows), dtype=bool)
        if len(tested):
            t, tree = self._t, self.tree
            # (np.take: a gather of rows of a 2-d array several times faster than indexing)
            lo, hi, lv = np.take(self.lo, tested, axis=0), np.take(self.hi, tested, axis=0), self.lv[tested]
            r = camera._box_reach(lo, hi, 6)  # what boxes_in_frustum tests
            side = np.minimum(np.minimum(r[:, 0], r[:, 1]), np.minimum(r[:, 2], r[:, 3]))
            ends = np.minimum(r[:, 4], r[:, 5])
            low = np.minimum(side, ends)
            infr = low >= 0  # (every reach >= 0)
            held = self.ref[tested]
            ref = held.copy()
            dslack = np.full(len(tested), np.inf)
            # (level 0, most of a band, is never refined: no answer, no depth slack; a virtual level
            # is always entered)
            real = np.flatnonzero((lv > 0) & (lv <= tree.top))
            if ask_all:
                ref[lv > tree.top] = True
            if len(real):
                rl, rlo, rhi = lv[real], np.take(lo, real, axis=0), np.take(hi, real, axis=0)
                dslack[real], side_now = self._depth_slack(camera, rl, rlo, rhi)
                if ask_all:
                    ask = np.arange(len(real))
                elif side_now is None:  # (an orthographic camera: the answer does not depend on depth)
                    ask = np.zeros(0, dtype=np.int64)
                else:  # the side of its limit a node lies on, the rule asked only within rounding of it
                    ref[real] = side_now
                    ask = np.flatnonzero(dslack[real] <= 1e-9 * max(1.0, self.radius))
                if len(ask):
                    ref[real[ask]] = self.policy.need(t, rl[ask], rlo[ask], rhi[ask])
            changed = (infr != self.infr[tested]) | (ref != held)
            if changed.any():
                self._touch(tested[changed])  # (before the answers change)
            self.infr[tested], self.ref[tested] = infr, ref
            # a kept node flips when a reach crosses 0 (each group of planes: its smallest), a culled
            # one when its most negative does (only that plane's group can bring it in); rounding of
            # the tests themselves: a node this close to flipping is always re-tested
            eps = 1e-9 * max(1.0, self.radius)
            sl = (np.where(infr | (side <= ends), np.where(infr, side, -low), np.inf) - eps,
                  np.where(infr | (side > ends), np.where(infr, ends, -low), np.inf) - eps, dslack - eps)
            if some:
                flipped[~mute] = changed
                for c in range(3):
                    slack[c, ~mute] = sl[c]
            else:
                flipped = changed
                slack[0], slack[1], slack[2] = sl
        self._band.set(rows, slack.T)
        return flipped

    def _depth_slack(self, camera, level: np.ndarray, lo, hi) -> tuple[np.ndarray, np.ndarray | None]:
        """How far each node's nearest depth may move before the projected-size policy's answer
        can flip (``level``: each node's; infinite for every box of an orthographic camera), and
        on which side of its limit each node lies: refined where its nearest depth is below the
        limit and its farthest beyond the eye (None for an orthographic camera)."""
        if camera.orthographic:  # the answer does not depend on depth (the lens is checked in update)
            return np.full(len(lo), np.inf), None
        f = np.asarray(camera.forward, dtype=np.float64)
        c, h = (lo + hi) * 0.5 - camera.eye, (hi - lo) * 0.5
        dc, dh = c @ f, h @ np.abs(f)
        dmin, dmax = dc - dh, dc + dh
        # (the limits depend on the lens alone, as the slacks do: kept while the lens is the same)
        key = float(camera.pixels_per_unit(1.0))
        if self._limits is None or self._limits[0] != key:
            self._limits = (key, np.array([self.policy.depth_threshold(camera, self.tree.voxel(L))
                                           if 0 < L <= self.tree.top else 0.0 for L in range(self.tree.top + 1)]))
        limit = self._limits[1][level]
        # refined while 0 < dmin < limit or dmin <= 0 (the eye plane crosses it); not once dmax <= 0
        return (np.minimum(np.abs(dmin - limit), np.abs(dmax)) - 1e-9 * np.maximum(1.0, np.abs(limit)),
                (dmax > 0) & (dmin < limit))

    # -- the update ------------------------------------------------------------------------------
    def _touch(self, rows: np.ndarray) -> None:
        """Note ``(reached, infr, eff)`` of the rows not noted yet since the last :meth:`_settle`."""
        new = rows[self._seen[rows] != self._serial]
        if len(new):
            self._seen[new] = self._serial
            self._touched.append((new, self.reached[new], self.infr[new], self.eff[new]))

    def _kind(self, lv, inside, opaque, mute) -> np.ndarray:
        """``(n,)`` uint8: each row's camera-free part of its key into :data:`_TABLE` (mute, inside,
        opaque, a real level above 0), times 8."""
        real = (lv > 0) & (lv <= self.tree.top)
        return ((mute.astype(np.uint8) | (inside.astype(np.uint8) << 1) | (opaque.astype(np.uint8) << 2)
                 | (real.astype(np.uint8) << 3)) << 3).astype(np.uint8)

    @staticmethod
    def _rows_tally(reached, infr, eff, mute, inside, opaque, real) -> np.ndarray:
        """``(6, n)`` bool: each row's part in each count of :data:`_TALLIED` for these flags (the
        traversal's counts; transparent level-0 rows are counted by :class:`KeptCounts`)."""
        tested = reached & ~mute
        kept = reached & infr & inside
        leaf = kept & ~eff
        return np.array([reached, tested & ~infr, tested & infr & ~inside, leaf & ~opaque & ~mute,
                         kept & eff & real, leaf & opaque])

    @staticmethod
    def _table() -> np.ndarray:
        """``(128, 7)`` int64: for each key (:meth:`_kind` plus reached, infr and eff in its low
        bits) a row's part in each count of :data:`_TALLIED`, and whether it is drawn (the last
        column): a settle is then a lookup of the touched rows' keys before and after, not a count
        of each flag combination over them."""
        k = np.arange(128)
        bit = [(k >> b & 1).astype(bool) for b in range(7)]
        reached, infr, eff, mute, inside, opaque, real = bit
        t = KeptCut._rows_tally(reached, infr, eff, mute, inside, opaque, real)
        return np.concatenate([t, [reached & infr & inside & ~eff & opaque]]).T.astype(np.int64)

    def _keys(self, rows, reached, infr, eff) -> np.ndarray:
        return self.kind[rows] | reached.view(np.uint8) | (infr.view(np.uint8) << 1) | (eff.view(np.uint8) << 2)

    def _tally(self, rows: np.ndarray, reached, infr, eff) -> np.ndarray:
        """The rows' part of each count of :data:`_TALLIED` for these ``reached``, ``infr``, ``eff``."""
        return np.bincount(self._keys(rows, reached, infr, eff), minlength=128) @ _TABLE[:, :6]

    def _drawn(self, rows: np.ndarray) -> np.ndarray:
        return _TABLE[self._keys(rows, self.reached[rows], self.infr[rows], self.eff[rows]), 6].astype(bool)

    def _settle(self) -> None:
        """The counts and drawn flags moved by what the touched rows changed (their difference)."""
        if self._touched:
            if len(self._touched) == 1:
                rows, *was = self._touched[0]
            else:
                rows = np.concatenate([t[0] for t in self._touched])
                was = [np.concatenate([t[k] for t in self._touched]) for k in (1, 2, 3)]
            now = self._keys(rows, self.reached[rows], self.infr[rows], self.eff[rows])
            self._count += (np.bincount(now, minlength=128) - np.bincount(self._keys(rows, *was), minlength=128)) \
                @ _COUNTS
            d = _DRAWN[now]
            if np.count_nonzero(d != self.drawn[rows]):
                self.drawn[rows] = d
                self._leaves_changed = True
        self._touched = []
        self._serial += 1

    def _recount(self) -> None:
        """The counts, drawn flags and evening counts over every row (after a propagation from nothing)."""
        rows = np.arange(len(self.lv))
        self._count = self._tally(rows, self.reached, self.infr, self.eff)
        self.drawn = self._drawn(rows)
        self._leaves_changed = True
        self._touched = []
        self._serial += 1
        tree, rows_of = self.tree, self._level_rows()
        self.live = self.reached & self.infr & self.inside
        self.geven = np.zeros(len(self.lv), dtype=bool)
        self._lvl[:] = 0
        for L in range(1, tree.root + 1):
            r = rows_of[L]
            r = r[self.live[r]]
            if L > tree.top:
                self.geven[r] = self.ref[r]
                continue
            _, inv = np.unique(self.parent[r], return_inverse=True)
            inv = inv.reshape(-1)
            ge = self.ref[r] | self.policy.evens(np.bincount(inv), np.bincount(inv, weights=self.ref[r]))[inv]
            self.geven[r] = ge
            self._lvl[L] = (len(r), int(np.count_nonzero(ge)))

    def _grow(self, camera, rows: np.ndarray) -> bool:
        """Expand ``rows`` (reached, kept, refined nodes without children yet), level by level (the
        traversal's own expansion), testing the children and propagating from them after each
        round (the new level's nodes decide, evened out together, what is refined there); False
        where a child lies outside the window."""
        tree = self.tree
        while len(rows):
            new_lv, new_idx, new_par = [], [], []
            for L in sorted_unique(self.lv[rows]).tolist():
                r = rows[self.lv[rows] == L]
                c, p = tree.children(L, self.idx[r])
                if L <= tree.top and not self._t.in_window(L - 1, c).all():
                    return False  # a child drawn from its parent: the traversal's records, not kept here
                new_lv.append(np.full(len(c), L - 1, dtype=np.int64))
                new_idx.append(c)
                new_par.append(r[p])
            self.expanded[rows] = True
            lv, idx, par = np.concatenate(new_lv), np.concatenate(new_idx), np.concatenate(new_par)
            n0, m = len(self.lv), len(lv)
            # (each parent's children are one run of rows: tree.children gives them parent by parent)
            start = np.flatnonzero(np.r_[True, par[1:] != par[:-1]])
            self.first[par[start]], self.nchild[par[start]] = n0 + start, np.diff(np.r_[start, m])
            lo, hi = np.empty((m, 3)), np.empty((m, 3))
            for L in sorted_unique(lv).tolist():
                k = lv == L
                lo[k], hi[k] = tree.boxes(L, idx[k])
            reach = self._reach(lo, hi)
            no, yes = np.zeros(m, dtype=bool), np.ones(m, dtype=bool)
            opaque = self._opaque(lv, idx)
            inside, mute = self._inside(lv, lo, hi), self._mute(lv, opaque)
            grown = dict(lv=lv, idx=idx, lo=lo, hi=hi, reach=reach, parent=par,
                         first=np.full(m, -1, dtype=np.int64), nchild=np.zeros(m, dtype=np.int64),
                         expanded=no, inside=inside, opaque=opaque, mute=mute,
                         kind=self._kind(lv, inside, opaque, mute), infr=no, ref=no, eff=no,
                         reached=no, live=no, geven=no, _seen=np.full(m, -1, dtype=np.int64))
            for name, new in grown.items():
                setattr(self, name, np.concatenate([getattr(self, name), new]))
            if self.drawn is not None:
                self.drawn = np.concatenate([self.drawn, yes & False])
            if self._levels is not None:  # the new rows join their levels' rows (the others keep theirs)
                rows_of = list(self._levels[1])
                for L in sorted_unique(lv).tolist():
                    rows_of[L] = np.concatenate([rows_of[L], n0 + np.nonzero(lv == L)[0]])
                self._levels = (self.lv, rows_of)
            self._band.grow(reach)
            new = np.arange(n0, n0 + m)
            self._touch(new)  # (not reached before: they counted nothing)
            self._test(new, camera, ask_all=True)
            rows = self._spread(new)
        return True

    def _spread(self, seeds: np.ndarray, flips: bool = False) -> np.ndarray:
        """Propagate what the rows ``seeds`` changed (their answers, or they are new), level by level
        from the coarsest down: each touched sibling group evened out again and the level's counts
        moved (the whole level evened again only where its count flips the level's evening), and
        ``reached`` set again below the nodes whose "reached and refined" changed. Returns the nodes
        now reached, kept and refined that have no children yet (to grow).

        ``flips``: the seeds are kept rows whose answers flipped (not new rows). Such a seed moves
        nothing where it is live neither before nor after (not reached, culled or outside the
        shape both times: its group's counts stay), nor at level 0 (never refined: its flip moves
        only the counts, noted by :meth:`_test`); both are left out. A seed's own flip never
        changes whether it is reached (its parent's answers do, and a parent that changes brings
        its children itself)."""
        tree, top = self.tree, self.tree.top
        lv, parent = self.lv, self.parent
        ls = lv[seeds]
        one = len(seeds) and not np.count_nonzero(ls != ls[0])  # (the seeds of one level: an orbit's level-1 flips)
        if flips and len(seeds):
            was = self.live[seeds]  # (most of an orbit's flips: live before, above level 0; nothing to leave out)
            if not (one and ls[0] > 0 and np.count_nonzero(was) == len(was)):
                keep = (ls > 0) & (was | (self.reached[seeds] & self.infr[seeds] & self.inside[seeds]))
                if np.count_nonzero(keep) < len(keep):
                    seeds, ls = seeds[keep], ls[keep]
                    one = len(seeds) and not np.count_nonzero(ls != ls[0])
        # (each part of a level's rows to do is distinct rows: the seeds, or the children of distinct
        # nodes; several parts may share rows; a part of children carries their reached, from their
        # parents, level 0 its only use)
        todo: dict[int, list] = {}
        if one:
            todo[int(ls[0])] = [(seeds, None)]
        else:
            for L in sorted_unique(ls).tolist():
                todo[L] = [(seeds[ls == L], None)]
        grow = []
        for L in range(max(todo, default=-1), -1, -1):
            if L not in todo:
                continue
            parts = todo.pop(L)
            if L == 0:  # level 0: reached where its parent is reached and refined (never refined itself)
                if len(parts) == 1 and parts[0][1] is not None:
                    d, r0 = parts[0]
                    self._touch(d)
                    self.reached[d] = r0
                else:
                    d = parts[0][0] if len(parts) == 1 else sorted_unique(np.concatenate([p[0] for p in parts]))
                    self._touch(d)
                    self.reached[d] = self._open_above(d)
                continue
            d = parts[0][0] if len(parts) == 1 else sorted_unique(np.concatenate([p[0] for p in parts]))
            # the sibling groups of ``d``: every child of their parents (the root: a group of its own)
            ups = sorted_unique(parent[d])
            if len(ups) and ups[0] < 0:  # (the root, whose parent is -1)
                ups, roots = ups[1:], d[parent[d] < 0]
                m = np.concatenate([_runs(self.first[ups], self.nchild[ups]), roots])
                grp = np.concatenate([np.repeat(np.arange(len(ups)), self.nchild[ups]),
                                      len(ups) + np.arange(len(roots))])
                self._touch(m)
                reached = self._open_above(m)
            else:  # (a group's rows share their parent: reached is the parent's, repeated)
                nu = self.nchild[ups]
                m = _runs(self.first[ups], nu)
                grp = np.repeat(np.arange(len(ups)), nu)
                self._touch(m)
                reached = (self.reached[ups] & self.eff[ups])[grp]
            open_was = self.reached[m] & self.eff[m]
            live = reached & self.infr[m] & self.inside[m]
            ref = self.ref[m]
            whole = False
            if L > top:  # virtual levels: the rule as it is
                ge, flag = live & ref, False
            else:
                ge = live & (ref | self.policy.evens(np.bincount(grp, weights=live),
                                                     np.bincount(grp, weights=live & ref))[grp])
                n, r = self._lvl[L].tolist()
                was = bool(self.policy.evens(n, r))
                n += int(np.count_nonzero(live)) - int(np.count_nonzero(self.live[m]))
                r += int(np.count_nonzero(ge)) - int(np.count_nonzero(self.geven[m]))
                self._lvl[L] = (n, r)
                flag = bool(self.policy.evens(n, r))
                whole = flag != was
            if whole:  # the level's own evening flipped: every node of the level again
                rl = self._level_rows()[L]
                self._touch(rl)
                open_l = self.reached[rl] & self.eff[rl]
                self.reached[m], self.live[m], self.geven[m] = reached, live, ge
                self.eff[rl] = self.geven[rl] | (flag & self.live[rl])
                changed = rl[open_l != (self.reached[rl] & self.eff[rl])]
            else:
                self.reached[m], self.live[m], self.geven[m] = reached, live, ge
                eff = ge | (flag & live)
                self.eff[m] = eff
                changed = m[open_was != (reached & eff)]
            if len(changed):
                now = self.reached[changed] & self.eff[changed]
                opened = changed[now]
                grow.append(opened[~self.expanded[opened]])
                nb = self.nchild[changed]
                below = nb > 0
                if np.count_nonzero(below):
                    todo.setdefault(L - 1, []).append((_runs(self.first[changed[below]], nb[below]),
                                                       np.repeat(now[below], nb[below])))
        return np.concatenate(grow) if grow else np.zeros(0, dtype=np.int64)

    def _open_above(self, rows: np.ndarray) -> np.ndarray:
        """Whether each row is reached: its parent reached and refined (the root always)."""
        p = self.parent[rows]
        if not len(p) or p.min() >= 0:
            return self.reached[p] & self.eff[p]
        q = np.maximum(p, 0)
        return np.where(p >= 0, self.reached[q] & self.eff[q], True)

    def _propagate(self) -> None:
        """From nothing: reached, the root and every child of a reached, kept, refined node;
        refined (``eff``), the rule's answers of the reached, kept nodes of a level evened out
        together by the policy, as the traversal's ``refine`` does (one gather and one evening per
        level, top down). What the first update and a lens change do; :meth:`_spread` follows the
        changes from there."""
        kept = self.infr & self.inside
        t, top, root = self._t, self.tree.top, self.tree.root
        rows_of = self._level_rows()
        for L in range(root, 0, -1):
            r = rows_of[L]
            if not len(r):
                continue
            p = self.parent[r]
            q = np.maximum(p, 0)
            self.reached[r] = np.where(p >= 0, self.reached[q] & self.eff[q], True)
            self.eff[r] = False
            live = r[self.reached[r] & kept[r]]
            ref = self.ref[live]
            if L > top or not len(live):
                self.eff[live] = ref
                continue
            groups = self._groups(t, L, self.lo[live]) if self._groups is not None else None
            self.eff[live] = self.policy.even(t, L, self.lo[live], ref) if groups is None else \
                self.policy.even(t, L, None, ref, groups=groups)
        r0 = rows_of[0]
        p = self.parent[r0]
        q = np.maximum(p, 0)
        self.reached[r0] = np.where(p >= 0, self.reached[q] & self.eff[q], True)

    def _compact(self) -> None:
        """Keep only the reached nodes (a reached node's parent is reached: the tree stays whole,
        and a node's children stay one run); a node whose children go is marked unexpanded, to grow
        again if it refines again. The dropped rows counted nothing and drew nothing."""
        keep = self.reached
        new = np.cumsum(keep) - 1
        for name in ("lv", "idx", "lo", "hi", "reach", "expanded", "inside", "opaque", "mute", "kind", "infr", "ref",
                     "eff", "reached", "live", "geven", "first", "nchild", "_seen"):
            setattr(self, name, getattr(self, name)[keep])
        if self.drawn is not None:
            self.drawn = self.drawn[keep]
        self._band.take(keep)
        self._levels = None  # (rows renumbered)
        parent = self.parent[keep]
        self.parent = np.where(parent >= 0, new[np.maximum(parent, 0)], -1)
        self.expanded &= self.infr & self.inside & self.eff  # (else its children were not reached)
        self.first = np.where(self.expanded, new[np.maximum(self.first, 0)], -1)
        self.nchild = np.where(self.expanded, self.nchild, 0)

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
        lens = last is not None and (last.orthographic != camera.orthographic
                                     or float(last.pixels_per_unit(1.0)) != float(camera.pixels_per_unit(1.0)))
        if lens:  # another lens or image size: the depth limits moved, every slack is void: test everything
            self._band.everything()
        if self._terms is None:
            turn = shift = np.zeros(3)
        else:  # this frame's move: the largest turn and shift of the side planes, of the near and far
            # planes (fitted to the volume each frame: they shift back and forth, the sides do not), and
            # the view direction's
            t, s = _turn_shift(self._terms, terms)
            turn = np.array([t[:4].max(), t[4:6].max(), t[6]])
            shift = np.array([s[:4].max(), s[4:6].max(), s[6]])
        self._terms = terms
        band = self._band.advance(turn, shift)
        self._t.camera = self.camera = camera
        flipped = self._test(band, camera, ask_all=lens or self.drawn is None)
        self.retested = len(band)
        changed = self.selection is None or bool(flipped.any())
        if not changed:
            self._touched, self._serial = [], self._serial + 1  # (nothing moved)
            if not ordered and not self.selection.ordered:
                # (the same object; its counts this camera's: a transparent level-0 node's may differ)
                self.selection.counts = self._counts(camera, self.selection.counts._base)
                return self.selection
        else:
            if self.drawn is None:  # the first cut: from nothing
                self._propagate()
                self._recount()
                go = np.nonzero(self.reached & self.infr & self.inside & self.eff & ~self.expanded)[0]
            else:  # from the flipped nodes down
                go = self._spread(band[flipped], flips=True)
                self._settle()
            n_out = len(self.lv) - int(self._count[0])
            if n_out > max(COMPACT_MIN, len(self.lv) - n_out):
                self._compact()
                go = np.nonzero(self.reached & self.infr & self.inside & self.eff & ~self.expanded)[0]
            if not self._grow(camera, go):
                self.supported = False
                return None
            self._settle()
        self.selection = self._selection(camera, ordered)
        return self.selection

    def _counts(self, camera, base: dict) -> KeptCounts:
        """The counts for ``camera``: ``base`` (the tested nodes') and the transparent level-0
        nodes', these read off the arrays as they are now when first asked."""
        return KeptCounts(base, camera, self.lo, self.hi, self.inside, self.mute, self.reached.copy())

    def _selection(self, camera, ordered: bool) -> Selection:
        tree = self.tree
        c = dict(zip(_TALLIED, self._count.tolist()))
        counts = self._counts(camera, dict(
            visited=c["visited"], culled_frustum=c["culled_frustum"], culled_shape=c["culled_shape"],
            culled_transparent=c["culled_transparent"], culled_policy=0, refined=c["refined"], outside_window=0,
            fallback=0, missing=0, texels=c["drawn"] * tree.texels, level=-1))
        last = self.selection
        node_data = getattr(self.policy, "node_data", None)
        node_data = dict(node_data) if node_data else {}
        if not ordered and last is not None and not last.ordered and not self._leaves_changed:
            # the band's answers flipped but no leaf did (a node culled or refined on another side):
            # the same items and wanted keys, kept objects, so that whatever was made of them (the
            # merge, the page table, the GPU check) is kept with them; only the counts are new
            return Selection(last.items, last.wanted, counts, self.params.policy, node_data, None, ordered=False)
        self._leaves_changed = False
        draw = np.nonzero(self.drawn)[0]
        lv, idx = self.lv[draw], self.idx[draw]
        keys = np.concatenate([lv[:, None], idx], axis=1)
        if ordered:
            u = unique_rows(keys) if len(keys) else keys
            wanted = u[load_order(tree, camera, u[:, 0], u[:, 1:])]
            o = order_nodes(tree, camera, lv, idx)
        else:
            o = depth_first(lv, idx)
            wanted = keys[o]
        do = draw[o]
        items = DrawItems(keys[o], np.take(self.lo, do, axis=0), np.take(self.hi, do, axis=0))
        return Selection(items, BrickKeys(wanted), counts, self.params.policy, node_data, None, ordered=ordered)


#: :meth:`KeptCut._table`, made once
_TABLE = KeptCut._table()
#: its counts' columns (contiguous) and its drawn column (bool), what a settle reads
_COUNTS, _DRAWN = np.ascontiguousarray(_TABLE[:, :6]), _TABLE[:, 6].astype(bool)
