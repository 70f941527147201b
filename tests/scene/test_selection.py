"""LOD selection: culling, refinement, residency fallback, budgets, modes and exact visibility order.

References are independent of the code under test: order is checked by casting every pixel's ray
through the drawn boxes; coverage by counting, for random points, how many drawn boxes hold them;
the LOD rule by recomputing projected voxel sizes from box corners.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.camera import Camera
from clipvol.scene.geometry import Shape
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import DrawItem, back_to_front, merge_items, select


# -- brute-force visibility check ---------------------------------------------------------------
def ray_intervals(cam, lo, hi):
    """Entry/exit distances ``(R, n)`` of every pixel ray of ``cam`` through every box (inf/-inf: miss)."""
    o, d = cam.rays()
    o, d = o.reshape(-1, 3)[:, None, :], d.reshape(-1, 3)[:, None, :]
    lo, hi = np.asarray(lo)[None], np.asarray(hi)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    zero = d == 0
    inside = (o > lo) & (o < hi)
    tmin = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    tmax = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    t0, t1 = tmin.max(axis=2), tmax.min(axis=2)
    if not cam.orthographic:
        t0 = np.maximum(t0, 0.0)
    return t0, t1


def order_violations(cam, lo, hi, eps=1e-7):
    """Number of rays along which the draw order (row order of ``lo``/``hi``) is not back to front.

    Along every ray the boxes it passes through (with a non-degenerate interval) must appear in
    decreasing draw position as the entry distance grows: the nearer box is drawn later.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    t0, t1 = ray_intervals(cam, lo, hi)
    scale = max(1.0, float(np.abs(hi - lo).max()))
    hit = (t1 - t0) > eps * scale
    key = np.where(hit, t0, np.inf)
    srt = np.argsort(key, axis=1, kind="stable")
    pos = np.broadcast_to(np.arange(lo.shape[0]), key.shape)
    pos_sorted = np.take_along_axis(pos, srt, axis=1)
    valid = np.take_along_axis(hit, srt, axis=1)
    pair = valid[:, 1:] & valid[:, :-1]
    bad = pair & (np.diff(pos_sorted, axis=1) > 0)
    return int(bad.any(axis=1).sum()), int(hit.any(axis=1).sum())


# -- helpers -------------------------------------------------------------------------------------

PYR = Pyramid.build((64, 64, 64), (8, 8, 8))  # grids 8, 4, 2, 1
CENTRE = (31.5, 31.5, 31.5)


def cam_at(eye, target=CENTRE, size=(48, 48), fov=60.0, pyr=PYR, up=(0, 1, 0)):
    if tuple(eye) == tuple(target):
        target = (40.0, 35.0, 100.0)
    return Camera.perspective(eye, target, up=up, fov_y=fov, size=size).fit_depth(*pyr.volume_box())


def boxes(items):
    return np.array([i.lo for i in items]).reshape(-1, 3), np.array([i.hi for i in items]).reshape(-1, 3)


def coverage(items, pts):
    lo, hi = boxes(items)
    return ((pts[:, None] > lo[None]) & (pts[:, None] < hi[None])).all(axis=2).sum(axis=1)


def visible_points(cam, pyr, n=3000, seed=0, shape=None):
    """Random points inside the volume and the frustum (clip-space test via view_projection)."""
    rng = np.random.default_rng(seed)
    vlo, vhi = pyr.volume_box()
    pts = rng.uniform(vlo, vhi, size=(n, 3))
    h = np.concatenate([pts, np.ones((n, 1))], axis=1) @ cam.view_projection().T
    inside = np.all(np.abs(h[:, :3]) < h[:, 3:], axis=1) & (h[:, 3] > 0)
    if shape is not None:
        inside &= shape.contains(pts)
    return pts[inside]


