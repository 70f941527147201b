"""The merge of a kept cut, merged again only in the cells whose leaves changed
(clipvol.scene.selection.merge.KeptMerge), against the merge from nothing (``merge_items``) of the
same cut, entry for entry and in the same order, along random camera paths; and, independently of
the merge's code, a numpy count of level-0 cells: the merged boxes cover every brick of the cut
from its own level, no cell twice, and nothing else but culled siblings ``may_cover`` allowed."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.scene.params import RenderParams
from clipvol.scene.selection import merge_items
from clipvol.scene.selection.kept_cut import KeptCut
from clipvol.scene.selection.merge import KeptMerge
from clipvol.scene.selection.policies import policy_for

from test_kept_cut import PYR, camera, path, transparent


def cover_some(level, node_level, nodes):
    """A camera-free ``may_cover``: about two thirds of the culled nodes may be covered."""
    nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
    return (nodes @ np.array([7, 3, 1]) + level + 2 * node_level) % 3 != 0


def level0_cover(rows, span, pyr) -> np.ndarray:
    """Per level-0 brick of ``pyr``, the data level + 1 of the boxes covering it, summed (0: none),
    and how many boxes cover it; each box ``(L, first, span)`` covers its bricks clipped to level
    L's grid, each of those 2^L level-0 bricks per axis clipped to level 0's grid."""
    g0 = np.asarray(pyr.grid(0))
    lvl = np.zeros(tuple(g0), dtype=np.int64)
    cnt = np.zeros(tuple(g0), dtype=np.int64)
    for (L, z, y, x), s in zip(rows.tolist(), span.tolist()):
        gL = np.asarray(pyr.grid(L))
        hi = np.minimum(np.array([z, y, x]) + s, gL) << L
        lo = np.array([z, y, x]) << L
        hi = np.minimum(hi, g0)
        lvl[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] += L + 1
        cnt[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] += 1
    return lvl, cnt


def check_cover(cut, merged, pyr, exact: bool) -> None:
    lvl_cut, cnt_cut = level0_cover(cut.rows, cut.span, pyr)
    lvl_m, cnt_m = level0_cover(merged.rows, merged.span, pyr)
    assert cnt_m.max() <= 1  # no region drawn twice
    drawn = cnt_cut > 0
    np.testing.assert_array_equal(lvl_m[drawn], lvl_cut[drawn])  # every brick of the cut, from its own level
    if exact:
        np.testing.assert_array_equal(cnt_m > 0, drawn)


def cover_moving(frame: int):
    """A ``may_cover`` whose answers change every third frame (as a camera's "beside the view" does)."""
    def cover(level, node_level, nodes):
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
        return (nodes @ np.array([7, 3, 1]) + level + frame // 3) % 3 != 0
    return cover


def cover_split(frame: int):
    """``cover_moving``'s answers in the render action's two parts: ``resident`` (the same every
    frame) and ``beside`` (the frame's), as attributes of the function (KeptMerge keeps and asks
    again only the second's questions)."""
    def resident(level, node_level, nodes):
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
        return (nodes @ np.array([7, 3, 1]) + level) % 2 == 0

    def beside(level, node_level, nodes):
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
        return (nodes @ np.array([1, 5, 3]) + node_level + frame // 3) % 3 == 0

    def cover(level, node_level, nodes):
        out = resident(level, node_level, nodes)
        out[~out] = beside(level, node_level, np.asarray(nodes).reshape(-1, 3)[~out])
        return out

    cover.resident, cover.beside = resident, beside
    return cover


@pytest.mark.parametrize("windows,cover", [pytest.param("grid", None, marks=pytest.mark.slow), ("grid", cover_some),
                                           ("small", cover_some),
                                           pytest.param("grid", cover_moving, marks=pytest.mark.slow),
                                           ("grid", cover_split)])
def test_the_kept_merge_is_the_merge_from_nothing_along_random_paths(windows, cover):
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    win = [PYR.grid(L) for L in range(PYR.num_levels)] if windows == "grid" else \
        [(3, 4, 4)] + [PYR.grid(L) for L in range(1, PYR.num_levels)]
    km = KeptMerge(PYR)
    rng = np.random.default_rng(3 + (cover is None) + 2 * (windows == "small") + 4 * (cover is cover_moving) + 8 * (cover is cover_split))
    partial = changed = upper = 0
    last = None
    for k, cam in enumerate(path(rng, 40, 2.0)):
        sel = kc.update(cam, ordered=False)
        ask = cover(k) if cover in (cover_moving, cover_split) else cover
        got = km.merge(sel.items, win, ask)
        want = merge_items(sel.items, PYR, win, (lambda *a: ask(*a)) if ask is not None else None)  # (plain)
        np.testing.assert_array_equal(got.rows, want.rows)
        np.testing.assert_array_equal(got.span, want.span)
        np.testing.assert_array_equal(got.lo, want.lo)
        np.testing.assert_array_equal(got.hi, want.hi)
        check_cover(sel.items, got, PYR, exact=cover is None)
        assert km.answers_hold(ask)
        upper += km.upper_kept
        if last is not None and last is not sel.items:
            changed += 1
            partial += km.remerged < len(sel.items)
        last = sel.items
    assert changed > 5 and partial > 3  # the cut changed, and changes re-merged only some cells
    assert upper > 3  # the upper passes' result was kept on frames whose cells' entries were the same


def test_new_windows_and_a_reset_merge_from_nothing():
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    km = KeptMerge(PYR)
    grid = [PYR.grid(L) for L in range(PYR.num_levels)]
    small = [(2, 2, 2)] + grid[1:]
    a = kc.update(camera(10, 20, 60), ordered=False)
    km.merge(a.items, grid)
    for win in (small, grid):  # the windows changed: every item merged again
        got = km.merge(a.items, win)
        assert km.remerged == len(a.items)
        np.testing.assert_array_equal(got.rows, merge_items(a.items, PYR, win).rows)
    km.merge(a.items, grid)
    assert km.remerged < len(a.items)  # the same leaves: only the coarse ones again
    km.reset()
    km.merge(a.items, grid)
    assert km.remerged == len(a.items)


def test_the_upper_passes_are_merged_again_when_only_their_answers_change():
    """The same items, the lower cells' answers the same, only the questions of the passes above
    the cells answered otherwise (a camera whose view moved off a coarse culled node): the upper
    merge is not kept, and the result is ``merge_items``'s for the new answers."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    win = [PYR.grid(L) for L in range(PYR.num_levels)]
    km = KeptMerge(PYR)

    def cover(upper_answer: bool):
        def ask(level, node_level, nodes):
            n = len(np.asarray(nodes).reshape(-1, 3))
            return np.full(n, True if node_level < km.cell_level else upper_answer)
        return ask

    differ = 0
    for deg in (10, 70, 130, 200):
        items = kc.update(camera(deg, 20, 90), ordered=False).items
        for answer in (True, False, True):
            got = km.merge(items, win, cover(answer))
            want = merge_items(items, PYR, win, cover(answer))
            np.testing.assert_array_equal(got.rows, want.rows)
            np.testing.assert_array_equal(got.span, want.span)
        differ += not np.array_equal(merge_items(items, PYR, win, cover(True)).rows,
                                     merge_items(items, PYR, win, cover(False)).rows)
    assert differ  # (else the upper questions decide nothing here)


def cover_camera(cam, boxed: bool):
    """The render action's ``may_cover`` in its parts for camera ``cam``: ``resident`` a fixed
    pattern (the texture memory's), ``beside`` whether the node's box, grown by one voxel of the
    level, lies wholly beside ``cam``'s view; with ``boxed`` also the camera-free ``boxes`` and the
    camera's ``beside_boxes`` (what lets ``KeptMerge.answers_hold`` keep the boxes)."""
    def resident(level, node_level, nodes):
        nodes = np.asarray(nodes, dtype=np.int64).reshape(-1, 3)
        return (nodes @ np.array([7, 3, 1]) + level) % 4 == 0

    def boxes(level, node_level, nodes):
        lo, hi = PYR.node_box(node_level, np.asarray(nodes, dtype=np.int64).reshape(-1, 3))
        pad = float(max(PYR.levels[level].scale))
        return lo - pad, hi + pad

    def beside(level, node_level, nodes):
        return cam.boxes_beside_view(*boxes(level, node_level, nodes))

    def cover(level, node_level, nodes):
        out = resident(level, node_level, nodes)
        out[~out] = beside(level, node_level, np.asarray(nodes).reshape(-1, 3)[~out])
        return out

    cover.resident, cover.beside = resident, beside
    if boxed:
        cover.boxes, cover.beside_boxes = boxes, cam.boxes_beside_view
    return cover


def test_answers_hold_over_kept_boxes_answers_as_each_question_asked_again():
    """``answers_hold`` with the boxes of the questions kept (one test of the next camera over all
    of them) answers as asking every question group of the last merge again (the plain split
    ``may_cover``), along a random path whose merges change the questions; where it says the
    answers hold, the merge from nothing under the next camera is the kept merge's result; the
    boxes a merge kept with the questions it kept are the nodes' boxes (``Pyramid.node_box``)."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    win = [PYR.grid(L) for L in range(PYR.num_levels)]
    km = KeptMerge(PYR)
    cams = list(path(np.random.default_rng(11), 40, 6.0))
    seen = set()
    kept_boxes = 0
    for k, (cam, nxt) in enumerate(zip(cams, cams[1:])):
        sel = kc.update(cam, ordered=False)
        got = km.merge(sel.items, win, cover_camera(cam, boxed=True))
        for L, n, nodes, _, _, box in km._asked:  # each question's kept box is its node's, grown by a voxel
            if box[0] is not None:
                lo, hi = PYR.node_box(n, nodes)
                pad = float(max(PYR.levels[L].scale))
                np.testing.assert_array_equal(box[0][0], lo - pad)
                np.testing.assert_array_equal(box[0][1], hi + pad)
                kept_boxes += 1
        for again in range(2):  # (the second: the kept boxes)
            hold = km.answers_hold(cover_camera(nxt, boxed=True))
            assert hold == km.answers_hold(cover_camera(nxt, boxed=False))
        seen.add(hold)
        if hold:
            want = merge_items(sel.items, PYR, win, cover_camera(nxt, boxed=False))
            np.testing.assert_array_equal(got.rows, want.rows)
            np.testing.assert_array_equal(got.span, want.span)
    assert seen == {True, False}  # (the path both keeps and changes the answers)
    assert kept_boxes > 10  # (merges kept the boxes of the questions they kept)


def leaf_cells(rows: np.ndarray, K: int) -> dict:
    """Per cell ``(z, y, x)`` of node level ``K``, the set of the rows' leaves below that level in it."""
    out: dict = {}
    for L, z, y, x in rows.tolist():
        if L < K:
            out.setdefault((z >> (K - L), y >> (K - L), x >> (K - L)), set()).add((L, z, y, x))
    return out


def test_the_changed_cells_are_those_whose_leaves_differ():
    """``KeptMerge._diff`` (compares only past the rows two cuts share at the front and the back)
    against a set of leaves per cell built row by row in Python: the cells whose sets differ, and
    each new row's cell, along a random path and for rows taken out at the front, the back, the
    middle and both ends of a cut."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    km = KeptMerge(PYR)
    K, grid = km.cell_level, tuple(PYR.grid(km.cell_level))

    def check(old: np.ndarray, new: np.ndarray) -> None:
        km._items = type("Rows", (), {"rows": old})()
        km._items_cells = km._cells(old)
        dirty, cells = km._diff(new)
        a, b = leaf_cells(old, K), leaf_cells(new, K)
        want = {c for c in a.keys() | b.keys() if a.get(c, set()) != b.get(c, set())}
        got = {tuple(int(v) for v in np.unravel_index(i, grid)) for i in np.nonzero(dirty)[0]}
        assert got == want
        ref = [int(np.ravel_multi_index((z >> (K - L), y >> (K - L), x >> (K - L)), grid)) if L < K else -1
               for L, z, y, x in new.tolist()]
        np.testing.assert_array_equal(cells, ref)

    changed = 0
    last = None
    for cam in path(np.random.default_rng(5), 30, 3.0):
        items = kc.update(cam, ordered=False).items
        if last is not None and last is not items:
            check(last.rows, items.rows)
            changed += 1
        last = items
    assert changed > 5
    rows = last.rows
    n = len(rows)
    assert n > 20
    for drop in ([0], [n - 1], [n // 2], [0, n - 1], [1, n // 3, n - 2], list(range(n // 4, n // 2))):
        check(rows, np.delete(rows, drop, axis=0))
        check(np.delete(rows, drop, axis=0), rows)
    check(rows, rows.copy())  # (no change: no cell)
