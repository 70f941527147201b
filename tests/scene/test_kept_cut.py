"""A projected-size cut kept between frames (clipvol.scene.selection.kept_cut) against what it
stands for: the cut a fresh ``select`` makes for the same camera, frame by frame along random camera
paths (small turns, where only a band of nodes is re-tested, and jumps), node for node, in the same
order, with the same counts and the same ideal cut in the same load order."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.camera import Camera
from clipvol.scene.geometry import Shape
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import merge_items, select
from clipvol.scene.selection.coherence import node_order
from clipvol.scene.selection.kept_cut import KeptCut
from clipvol.scene.selection.order import depth_first
from clipvol.scene.selection.policies import policy_for

PYR = Pyramid.build((96, 80, 112), (8, 8, 8))  # grids 12x10x14 .. 1: no virtual level above the top
PYR_V = Pyramid.build((64, 64, 64), (16, 16, 16)).with_levels(2)  # top grid 2^3: a virtual root above it
CENTRE = np.array([55.5, 39.5, 47.5])


def transparent(level, idx):
    """A ball of data in air, in brick units of the level (a numpy statement)."""
    idx = np.asarray(idx, dtype=np.float64).reshape(-1, 3)
    c = (idx + 0.5) * 8 * 2 ** level - CENTRE[::-1]
    return np.linalg.norm(c, axis=1) >= 40 + 4 * 2 ** level


def camera(deg, elev, dist, fov=35.0, shift=(0, 0, 0), size=(32, 32), pyr=PYR) -> Camera:
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    th, ph = np.radians(deg), np.radians(elev)
    d = np.array([np.sin(th) * np.cos(ph), np.sin(ph), np.cos(th) * np.cos(ph)])
    cam = Camera.perspective(tuple(c + d * dist), tuple(c + np.asarray(shift, dtype=float)), up=(0, 1, 0),
                             fov_y=fov, size=size)
    cam = cam.fit_depth(lo, hi)
    return cam.with_depth_range(min(cam.near, cam.far * 1e-7), cam.far)


def same(kept, fresh) -> None:
    assert kept is not None
    np.testing.assert_array_equal(kept.items.rows, fresh.items.rows)
    np.testing.assert_array_equal(kept.items.lo, fresh.items.lo)
    np.testing.assert_array_equal(kept.items.hi, fresh.items.hi)
    np.testing.assert_array_equal(kept.wanted.rows, fresh.wanted.rows)
    assert kept.counts == fresh.counts


def path(rng, n: int, step: float):
    """A random camera path: small turns, zooms and pans of up to ``step`` degrees, and jumps."""
    deg, elev, dist, shift = rng.uniform(0, 360), rng.uniform(-40, 40), rng.uniform(60, 200), rng.uniform(-10, 10, 3)
    for _ in range(n):
        if rng.random() < 0.1:  # anywhere
            deg, elev, dist = rng.uniform(0, 360), rng.uniform(-40, 40), rng.uniform(40, 220)
        else:
            deg += rng.uniform(-step, step)
            elev = float(np.clip(elev + rng.uniform(-step, step), -60, 60))
            dist *= 1 + rng.uniform(-step, step) / 100
            shift = shift + rng.uniform(-step, step, 3) / 4
        yield camera(deg, elev, dist, shift=shift)


CROP = Shape(box=((10, 5, 20), (70, 60, 90)), planes=[(1, 1, 0, -40)])


@pytest.mark.parametrize("threshold,shape", [(0.1, None), (0.25, None), (0.1, CROP)])
def test_the_kept_cut_is_a_fresh_selections_cut_along_random_paths(threshold, shape):
    params = RenderParams(policy="projected-size", lod_threshold=threshold, shape=shape)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    rng = np.random.default_rng(int(threshold * 100) + (shape is not None))
    partial = 0
    for cam in path(rng, 40, 2.0):
        same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
        partial += kc.retested < len(kc.lv)
    assert partial > 10  # most small moves re-tested only a band of the kept nodes


def test_nodes_no_longer_reached_are_dropped_and_grown_again(monkeypatch):
    from clipvol.scene.selection import kept_cut

    monkeypatch.setattr(kept_cut, "COMPACT_MIN", 0)
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    sizes = []
    for k, dist in enumerate([60, 200, 60, 220, 50, 200, 60]):  # near and far: nodes go and come back
        cam = camera(20 + k, 15, dist)
        same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
        sizes.append(len(kc.lv))
        assert np.all(kc.parent[1:] < np.arange(1, len(kc.lv))) and kc.parent[0] == -1
    assert any(b < a for a, b in zip(sizes, sizes[1:]))  # kept nodes were dropped (else they only grow)


def test_a_virtual_root_and_every_node_refined_to_level_0():
    params = RenderParams(policy="projected-size", lod_threshold=0.02)
    kc = KeptCut(PYR_V, params, policy_for(params))
    rng = np.random.default_rng(5)
    for k in range(12):
        cam = camera(30 + k * 3, 10, rng.uniform(50, 150), pyr=PYR_V)
        same(kc.update(cam), select(PYR_V, cam, params))


def test_an_unchanged_cut_comes_back_as_the_same_object_and_depth_first():
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    a = kc.update(camera(10, 20, 150), ordered=False)
    b = kc.update(camera(10.001, 20, 150), ordered=False)
    assert b is a and not a.ordered and kc.retested < len(kc.lv)
    fresh = select(PYR, camera(10.001, 20, 150), params, transparent=transparent)
    # the same nodes; depth-first order merges as the back-to-front order does, and node_order of
    # the merged boxes is the fresh order's merge
    assert sorted(map(tuple, a.items.rows.tolist())) == sorted(map(tuple, fresh.items.rows.tolist()))
    windows = [PYR.grid(L) for L in range(PYR.num_levels)]
    merged = merge_items(a.items, PYR, windows)
    want = merge_items(fresh.items, PYR, windows)
    cam = camera(10.001, 20, 150)
    assert [merged[i] for i in node_order(merged, PYR, cam)] == want


def test_depth_first_is_the_octree_order_with_octants_by_number():
    rng = np.random.default_rng(0)
    # a random cut of a 16^3 grid: refine each node with probability 1/2, children in octant order
    def walk(level, idx, out):
        if level == 0 or rng.random() < 0.4:
            out.append((level, *idx))
            return
        for o in range(8):
            walk(level - 1, (2 * idx[0] + (o >> 2), 2 * idx[1] + ((o >> 1) & 1), 2 * idx[2] + (o & 1)), out)
    nodes: list = []
    walk(4, (0, 0, 0), nodes)
    shuffled = rng.permutation(len(nodes))
    rows = np.array(nodes, dtype=np.int64)[shuffled]
    o = depth_first(rows[:, 0], rows[:, 1:])
    assert [tuple(r) for r in rows[o].tolist()] == nodes


def test_a_budgeted_or_fixed_cut_is_not_kept():
    for params in (RenderParams(policy="projected-size", max_texels_drawn=100 * 512),
                   RenderParams(policy="fixed", level=0)):
        kc = KeptCut(PYR, params, policy_for(params))
        assert not kc.supported and kc.update(camera(0, 0, 100)) is None


@pytest.mark.parametrize("threshold", [1.5, 3.0])
def test_the_kept_cut_evens_out_as_a_fresh_selection_does(threshold, monkeypatch):
    """The projected-size rule is evened out level by level (``ProjectedSize.even``): whether a node
    is refined depends on the others of its level, not only on its own depth. The kept cut tests the
    rule node by node in the band and evens out each level as it propagates; along random paths it
    is the fresh cut, on frames where evening out changed the cut too (counted against the rule
    without it)."""
    from clipvol.scene.selection.policies.projected_size import ProjectedSize

    params = RenderParams(policy="projected-size", lod_threshold=threshold)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    rng = np.random.default_rng(1)
    cams = list(path(rng, 30, 2.0))
    fresh = [select(PYR, cam, params, transparent=transparent) for cam in cams]
    for cam, f in zip(cams, fresh):
        same(kc.update(cam), f)
    monkeypatch.setattr(ProjectedSize, "even", lambda self, t, level, lo, need: need)
    raw = [select(PYR, cam, params, transparent=transparent) for cam in cams]
    evened = sum(not np.array_equal(a.items.rows, b.items.rows) for a, b in zip(fresh, raw))
    assert evened >= 3, evened  # else this tests nothing the other test does not


def test_the_same_leaves_come_back_as_the_same_items_with_fresh_counts():
    """A small move that flips band answers but no leaf: a new selection (the counts of the fresh
    selection) holding the very same items object, so what the renderer made of the items (merge,
    page table, GPU check) is kept; a move that changes a leaf gives new items."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    last, kept, new = None, 0, 0
    for k in range(60):
        cam = camera(10 + 0.05 * k, 20, 150 - 1.5 * k)
        sel = kc.update(cam, ordered=False)
        fresh = select(PYR, cam, params, transparent=transparent)
        assert sel.counts == fresh.counts
        leaves = sorted(map(tuple, fresh.items.rows.tolist()))
        assert sorted(map(tuple, sel.items.rows.tolist())) == leaves
        if last is not None:
            if leaves == last[0]:
                assert sel.items is last[1].items and sel.wanted is last[1].wanted
                kept += sel is not last[1]  # (a new selection: some answer flipped)
            else:
                assert sel.items is not last[1].items
                new += 1
        last = (leaves, sel)
    assert kept > 3 and new > 3, (kept, new)  # (both kinds of move happened)