def px_size(cam, lo, hi, length):
    """Independent projected size: voxel length over the box's smallest corner depth."""
    corners = np.array([[a[0], b[1], c[2]] for a in (lo, hi) for b in (lo, hi) for c in (lo, hi)])
    depth = ((corners - cam.eye) @ cam.forward).min()
    if depth <= 0:
        return math.inf
    return length * cam.size[1] / (2 * math.tan(math.radians(cam.fov_y) / 2) * depth)


class FakeResidency:
    """Windows ``[start, stop)`` per level and a set of missing (not yet loaded) bricks."""

    def __init__(self, pyr, windows=None, missing=()):
        self.pyr, self.windows, self.missing = pyr, windows or {}, set(missing)
        self.calls = 0

    def in_window_mask(self, level, idx):
        self.calls += 1
        idx = np.asarray(idx).reshape(-1, 3)
        if level not in self.windows:
            return np.ones(len(idx), dtype=bool)
        a, b = (np.asarray(v) for v in self.windows[level])
        return np.all((idx >= a) & (idx < b), axis=1)

    def resident_mask(self, level, idx):
        idx = np.asarray(idx).reshape(-1, 3)
        win = self.in_window_mask(level, idx)
        return win & np.array([(level, tuple(int(v) for v in r)) not in self.missing for r in idx], dtype=bool)


EYES = [(-20, 10, -30), (10, -30, 15), (5, 5, 5), (70, 70, -5), (20.3, 17.9, 33.1), CENTRE]


@pytest.mark.parametrize("eye", EYES)
def test_order_is_back_to_front_and_cut_covers_the_view_once(eye):
    cam = cam_at(eye)
    sel = select(PYR, cam, RenderParams(lod_threshold=3))
    lo, hi = boxes(sel.items)
    bad, hit = order_violations(cam, lo, hi)
    assert bad == 0 and hit > 0
    pts = visible_points(cam, PYR)
    np.testing.assert_array_equal(coverage(sel.items, pts), 1)
    assert all(i.lo == tuple(map(float, PYR.node_box(i.level, i.index)[0])) for i in sel.items)


def test_centre_distance_sorting_fails_where_our_order_holds():
    # a mixed-level cut seen from the side: sorting by centre distance draws boxes in the wrong order
    cam = cam_at((10, -30, 15))
    sel = select(PYR, cam, RenderParams(lod_threshold=3))
    lo, hi = boxes(sel.items)
    assert len({i.level for i in sel.items}) > 1
    dist = np.linalg.norm((lo + hi) / 2 - cam.eye, axis=1)
    by_centre = np.argsort(-dist, kind="stable")
    assert order_violations(cam, lo[by_centre], hi[by_centre])[0] > 0
    assert order_violations(cam, lo, hi)[0] == 0
    assert order_violations(cam, lo[::-1], hi[::-1])[0] > 0  # the check does see a wrong order


@pytest.mark.parametrize(
    "cam",
    [
        Camera.orthographic(CENTRE, (0, 0, 1), (0, -1, 0), 70, 70, size=(40, 40)),
        Camera.orthographic(CENTRE, (1, 1, 1), (0, 1, 0), 90, 90, size=(40, 40)),
        Camera.orthographic(CENTRE, (-1, 0, 0), (0, 0, 1), 30, 30, size=(40, 40)),
        cam_at((31.5, 31.5, -40)),  # on the axis through every split plane
        cam_at((-40, -40, -40)),  # exactly on the diagonal
        cam_at(CENTRE, target=(31.5, 31.5, 100)),  # eye on three split planes, looking along +z
    ],
)
def test_order_with_ties_on_axes_and_diagonals(cam):
    sel = select(PYR, cam, RenderParams(policy="fixed", level=0))
    mixed = select(PYR, cam, RenderParams(lod_threshold=2.5))
    for s in (sel, mixed):
        lo, hi = boxes(s.items)
        assert order_violations(cam, lo, hi)[0] == 0


