"""The rule that lets a frame draw the last frame's cut again (clipvol.scene.selection.coherence).

Checked against what it stands for, a fresh selection: wherever ``cut_holds`` says a kept cut is
the cut of a turned camera, ``select`` for that camera makes exactly that cut; ``node_order`` of the
kept merged boxes is the order the merge of the fresh, camera-ordered cut gives; and the fixed
level's ``subtree_empty`` is the numpy statement "every brick of the fixed level under the node is
transparent", evaluated brick by brick.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import merge_items, select
from clipvol.scene.selection.coherence import cut_holds, node_order, replayable
from clipvol.scene.selection.octree import Octree
from clipvol.scene.selection.policies import policy_for
from clipvol.scene.selection.traversal import Traversal

PYR = Pyramid.build((64, 64, 64), (8, 8, 8))  # grids 8, 4, 2, 1
CENTRE = np.array([31.5, 31.5, 31.5])
FIXED = RenderParams(policy="fixed", level=0)


def transparent(level, idx):
    """A ball of data in air: a brick is transparent when its centre lies 3.2 level-0 bricks or
    more from the volume's centre (a numpy statement, in brick units of its level)."""
    idx = np.asarray(idx, dtype=np.float64).reshape(-1, 3)
    c = (idx + 0.5) * 2 ** level - 4.0  # centre in level-0 bricks from the volume's centre
    return np.linalg.norm(c, axis=1) >= 3.2


def orbit_cam(deg: float, elev: float = 20.0, dist: float = 75.0, fov: float = 30.0, shift=(0, 0, 0)) -> Camera:
    th, ph = np.radians(deg), np.radians(elev)
    d = np.array([np.sin(th) * np.cos(ph), np.sin(ph), np.cos(th) * np.cos(ph)])
    cam = Camera.perspective(tuple(CENTRE + d * dist), tuple(CENTRE + np.asarray(shift, dtype=float)),
                             up=(0, 1, 0), fov_y=fov, size=(24, 24))
    return cam.fit_depth(*PYR.volume_box())


def keys(sel) -> set:
    return {(int(r[0]), *map(int, r[1:])) for r in sel.items.rows}


def test_a_kept_cut_holds_only_where_a_fresh_selection_makes_it_again():
    rng = np.random.default_rng(3)
    held = changed = 0
    for trial in range(16):
        deg, elev, dist, fov = rng.uniform(0, 360), rng.uniform(-30, 30), rng.uniform(45, 80), rng.uniform(20, 35)
        shift = rng.uniform(-12, 12, 3)
        base = orbit_cam(deg, elev, dist, fov, shift)
        sel0 = select(PYR, base, FIXED, transparent=transparent)
        assert replayable(sel0) and sel0.frustum_culled is not None
        for _ in range(6):
            if rng.random() < 0.3:  # anywhere
                turned = orbit_cam(rng.uniform(0, 360), rng.uniform(-30, 30), rng.uniform(45, 80),
                                   rng.uniform(20, 35), rng.uniform(-12, 12, 3))
            else:  # a few degrees of orbit
                turned = orbit_cam(deg + rng.uniform(-8, 8), elev + rng.uniform(-4, 4), dist, fov, shift)
            fresh = select(PYR, turned, FIXED, transparent=transparent)
            if cut_holds(sel0, turned):
                held += 1
                assert keys(fresh) == keys(sel0)
            elif keys(fresh) != keys(sel0):
                changed += 1
    assert held >= 8 and changed >= 8  # both answers were exercised


def test_a_cut_whose_culled_node_turns_into_view_does_not_hold():
    cam = orbit_cam(0.0, dist=40.0, fov=20.0)  # close: the frustum culls much of the ball
    sel = select(PYR, cam, FIXED, transparent=transparent)
    assert len(sel.frustum_culled[0])
    far = orbit_cam(0.0, dist=120.0, fov=40.0)  # the whole ball in view: the cut grows
    assert keys(select(PYR, far, FIXED, transparent=transparent)) != keys(sel)
    assert not cut_holds(sel, far)


def test_node_order_of_kept_merged_boxes_is_the_fresh_merge_order():
    windows = [(8, 8, 8), (4, 4, 4), (2, 2, 2), (1, 1, 1)]
    base = orbit_cam(30.0, dist=140.0, fov=40.0)
    sel0 = select(PYR, base, FIXED)  # no transparency: complete sibling sets merge
    merged0 = merge_items(sel0.items, PYR, windows)
    assert len(merged0) < len(sel0.items)
    for deg in (31.0, 75.0, 160.0, 260.0):
        cam = orbit_cam(deg, dist=140.0, fov=40.0)
        assert cut_holds(sel0, cam)
        fresh = merge_items(select(PYR, cam, FIXED).items, PYR, windows)
        assert [merged0[i] for i in node_order(merged0, PYR, cam)] == fresh


@pytest.mark.parametrize("level", [1, 2, 3])
def test_fixed_level_subtree_empty_is_every_fixed_level_brick_transparent(level):
    t = Traversal(Octree(PYR), orbit_cam(0.0), FIXED, policy_for(FIXED), None, transparent)
    g = np.array(PYR.grid(level))
    nodes = np.argwhere(np.ones(tuple(g), dtype=bool)).astype(np.int64)
    lo, hi = t.tree.boxes(level, nodes)
    got = np.asarray(t.policy.subtree_empty(t, level, lo, hi), dtype=bool)
    f = 2 ** level
    expect = []
    for n in nodes:  # brick by brick
        zs, ys, xs = (range(n[a] * f, min((n[a] + 1) * f, 8)) for a in range(3))
        under = [(z, y, x) for z in zs for y in ys for x in xs]
        expect.append(all(bool(transparent(0, [b])[0]) for b in under))
    np.testing.assert_array_equal(got, expect)
    assert (0 < got.sum() < len(got)) or level >= 2  # (from level 2 up every node holds some of the ball)