def test_transparent_level0_nodes_are_counted_not_re_tested_and_counts_keep_their_camera():
    """A transparent level-0 node's frustum answer only feeds the counts: the band leaves it out, so a
    move that carries only such nodes across a frustum plane gives back the same selection object,
    its counts (``KeptCounts``, completed when read) the fresh selection's for the new camera; and
    each frame's counts, read only after the whole path (nodes reached and dropped since), are still
    the fresh selection's of that frame's camera."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    rng = np.random.default_rng(11)
    held, fresh_counts, last, last_counts, same_obj_new_counts = [], [], None, None, 0
    cams = [camera(10 + 0.2 * k, 20, 90 + 0.3 * k) for k in range(40)] + list(path(rng, 30, 2.0))
    for cam in cams:
        sel = kc.update(cam, ordered=False)
        fresh = select(PYR, cam, params, transparent=transparent)
        held.append(sel.counts.copy())  # what FrameStats keeps: not read yet
        fresh_counts.append(dict(fresh.counts))
        if sel is last and fresh.counts != last_counts:
            same_obj_new_counts += 1  # only transparent level-0 nodes crossed a plane
        last, last_counts = sel, dict(fresh.counts)
        assert np.all(kc._band.deadline(np.flatnonzero(kc.mute)) == np.inf)  # never in a band
    assert same_obj_new_counts >= 3, same_obj_new_counts
    for got, want in zip(held, fresh_counts):
        assert dict(got) == want


def test_the_propagation_kept_between_frames_is_the_full_propagation_along_random_paths():
    """``KeptCut._propagate`` sets again only the levels from the coarsest one whose answers flipped
    down, and level 0 only under the level-1 nodes whose answer changed: along random paths (turns,
    zooms, jumps, nodes grown and dropped) its ``reached`` and ``eff`` arrays equal a propagation
    over every level and row from nothing on the same nodes and answers."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    rng = np.random.default_rng(11)
    partial = 0
    for cam in path(rng, 60, 1.0):
        kc.update(cam, ordered=False)
        full = KeptCut(PYR, params, policy_for(params), transparent=transparent)
        for name in ("lv", "idx", "lo", "hi", "parent", "infr", "inside", "ref"):
            setattr(full, name, getattr(kc, name).copy())
        full.reached = np.zeros(len(kc.lv), dtype=bool)  # (nothing carried over)
        full.eff = np.zeros(len(kc.lv), dtype=bool)
        full._propagate()
        np.testing.assert_array_equal(kc.reached, full.reached)
        np.testing.assert_array_equal(kc.eff, full.eff)
        partial += kc.retested < len(kc.lv)
    assert partial > 20