def test_back_to_front_on_a_hand_made_mixed_cut():
    # level-2 node (0,0,0) split down: its child (1,(1,1,1)) split into level 0, the rest kept
    nodes = [(1, c) for c in PYR.children(2, (0, 0, 0)) if c != (1, 1, 1)]
    nodes += [(0, c) for c in PYR.children(1, (1, 1, 1))]
    nodes += [(2, c) for c in PYR.children(3, (0, 0, 0)) if c != (0, 0, 0)]
    lv = np.array([n[0] for n in nodes])
    idx = np.array([n[1] for n in nodes])
    for eye in [(12, 13, 14), (100, -50, 20), (15.5, 15.5, 15.5), (-5, 70, 30)]:
        cam = cam_at(eye)
        order = back_to_front(PYR, cam, lv, idx)
        assert sorted(order.tolist()) == list(range(len(nodes)))
        lo = np.array([PYR.node_box(int(a), b)[0] for a, b in zip(lv[order], idx[order])])
        hi = np.array([PYR.node_box(int(a), b)[1] for a, b in zip(lv[order], idx[order])])
        assert order_violations(cam, lo, hi)[0] == 0


@pytest.mark.parametrize("eye", [(-20, 10, -30), (5, 5, 5)])
def test_lod_rule_and_refinement_falls_with_threshold(eye):
    cam = cam_at(eye, size=(64, 64))
    counts = []
    for thr in (16, 8, 4, 2, 1):
        sel = select(PYR, cam, RenderParams(lod_threshold=thr))
        counts.append(len(sel.items))
        parents = {(it.level + 1, tuple(i // 2 for i in it.index)) for it in sel.items if it.level < PYR.num_levels - 1}
        # a level is evened out (tests/scene/test_even_out.py) only where some node of it needed refining
        needed = {lv for lv, b in parents if px_size(cam, *PYR.node_box(lv, b), max(PYR.levels[lv].scale)) > thr}
        for it in sel.items:
            vox = max(PYR.levels[it.level].scale)
            if it.level > 0:
                assert px_size(cam, np.array(it.lo), np.array(it.hi), vox) <= thr * (1 + 1e-9)
            if it.level < PYR.num_levels - 1:
                plo, phi = PYR.node_box(it.level + 1, tuple(i // 2 for i in it.index))
                assert px_size(cam, plo, phi, max(PYR.levels[it.level + 1].scale)) > thr or it.level + 1 in needed
    assert counts == sorted(counts) and counts[-1] > counts[0]


def test_frustum_culling():
    cam = cam_at((-10, -10, -10), target=(0, 0, 0), fov=20)
    sel = select(PYR, cam, RenderParams(lod_threshold=2))
    assert sel.counts["culled_frustum"] > 0
    lo, hi = boxes(sel.items)
    # no drawn box lies wholly outside a frustum plane (checked on its 8 corners), and the
    # visible points are all covered once
    p = cam.frustum_planes()
    corners = np.stack([np.stack([np.where(m[0], hi[:, 0], lo[:, 0]), np.where(m[1], hi[:, 1], lo[:, 1]),
                                  np.where(m[2], hi[:, 2], lo[:, 2])], axis=1) for m in np.ndindex(2, 2, 2)], axis=1)
    assert np.all(np.max(corners @ p[:, :3].T + p[:, 3], axis=1) >= -1e-9)
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, PYR)), 1)
    assert len(sel.items) < PYR.num_bricks(0)


def test_shape_culling():
    shape = Shape(box=((0, 0, 0), (20, 20, 60)), planes=[(1, 1, 0, -10)])
    cam = cam_at((-20, 10, -30))
    sel = select(PYR, cam, RenderParams(lod_threshold=2, shape=shape))
    full = select(PYR, cam, RenderParams(lod_threshold=2))
    assert sel.counts["culled_shape"] > 0 and len(sel.items) < len(full.items)
    lo, hi = boxes(sel.items)
    assert not shape.boxes_outside(lo, hi).any()
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, PYR, shape=shape)), 1)


def test_transparent_bricks_are_neither_drawn_nor_wanted():
    def transparent(level, idx):
        return (level <= 1) & (np.asarray(idx).sum(axis=1) % 2 == 0)

    cam = cam_at((-20, 10, -30))
    full = select(PYR, cam, RenderParams(lod_threshold=3))
    sel = select(PYR, cam, RenderParams(lod_threshold=3), transparent=transparent)
    key = lambda it: (it.level, it.index)  # noqa: E731
    expect = [key(i) for i in full.items if not (i.level <= 1 and sum(i.index) % 2 == 0)]
    assert sorted(map(key, sel.items)) == sorted(expect)
    assert sel.counts["culled_transparent"] > 0
    assert all(not (lv <= 1 and sum(b) % 2 == 0) for lv, b in sel.wanted)


def _window_around(pyr, point, w):
    win = {}
    for lv in range(pyr.num_levels):
        g = np.array(pyr.grid(lv))
        if np.all(g <= w):
            continue
        c = np.array(pyr.world_to_brick(lv, point))
        start = np.clip(c - w // 2, 0, g - w)
        win[lv] = (start, start + w)
    return win


@pytest.mark.parametrize("seed", range(3))
def test_fallback_to_nearest_resident_ancestor_without_holes_or_overlaps(seed):
    rng = np.random.default_rng(seed)
    cam = cam_at(EYES[seed])
    missing = {(lv, b) for lv in range(PYR.num_levels - 1) for b in np.ndindex(PYR.grid(lv)) if rng.uniform() < 0.35}
    res = FakeResidency(PYR, _window_around(PYR, (20, 20, 20), 4), missing)
    sel = select(PYR, cam, RenderParams(lod_threshold=2), residency=res)
    ideal = select(PYR, cam, RenderParams(lod_threshold=2), residency=FakeResidency(PYR, res.windows))
    assert sel.counts["fallback"] > 0
    # coverage identical to the all-resident cut, each point exactly once
    pts = visible_points(cam, PYR, seed=seed)
    np.testing.assert_array_equal(coverage(sel.items, pts), 1)
    np.testing.assert_array_equal(coverage(ideal.items, pts), 1)
    vol = lambda items: float(np.prod(boxes(items)[1] - boxes(items)[0], axis=1).sum())  # noqa: E731
    assert vol(sel.items) == pytest.approx(vol(ideal.items), rel=1e-12)
    for it in sel.items:
        idx = np.array([it.index])
        assert res.resident_mask(it.level, idx)[0]
        nlo, nhi = PYR.node_box(it.level, it.index)
        assert np.all(np.array(it.lo) >= nlo) and np.all(np.array(it.hi) <= nhi)
        # nothing finer that covers the item is resident: the ancestor is the nearest one
        mid = (np.array(it.lo) + np.array(it.hi)) / 2
        for lv in range(it.level):
            b = PYR.world_to_brick(lv, mid)
            blo, bhi = PYR.node_box(lv, b)
            if np.all(blo <= np.array(it.lo)) and np.all(bhi >= np.array(it.hi)):
                assert not res.resident_mask(lv, np.array([b]))[0]
    # wanted is the ideal cut, inside the windows, and does not depend on residency
    assert sorted(sel.wanted) == sorted(ideal.wanted)
    for lv, b in sel.wanted:
        assert res.in_window_mask(lv, np.array([b]))[0]
    lo, hi = boxes(sel.items)
    assert order_violations(cam, lo, hi)[0] == 0


@pytest.mark.parametrize("seed", range(3))
def test_selection_arrays_agree_with_its_items_and_sets(seed):
    """select() hands its items over as arrays (DrawItems): the arrays, the DrawItem objects made
    from them, the key arrays and the convergence answers all say the same as plain Python sets
    over the items and the wanted list."""
    from clipvol.scene.selection import DrawItems, Selection

    rng = np.random.default_rng(seed)
    cam = cam_at(EYES[seed])
    missing = {(lv, b) for lv in range(PYR.num_levels - 1) for b in np.ndindex(PYR.grid(lv)) if rng.uniform() < 0.35}
    sel = select(PYR, cam, RenderParams(lod_threshold=2),
                 residency=FakeResidency(PYR, _window_around(PYR, (20, 20, 20), 4), missing))
    assert isinstance(sel.items, DrawItems) and len(sel.items) > 20
    items = list(sel.items)
    assert all(isinstance(it, DrawItem) for it in items) and sel.items == items
    assert [tuple(r) for r in sel.item_keys().tolist()] == [(it.level, *it.index) for it in items]
    np.testing.assert_array_equal(sel.items.lo, [it.lo for it in items])
    assert [(L, tuple(i)) for L, i in ((r[0], r[1:]) for r in sel.wanted_keys().tolist())] == sel.wanted
    drawn = {(it.level, tuple(it.index)) for it in items}
    want_missing = [(L, tuple(i)) for L, i in sel.wanted if (L, tuple(i)) not in drawn]
    assert want_missing and sel.missing_wanted() == want_missing and not sel.is_converged()
    # a Selection built from a plain list answers alike
    plain = Selection(items, sel.wanted, dict(sel.counts))
    assert plain.missing_wanted() == want_missing and not plain.is_converged()
    done = Selection(items, [w for w in sel.wanted if w not in want_missing])
    assert done.is_converged() and done.missing_wanted() == []
    # the merge reads the arrays or the list, and returns the same boxes
    wins = [tuple(min(g, 4) for g in PYR.grid(L)) for L in range(PYR.num_levels)]
    full = select(PYR, cam, RenderParams(lod_threshold=2))
    merged = merge_items(full.items, PYR, wins, cover_all)
    assert merged == merge_items(list(full.items), PYR, wins, cover_all) and len(merged) < len(full.items)


def test_nothing_resident_draws_nothing_and_window_limits_refinement():
    cam = cam_at((-20, 10, -30))
    none = FakeResidency(PYR, missing={(lv, b) for lv in range(PYR.num_levels) for b in np.ndindex(PYR.grid(lv))})
    sel = select(PYR, cam, RenderParams(lod_threshold=1), residency=none)
    assert sel.items == [] and len(sel.wanted) > 0 and sel.counts["missing"] > 0
    # windows of 2 bricks: finer children outside the window are drawn from their parent
    res = FakeResidency(PYR, _window_around(PYR, (0, 0, 0), 2))
    sel = select(PYR, cam, RenderParams(lod_threshold=0.5), residency=res)
    assert sel.counts["outside_window"] > 0
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, PYR)), 1)
    for it in sel.items:
        assert res.in_window_mask(it.level, np.array([it.index]))[0]