def test_a_motion_bands_deadlines_are_the_summed_per_frame_bounds():
    """``MotionBand`` against the sum it stands for, accumulated row by row in plain numpy: after
    each frame, a row is due exactly when the per-frame bounds ``turn * reach + shift`` summed
    since its deadline was set reach its slack (in some channel), rows set again mid-way counting
    from then; rows grown later join, and a compaction keeps the rest's deadlines."""
    from clipvol.scene.selection.band import MotionBand

    rng = np.random.default_rng(3)
    band = MotionBand(3)
    reach = rng.uniform(0, 50, 400)
    band.grow(reach)
    slack = rng.uniform(0, 30, (400, 3))
    slack[rng.random((400, 3)) < 0.1] = np.inf  # (never due through that channel)
    band.set(np.arange(400), slack)
    moved = np.zeros((400, 3))  # the bound summed since each row's slack was measured
    for frame in range(60):
        turn, shift = rng.uniform(0, 0.05, 3), rng.uniform(0, 0.5, 3) * (rng.random(3) < 0.5)
        got = band.advance(turn, shift)
        moved += reach[:, None] * turn[None] + shift[None]
        want = np.any(moved >= slack, axis=1)
        clear = np.all(np.abs(moved - slack) > 1e-9, axis=1) | np.isinf(slack).all(axis=1)  # (no rounding tie)
        np.testing.assert_array_equal(np.isin(np.arange(len(reach)), got)[clear], want[clear])
        again = np.union1d(got, rng.choice(len(reach), 20, replace=False))  # (tested again: the kept cut's band)
        slack[again] = rng.uniform(0, 30, (len(again), 3))
        moved[again] = 0.0
        band.set(again, slack[again])
        if frame == 20:  # new rows, due until set
            new = rng.uniform(0, 50, 50)
            band.grow(new)
            assert set(band.advance(np.zeros(3), np.zeros(3)).tolist()) >= set(range(400, 450))
            reach = np.concatenate([reach, new])
            slack = np.concatenate([slack, rng.uniform(0, 30, (50, 3))])
            moved = np.concatenate([moved, np.zeros((50, 3))])
            band.set(np.arange(400, 450), slack[400:])
        if frame == 40:  # a compaction: the kept rows' deadlines renumbered with them
            keep = rng.random(len(reach)) < 0.7
            band.take(keep)
            reach, slack, moved = reach[keep], slack[keep], moved[keep]