@pytest.mark.parametrize("budget_bricks", [1, 5, 20, 60, 200])
def test_texel_budget_holds_and_coverage_stays_complete(budget_bricks):
    cam = cam_at((5, 5, 5))
    texels = int(np.prod(PYR.brick_shape))
    sel = select(PYR, cam, RenderParams(lod_threshold=1, max_texels_drawn=budget_bricks * texels))
    assert len(sel.items) <= max(budget_bricks, 1)
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, PYR)), 1)
    assert order_violations(cam, *boxes(sel.items))[0] == 0
    free = select(PYR, cam, RenderParams(lod_threshold=1))
    if budget_bricks >= len(free.items):
        assert sorted((i.level, i.index) for i in sel.items) == sorted((i.level, i.index) for i in free.items)


def test_budget_grows_detail_monotonically():
    cam = cam_at((-20, 10, -30))
    t = int(np.prod(PYR.brick_shape))
    n = [len(select(PYR, cam, RenderParams(lod_threshold=1, max_texels_drawn=k * t)).items) for k in (1, 8, 30, 100, 400)]
    assert n == sorted(n) and n[-1] > n[0]


def test_roaming_picks_one_level_the_finest_inside_the_window():
    cam = cam_at((-20, 10, -30))
    res = FakeResidency(PYR, _window_around(PYR, (20, 20, 20), 3))
    sel = select(PYR, cam, RenderParams(policy="roaming", lod_threshold=0.1), residency=res)
    levels = {i.level for i in sel.items}
    assert len(levels) == 1
    L = levels.pop()
    assert sel.counts["level"] == L

    def visible(lv):
        idx = np.array(list(np.ndindex(PYR.grid(lv))))
        lo, hi = PYR.node_box(lv, idx)
        return idx[cam.boxes_in_frustum(lo, hi)]

    assert res.in_window_mask(L, visible(L)).all()
    assert L == 0 or not res.in_window_mask(L - 1, visible(L - 1)).all()
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, PYR)), 1)
    # without a window it goes as fine as the LOD threshold asks; a texel budget coarsens it
    assert select(PYR, cam, RenderParams(policy="roaming", lod_threshold=0.1)).counts["level"] == 0
    t = int(np.prod(PYR.brick_shape))
    s2 = select(PYR, cam, RenderParams(policy="roaming", lod_threshold=0.1, max_texels_drawn=20 * t))
    assert len({i.level for i in s2.items}) == 1 and len(s2.items) <= 20