def test_a_motion_bands_pass_lists_only_rows_that_can_be_due(monkeypatch):
    """``MotionBand`` passes over a list of the rows with a finite deadline: rows whose deadlines
    are all infinite (a kept cut's transparent level-0 nodes) leave the list when it is made
    again (every ``RELIST`` frames, or after much growth), and rows given a finite deadline later
    join it (appended out of row order). Frame by frame, against the per-frame bounds summed row
    by row in plain numpy, a row is due exactly when its sum reaches its slack, and after a
    listing the list holds exactly the rows with a finite deadline."""
    from clipvol.scene.selection import band as band_mod
    from clipvol.scene.selection.band import MotionBand

    monkeypatch.setattr(band_mod, "RELIST", 7)
    rng = np.random.default_rng(8)
    n = 600
    band = MotionBand(3)
    reach = rng.uniform(0, 50, n)
    band.grow(reach)
    slack = rng.uniform(0, 30, (n, 3))
    slack[rng.random(n) < 0.5] = np.inf  # (half the rows never due)
    band.set(np.arange(n), slack)
    moved = np.zeros((n, 3))
    listed_all_finite = 0
    for frame in range(40):
        turn, shift = rng.uniform(0, 0.05, 3), rng.uniform(0, 0.5, 3) * (rng.random(3) < 0.5)
        got = band.advance(turn, shift)
        assert np.all(np.diff(got) > 0)  # (sorted rows, each once)
        moved += reach[:, None] * turn[None] + shift[None]
        want = np.any(moved >= slack, axis=1)
        clear = np.all(np.abs(moved - slack) > 1e-9, axis=1) | np.isinf(slack).all(axis=1)
        np.testing.assert_array_equal(np.isin(np.arange(n), got)[clear], want[clear])
        if band._age == 0:  # (listed anew this frame: exactly the rows that can be due)
            finite = np.flatnonzero(np.any(np.isfinite(slack), axis=1))
            np.testing.assert_array_equal(np.sort(band.listed), finite)
            listed_all_finite += 1
        again = np.union1d(got, rng.choice(n, 30, replace=False))
        slack[again] = rng.uniform(0, 30, (len(again), 3))
        slack[again[rng.random(len(again)) < 0.5]] = np.inf  # (some rows leave the band, some come back)
        moved[again] = 0.0
        band.set(again, slack[again])
    assert listed_all_finite >= 4, listed_all_finite


def test_the_band_holds_every_node_whose_answer_changed_along_a_path_that_turns_back():
    """Every kept node whose frustum or refine answer for the new camera differs from the one it
    holds is re-tested (in the band: its deadline in accumulated motion passed), frame by frame
    along a camera swinging back and forth and drifting (the sum of per-frame bounds grows while
    the camera returns), checked against each node tested afresh with the traversal's own tests;
    and the cut stays the fresh selection's."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    got: list = []
    test = KeptCut._test

    def recorded(self, rows, camera, ask_all=False):  # (the band: the rows re-tested)
        got.append(rows)
        return test(self, rows, camera, ask_all)

    KeptCut._test = recorded
    try:
        flips = 0
        for k in range(80):
            cam = camera(30 + 6 * np.sin(k / 3.0), 15 + 0.1 * k, 120 - 0.4 * k)
            n0 = len(kc.lv)
            held = (kc.infr[:n0].copy(), kc.ref[:n0].copy(), kc.mute[:n0].copy())
            lo, hi, lv = kc.lo[:n0].copy(), kc.hi[:n0].copy(), kc.lv[:n0].copy()
            got.clear()
            kc.update(cam, ordered=False)
            if k == 0:
                continue
            infr = np.asarray(cam.boxes_in_frustum(lo, hi), dtype=bool)
            t = kc._t
            ref = np.zeros(n0, dtype=bool)
            for L in np.unique(lv).tolist():
                m = lv == L
                ref[m] = L > kc.tree.top if L > kc.tree.top else \
                    (kc.policy.need(t, L, lo[m], hi[m]) if L > 0 else False)
            changed = ((infr != held[0]) | (ref != held[1])) & ~held[2]
            flips += int(changed.sum())
            assert set(np.flatnonzero(changed).tolist()) <= set(got[0].tolist()), k
            same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
    finally:
        KeptCut._test = test
    assert flips > 20, flips  # (the path moved answers)


def test_a_refine_answer_is_the_side_of_the_depth_limit_and_the_rule_is_asked_near_it(monkeypatch):
    """A re-tested node's refine answer is the side of its level's depth limit (``depth_threshold``)
    its nearest depth lies on, and beyond the eye plane its farthest; ``ProjectedSize.need`` is
    asked only of the nodes within rounding of their limit (and of new nodes). Along random paths
    (turns, zooms, an eye inside the volume: boxes behind the eye plane and straddling it), every
    node's held answer is the rule's for that frame's camera (the rule asked of every kept node
    afresh, in plain calls), the rule is asked of far fewer nodes than are re-tested, and the cut
    is the fresh selection's."""
    from clipvol.scene.selection.policies.projected_size import ProjectedSize

    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    asked = []
    need = ProjectedSize.need

    def counted(self, t, level, lo, hi):
        asked.append(len(lo))
        return need(self, t, level, lo, hi)

    monkeypatch.setattr(ProjectedSize, "need", counted)
    rng = np.random.default_rng(7)
    cams = list(path(rng, 50, 2.0)) + [camera(40 + k, 10, 30 + 2 * k) for k in range(15)]  # (eye inside)
    n_asked = n_tested = 0
    for k, cam in enumerate(cams):
        asked.clear()
        sel = kc.update(cam)
        if k:
            n_asked, n_tested = n_asked + sum(asked), n_tested + kc.retested
        same(sel, select(PYR, cam, params, transparent=transparent))
        asked.clear()
        real = np.flatnonzero((kc.lv > 0) & (kc.lv <= kc.tree.top) & ~kc.mute)
        for L in np.unique(kc.lv[real]).tolist():
            r = real[kc.lv[real] == L]
            np.testing.assert_array_equal(kc.ref[r], need(kc.policy, kc._t, L, kc.lo[r], kc.hi[r]))
    assert n_asked < n_tested // 2, (n_asked, n_tested)


@pytest.mark.parametrize("threshold", [0.5, 1.5])
def test_a_level_evened_whole_as_the_camera_nears_and_leaves(threshold):
    """``ProjectedSize.even`` evens a level as one group once enough of it refines: a slow zoom in
    and out carries levels across that count, and the kept cut - which evens again only the
    sibling groups a flip touched, and the whole level where the level's count crosses - is the
    fresh selection's on every frame; the whole-level evening flipped on some of them."""
    params = RenderParams(policy="projected-size", lod_threshold=threshold)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    dists = np.r_[np.linspace(230, 45, 30), np.linspace(45, 230, 30)]
    flags, flipped = None, 0
    for k, dist in enumerate(dists):
        cam = camera(25 + 0.3 * k, 20, dist)
        same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
        now = [bool(kc.policy.evens(*kc._lvl[L])) for L in range(1, kc.tree.top + 1)]
        flipped += flags is not None and now != flags
        flags = now
    assert flipped >= 2, flipped