def test_fixed_level_with_ancestor_fallback():
    cam = cam_at((70, 70, -5))
    sel = select(PYR, cam, RenderParams(policy="fixed", level=1))
    assert {i.level for i in sel.items} == {1}
    missing = {(1, (0, 0, 0)), (1, (3, 3, 3)), (1, (2, 3, 3))}
    sel2 = select(PYR, cam, RenderParams(policy="fixed", level=1), residency=FakeResidency(PYR, missing=missing))
    assert {i.level for i in sel2.items} <= {1, 2}
    pts = visible_points(cam, PYR)
    np.testing.assert_array_equal(coverage(sel2.items, pts), 1)
    assert all((i.level, i.index) not in missing for i in sel2.items)


def test_huge_virtual_pyramid_near_the_far_corner_is_bounded():
    n = 2**20
    big = Pyramid.build((n, n, n), (64, 64, 64))
    far = np.array(big.volume_box()[1])
    cam = Camera.perspective(far + (40, 25, 60), far - (500, 500, 500), size=(32, 32), fov_y=50).fit_depth(*big.volume_box())
    sel = select(big, cam, RenderParams(lod_threshold=2))
    assert 0 < len(sel.items) and sel.counts["visited"] < 20000
    lo, hi = boxes(sel.items)
    assert cam.boxes_in_frustum(lo, hi).all()
    assert len({i.level for i in sel.items}) > 2
    assert order_violations(cam, lo, hi)[0] == 0
    # inside the huge volume, near its far corner
    cam2 = Camera.perspective(far - (30, 30, 30), far - (5000, 4000, 3000), size=(32, 32)).fit_depth(*big.volume_box())
    sel2 = select(big, cam2, RenderParams(lod_threshold=2))
    assert 0 < len(sel2.items) and sel2.counts["visited"] < 20000
    assert order_violations(cam2, *boxes(sel2.items))[0] == 0


def test_top_level_with_several_bricks_uses_virtual_levels():
    pyr = PYR.with_levels(2)  # top level has 4x4x4 bricks
    cam = cam_at((-20, 10, -30), pyr=pyr)
    sel = select(pyr, cam, RenderParams(lod_threshold=4))
    assert {i.level for i in sel.items} <= {0, 1}
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, pyr)), 1)
    assert order_violations(cam, *boxes(sel.items))[0] == 0


def test_prime_sized_anisotropic_volume():
    pyr = Pyramid.build((13, 61, 7), (4, 8, 4), spacing=(5.0, 0.5, 2.0))
    vlo, vhi = pyr.volume_box()
    c = (vlo + vhi) / 2
    cam = cam_at(c + (30, -12, -40), target=c, pyr=pyr)
    sel = select(pyr, cam, RenderParams(lod_threshold=1.5))
    np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, pyr)), 1)
    assert order_violations(cam, *boxes(sel.items))[0] == 0