def test_another_lens_or_image_size_tests_every_node_again():
    """A camera of another lens or image size moves every depth limit: every kept node is due
    at once (``MotionBand.everything``), and the cut is the fresh selection's across the changes."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    for k, (fov, size) in enumerate([(35, (32, 32)), (35, (32, 32)), (20, (32, 32)), (20, (64, 48)),
                                     (50, (64, 48)), (50, (64, 48))]):
        cam = camera(40 + 0.5 * k, 10, 120, fov=fov, size=size)
        n0 = len(kc.lv)
        same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
        if k in (2, 3, 4):  # (a slack of the old lens says nothing: none may defer a node)
            assert kc.retested == n0, (k, kc.retested, n0)
        elif k == 5:
            assert kc.retested < n0 // 4


def test_after_another_lens_small_moves_use_its_depth_limits():
    """The depth limits are kept per lens (a node's refine answer is the side of its limit): after
    a change of field of view and image size, a slow zoom under the new lens - where most nodes
    are not asked again, their answers following their limits - gives the fresh selection's cut
    and, node for node, the rule's answers (``ProjectedSize.need`` asked afresh) on every frame."""
    params = RenderParams(policy="projected-size", lod_threshold=2.0)  # (limits within the camera's reach)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    lenses = [(35, (32, 32))] * 12 + [(20, (64, 48))] * 25
    flips = 0
    for k, (fov, size) in enumerate(lenses):
        cam = camera(40 + 0.3 * k, 10, 160 - 3.0 * k, fov=fov, size=size)
        held = kc.ref.copy()
        same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
        real = np.flatnonzero((kc.lv > 0) & (kc.lv <= kc.tree.top) & ~kc.mute)
        for L in np.unique(kc.lv[real]).tolist():
            r = real[kc.lv[real] == L]
            np.testing.assert_array_equal(kc.ref[r], kc.policy.need(kc._t, L, kc.lo[r], kc.hi[r]), err_msg=str(k))
        flips += k > 12 and int(np.count_nonzero(kc.ref[:len(held)] != held))
    assert flips > 10, flips  # (answers moved under the new lens's limits)


def test_runs_are_each_nodes_child_rows_concatenated():
    """``_runs`` (a node's children are one run of rows) against a list built row by row, with
    equal counts (its broadcast path) and mixed ones, zeros included."""
    from clipvol.scene.selection.kept_cut import _runs

    rng = np.random.default_rng(3)
    for counts in ([8, 8, 8], [8], [4, 8, 0, 2], [0, 0], [3, 3, 1]):
        first = rng.integers(0, 1000, len(counts))
        want = [f + k for f, c in zip(first.tolist(), counts) for k in range(c)]
        np.testing.assert_array_equal(_runs(first, np.array(counts, dtype=np.int64)), np.array(want, dtype=np.int64))


@pytest.mark.parametrize("shape", [None, CROP])
def test_flips_that_move_nothing_are_left_out_and_the_cut_stays_selects(shape, monkeypatch):
    """A flipped level-0 node, and one live (reached, in the frustum, inside the shape) neither
    before nor after its flip, is left out of the propagation: along random paths such flips
    happen (counted here from the arrays, apart from the kept cut's filter) and the cut stays a
    fresh ``select``'s. Fails when a seed that becomes live is left out too."""
    params = RenderParams(policy="projected-size", lod_threshold=0.1, shape=shape)
    kc = KeptCut(PYR, params, policy_for(params), transparent=transparent)
    spread, idle = KeptCut._spread, []

    def counted(self, seeds, flips=False):
        if flips:
            live = self.reached[seeds] & self.infr[seeds] & self.inside[seeds]
            idle.append(int(np.count_nonzero((self.lv[seeds] == 0) | (~self.live[seeds] & ~live))))
        return spread(self, seeds, flips)

    monkeypatch.setattr(KeptCut, "_spread", counted)
    rng = np.random.default_rng(21 + (shape is not None))
    for cam in path(rng, 40, 2.0):
        same(kc.update(cam), select(PYR, cam, params, transparent=transparent))
    assert sum(idle) > 0  # (the shortcut was taken)