def test_params_validation():
    from clipvol.errors import ParameterError

    for kw in (dict(policy="x"), dict(lod_threshold=0), dict(policy="texel-budget"), dict(level=-1), dict(max_texels_drawn=0)):
        with pytest.raises(ParameterError):
            RenderParams(**kw)
    with pytest.raises(ParameterError):
        select(PYR, cam_at((0, 0, -50)), RenderParams(policy="fixed", level=9))
    assert isinstance(select(PYR, cam_at((0, 0, -50))).items[0], DrawItem)


def test_with_a_real_clip_texture_items_are_resident_and_wanted_in_window():
    from clipvol.loaders.numpy_array import NumpyLoader

    from clipvol.paging.cliptexture import ClipTexture

    vol = np.random.default_rng(0).random((64, 64, 64), dtype=np.float32)
    loader = NumpyLoader(vol, brick=8)
    pyr = loader.pyramid
    cam = cam_at((-20, 10, -30), pyr=pyr)
    budget = 40 * pyr.brick_nbytes * 8
    with ClipTexture(loader, memory_budget=budget, threads=1, center=(10, 10, 10)) as ct:
        ct.wait_until_idle(timeout=30)
        sel = select(pyr, cam, RenderParams(lod_threshold=0.5), residency=ct)
        assert sel.items and sel.counts["outside_window"] > 0  # the window limits refinement
        for it in sel.items:
            assert ct.resident_mask(it.level, np.array([it.index]))[0]
        for lv, b in sel.wanted:
            assert ct.in_window_mask(lv, np.array([b]))[0]
        np.testing.assert_array_equal(coverage(sel.items, visible_points(cam, pyr)), 1)
        assert order_violations(cam, *boxes(sel.items))[0] == 0


def cover_all(level, node_level, nodes):
    """A ``may_cover`` of merge_items that covers every culled sibling."""
    return np.ones(len(nodes), dtype=bool)


def cover_none(level, node_level, nodes):
    return np.zeros(len(nodes), dtype=bool)


@pytest.mark.parametrize("eye", EYES)
@pytest.mark.parametrize("threshold", [0.7, 3.0])
def test_merged_items_keep_order_and_coverage(eye, threshold):
    """merge_items: same region covered exactly once, still back to front, each item one level."""
    cam = cam_at(eye)
    sel = select(PYR, cam, RenderParams(lod_threshold=threshold))
    windows = [PYR.grid(L) for L in range(PYR.num_levels)]
    merged = merge_items(sel.items, PYR, windows)
    assert 0 < len(merged) <= len(sel.items)
    bad, hit = order_violations(cam, *boxes(merged))
    assert bad == 0 and hit > 0
    pts = visible_points(cam, PYR)
    np.testing.assert_array_equal(coverage(merged, pts), coverage(sel.items, pts))
    # every point is sampled from the same level as before the merge
    def level_at(items, p):
        return [it.level for it in items if np.all(p > it.lo) and np.all(p < it.hi)]
    for p in pts[:200]:
        assert level_at(merged, p) == level_at(sel.items, p)


def test_merge_collapses_a_uniform_cut_and_respects_windows():
    cam = Camera.orthographic(CENTRE, (0, 0, 1), (0, -1, 0), 70, 70, size=(32, 32))
    sel = select(PYR, cam, RenderParams(policy="fixed", level=0))
    assert len(sel.items) == 512
    whole = merge_items(sel.items, PYR, [PYR.grid(L) for L in range(PYR.num_levels)])
    assert [(it.level, it.index, it.span) for it in whole] == [(0, (0, 0, 0), 8)]
    # a GPU window of 4 bricks per axis: blocks of at most 4, never two bricks in one slot
    four = merge_items(sel.items, PYR, [(4, 4, 4)] * PYR.num_levels)
    assert len(four) == 8 and all(it.span == 4 for it in four)
    assert merge_items(sel.items, PYR, [None] * PYR.num_levels) == sel.items


def test_merge_covers_a_culled_sibling_only_when_allowed_and_never_twice():
    cam = Camera.orthographic(CENTRE, (0, 0, 1), (0, -1, 0), 70, 70, size=(32, 32))
    sel = select(PYR, cam, RenderParams(policy="fixed", level=0))
    windows = [PYR.grid(L) for L in range(PYR.num_levels)]
    culled = [it for it in sel.items if it.index != (0, 0, 0)]  # as if (0,0,0) were transparent
    assert len(merge_items(culled, PYR, windows)) > 1
    asked = []

    def yes(level, node_level, nodes):
        asked.extend((level, node_level, tuple(int(v) for v in k)) for k in nodes)
        return np.ones(len(nodes), dtype=bool)

    merged = merge_items(culled, PYR, windows, yes)
    assert [(it.level, it.span) for it in merged] == [(0, 8)] and asked == [(0, 0, (0, 0, 0))]
    assert len(merge_items(culled, PYR, windows, cover_none)) > 1
    # a sibling drawn at a finer level (here: a level-1 brick replaced by its level-0 children)
    # is never covered by a merge of its level-1 siblings, whatever may_cover says
    sel1 = select(PYR, cam, RenderParams(policy="fixed", level=1))
    mixed = []
    for it in sel1.items:
        if it.index == (0, 0, 0):
            mixed += [DrawItem(0, c, tuple(PYR.node_box(0, c)[0]), tuple(PYR.node_box(0, c)[1]))
                      for c in PYR.children(1, (0, 0, 0))]
        else:
            mixed.append(it)
    out = merge_items(mixed, PYR, windows, cover_all)
    pts = visible_points(cam, PYR)
    np.testing.assert_array_equal(coverage(out, pts), 1)


@pytest.mark.parametrize("seed", [0, 1, 2, *(pytest.param(s, marks=pytest.mark.slow) for s in (3, 4, 5))])
def test_merge_of_mixed_cuts_keeps_order_coverage_and_levels(seed):
    """merge_items on cuts with ancestor fallbacks, culled items and small GPU windows: every
    visible point is covered as often as before and sampled from the same level, the order stays
    back to front, and no merged block is wider than its level's window."""
    rng = np.random.default_rng(seed)
    pyr = Pyramid.build((61, 37, 83), (8, 8, 8))
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    cam = cam_at(tuple(c + d * float(np.linalg.norm(hi - lo)) * rng.uniform(0.4, 1.5)), target=tuple(c), pyr=pyr,
                 up=(0, 1, 0) if abs(d[1]) < 0.9 else (1, 0, 0))
    gone = {}

    class Residency:  # a fifth of the bricks below the top level not resident: their ancestors stand in
        def in_window_mask(self, level, idx):
            return np.ones(len(idx), bool)

        def resident_mask(self, level, idx):
            return np.array([level == pyr.num_levels - 1 or not gone.setdefault((level, tuple(b)), rng.random() < 0.2)
                             for b in np.asarray(idx).tolist()], bool)

    sel = select(pyr, cam, RenderParams(lod_threshold=float(rng.uniform(0.5, 2.0))), residency=Residency())
    items = [it for it in sel.items if rng.random() > 0.1]  # some culled, as if transparent
    windows = [(2, 3, 4)] + [pyr.grid(L) for L in range(1, pyr.num_levels)]
    merged = merge_items(items, pyr, windows, lambda L, n, nodes: rng.random(len(nodes)) < 0.5)
    assert 0 < len(merged) <= len(items)
    assert order_violations(cam, *boxes(merged))[0] == 0
    pts = visible_points(cam, pyr)
    cov_items, cov_merged = coverage(items, pts), coverage(merged, pts)
    assert np.all(cov_merged[cov_items == 1] == 1)  # what was drawn still is, once
    assert cov_merged.max() <= 1  # a culled sibling may be covered, nothing twice

    def level_at(its, p):
        return [it.level for it in its if np.all(p > it.lo) and np.all(p < it.hi)]

    for p in pts[:300]:
        before = level_at(items, p)
        assert before == [] or level_at(merged, p) == before
    for it in merged:
        if it.level == 0:
            assert it.span <= 2  # the (2, 3, 4) window: at most two bricks per axis
