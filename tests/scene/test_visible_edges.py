"""The edge term of the visible-error estimate (clipvol.scene.visible_edges): the edge share of an
opacity map and each box's shown and edge shares against pixel-by-pixel counts, and the image
policy's estimate following the edges in front of each node (a view whose opacity map shows no edge
is predicted to differ on fewer pixels than one full of edges; the estimate equals the sum over the
cut's nodes, each weighted by the pixels it shows, computed here from the definition)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.summary import open_summary
from clipvol.errors import ParameterError
from clipvol.scene.camera import Camera
from clipvol.scene.lod_error import lod_errors
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import select
from clipvol.scene.selection.policies.image_based import ImageBased
from clipvol.scene.transfer import TransferFunction
from clipvol.scene.visibility import OcclusionLayers
from clipvol.scene.visible_edges import (EDGE_FLOOR, EDGE_GAIN, EDGE_GROWTH, EDGE_JUMP, EDGE_MAP_CAP, EDGE_MAP_VOXEL,
                                         edge_difference, edge_map, edge_share)


def _edges_by_loop(a, nonempty=0.02, jump=EDGE_JUMP):
    """The definition, one pixel at a time: ``(shown, edge)`` bool maps - pixels above ``nonempty``,
    and those of them with a 4-neighbour at least ``jump`` away."""
    h, w = a.shape
    shown = np.zeros((h, w), bool)
    edge = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            if a[y, x] <= nonempty:
                continue
            shown[y, x] = True
            for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                yy, xx = y + dy, x + dx
                if 0 <= yy < h and 0 <= xx < w and abs(a[yy, xx] - a[y, x]) >= jump:
                    edge[y, x] = True
                    break
    return shown, edge


def _edge_share_by_loop(a, nonempty=0.02, jump=EDGE_JUMP):
    shown, edge = _edges_by_loop(a, nonempty, jump)
    return edge.sum() / shown.sum() if shown.any() else 0.0


def _rect_by_corners(cam, lo, hi, map_w, map_h):
    """A box's rectangle in map pixels, from its eight corners projected here with the camera's
    matrix: ``x0, y0, x1, y1`` (floor / ceil of the image rectangle scaled to the map, at least one
    pixel)."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    hom = np.c_[corners, np.ones(8)] @ cam.view_projection().T
    W, H = cam.size
    px = (hom[:, 0] / hom[:, 3] + 1) * 0.5 * W
    py = (1 - hom[:, 1] / hom[:, 3]) * 0.5 * H
    px, py = np.clip(px, 0, W), np.clip(py, 0, H)
    x0 = int(np.clip(np.floor(px.min() * map_w / W), 0, map_w - 1))
    y0 = int(np.clip(np.floor(py.min() * map_h / H), 0, map_h - 1))
    x1 = int(np.clip(np.ceil(px.max() * map_w / W), x0 + 1, map_w))
    y1 = int(np.clip(np.ceil(py.max() * map_h / H), y0 + 1, map_h))
    return x0, y0, x1, y1, (px.max() - px.min()) * (py.max() - py.min())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_edge_share_counts_pixels_with_a_step_to_a_neighbour(seed):
    rng = np.random.default_rng(seed)
    a = np.clip(rng.normal(0.5, 0.08, (23, 31)), 0, 1)
    a[:, :5] = 0.0  # empty border: not counted, though its neighbours step
    a[rng.random(a.shape) < 0.1] = 0.0
    assert edge_share(a) == pytest.approx(_edge_share_by_loop(a), abs=1e-12)
    assert edge_share(np.zeros((8, 8))) == 0.0
    assert edge_share(np.full((8, 8), 0.7)) == 0.0
    with pytest.raises(ParameterError, match="edge_share: expected a 2-D opacity map"):
        edge_share(np.zeros((2, 8, 8)))


def test_edge_map_marks_what_the_loop_marks():
    a = np.random.default_rng(5).random((16, 20)) * (np.random.default_rng(6).random((16, 20)) > 0.3)
    assert np.array_equal(edge_map(a), _edges_by_loop(a)[1])
    with pytest.raises(ParameterError, match="edge_map: expected a 2-D opacity map"):
        edge_map(np.zeros((2, 8, 8)))


def test_edge_difference_grows_with_level_and_edges_from_a_floor():
    assert np.all(edge_difference([0, 0], [0.0, 0.9]) == 0.0)
    shares = np.array([0.0, 0.01, EDGE_FLOOR, 0.1, 0.3, 1.0])
    q = np.array([edge_difference(np.full(len(shares), L), shares) for L in (1, 2, 3)])
    assert np.all((q > 0) & (q < 1))
    assert np.all(np.diff(q, axis=0) > 0)  # a coarser level differs on more pixels
    assert np.all(np.diff(q[:, 2:], axis=1) > 0)  # more edges, more pixels
    assert np.all(q[:, 0] == q[:, 2]) and np.all(q[:, 1] == q[:, 2])  # below the floor: the floor
    # small exponents: q is about EDGE_GAIN * EDGE_GROWTH**L times the share
    assert float(edge_difference(1, 0.06)) == pytest.approx(EDGE_GAIN * EDGE_GROWTH * 0.06, rel=0.05)
    # a voxel smaller in the map than where it was fitted: each map pixel's edge stands for fewer
    # differing pixels; larger: more, up to the cap
    assert float(edge_difference(1, 0.3, EDGE_MAP_VOXEL)) == float(edge_difference(1, 0.3))
    assert float(edge_difference(1, 0.3, EDGE_MAP_VOXEL / 2)) == float(edge_difference(1, 0.15))
    assert float(edge_difference(1, 0.3, EDGE_MAP_VOXEL * 100)) == float(edge_difference(1, 0.3 * EDGE_MAP_CAP))
    assert float(edge_difference(1, 0.01, EDGE_MAP_VOXEL * 2)) == float(edge_difference(1, 0.0))  # the floor


def test_footprint_counts_each_box_s_shown_and_edge_pixels():
    """Each box's share of shown pixels in its map rectangle and the share of those on an edge equal
    counts over the loop's maps in the rectangle of its corners projected here."""
    rng = np.random.default_rng(11)
    total = rng.random((32, 32)) * (rng.random((32, 32)) > 0.4)
    cam = Camera.perspective((32.0, 32.0, -90.0), (32.0, 32.0, 32.0), up=(0, -1, 0), fov_y=45, size=(128, 96))
    layers = _occlusion(cam, total)
    lo = rng.uniform(0, 50, size=(40, 3))
    hi = lo + rng.uniform(2, 30, size=(40, 3))
    shown, edges = layers.footprint(lo, hi)
    ref_shown, ref_edge = _edges_by_loop(total)
    for i in range(len(lo)):
        x0, y0, x1, y1, _ = _rect_by_corners(cam, lo[i], hi[i], 32, 32)
        s, e = ref_shown[y0:y1, x0:x1], ref_edge[y0:y1, x0:x1]
        assert shown[i] == pytest.approx(s.mean(), abs=1e-12)
        assert edges[i] == pytest.approx(e.sum() / s.sum() if s.any() else 0.0, abs=1e-12)


TF = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.45, (0, 0, 0, 0)), (0.55, (1, 0.9, 0.8, 1)),
                                   (1.0, (1, 1, 1, 1))])


@pytest.fixture(scope="module")
def shell_store(tmp_path_factory):
    """A thin bright shell (two voxels thick) in dim tissue: the coarse levels' bias sits on its edges."""
    z, y, x = np.mgrid[:64, :64, :64]
    r = np.sqrt((x - 31.5) ** 2 + (y - 31.5) ** 2 + (z - 31.5) ** 2)
    vol = np.where(np.abs(r - 20) < 1.0, 230, np.where(r < 28, 60, 0)).astype(np.uint8)
    path = tmp_path_factory.mktemp("edges") / "s.zarr"
    brick_volume(vol, path, brick=8, progress=False)
    return path


def _occlusion(cam, total):
    """A visibility estimate with nothing in front of any brick and ``total`` as the total opacity."""
    alpha = np.stack([np.zeros_like(total), total])
    return OcclusionLayers(cam, np.array([0.0, 1e9]), alpha)


@pytest.mark.parametrize("classify", ["distribution", "mean"])
def test_the_estimate_follows_the_view_s_edges(shell_store, classify):
    """With consistent coarse levels a smooth view is predicted to differ on fewer pixels than one full
    of edges; with the mean classified (a thin structure can vanish from a coarse level, on smooth
    views too) the edges do not change the estimate."""
    tabs = open_summary(shell_store)
    cam = Camera.perspective((32.0, 32.0, -90.0), (32.0, 32.0, 32.0), up=(0, -1, 0), fov_y=45, size=(128, 128))
    errors = lod_errors(tabs, TF, classify)
    flat = np.full((64, 64), 0.4)
    stripes = flat.copy()
    stripes[:, ::2] = 0.25  # opacity steps of 0.15 between every pair of columns, never across 0.5
    est = {}
    for name, total in (("flat", flat), ("stripes", stripes)):
        params = RenderParams(policy="image", block_budget=8, classify=classify)
        pol = ImageBased(params, errors=errors, visibility=_occlusion(cam, total))
        sel = select(tabs.pyramid, cam, params, policy=pol)
        assert {L for L, _ in sel.wanted} - {0}, "the cut must hold coarse nodes"
        est[name] = pol.estimated_error
    assert edge_share(flat) == 0.0 and edge_share(stripes) == 1.0
    if classify == "distribution":
        assert 0.0 < est["flat"] < 0.8 * est["stripes"]
    else:
        assert est["flat"] == pytest.approx(est["stripes"], rel=1e-12) and est["flat"] > 0


@pytest.mark.parametrize("distance", [90.0, 400.0])  # far: a voxel below EDGE_MAP_VOXEL map pixels
def test_the_estimate_sums_the_edges_in_front_of_each_node(shell_store, distance):
    """Edges on the left half of the map only: the estimate is, over the cut's nodes, the share of the
    image that shows something times the mean of each coarse node's ``q`` (its level, the edge share of
    its rectangle scaled by a level-0 voxel's size in map pixels at the box's nearest depth) weighted
    by its area times the share of its rectangle that shows something - all recomputed here from the
    definition (corners projected here, the loop's maps, the pinhole's pixels per unit); the same cut
    with the edges on the right half predicts differently."""
    tabs = open_summary(shell_store)
    eye, target = np.array([32.0, 32.0, 32.0 - distance]), np.array([32.0, 32.0, 32.0])
    cam = Camera.perspective(tuple(eye), tuple(target), up=(0, -1, 0), fov_y=45, size=(128, 128))
    fwd = (target - eye) / np.linalg.norm(target - eye)
    px_per_unit = 128 / (2 * np.tan(np.radians(45 / 2)))  # at depth 1; the store's voxels are 1 unit
    errors = lod_errors(tabs, TF, "distribution")
    base = np.full((64, 64), 0.4)
    base[:, :8] = 0.0  # a strip that shows nothing
    est = {}
    for side in ("left", "right"):
        total = base.copy()
        cols = slice(8, 36, 2) if side == "left" else slice(36, 64, 2)
        total[:, cols] = 0.25
        params = RenderParams(policy="image", block_budget=8, classify="distribution")
        pol = ImageBased(params, errors=errors, visibility=_occlusion(cam, total))
        select(tabs.pyramid, cam, params, policy=pol)
        shown_map, edge_map_ = _edges_by_loop(total)
        num = den = 0.0
        scaled = []
        for (level, b) in pol.node_data:
            lo, hi = tabs.pyramid.node_box(level, b)
            x0, y0, x1, y1, area = _rect_by_corners(cam, lo, hi, 64, 64)
            s, e = shown_map[y0:y1, x0:x1], edge_map_[y0:y1, x0:x1]
            w = area * s.mean()
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            map_voxel = px_per_unit / ((corners - eye) @ fwd).min() * 64 / 128
            share = e.sum() / s.sum() if s.any() else 0.0
            share = max(share * min(map_voxel / EDGE_MAP_VOXEL, EDGE_MAP_CAP), EDGE_FLOOR)
            scaled.append(map_voxel < EDGE_MAP_VOXEL)
            q = 0.0 if level == 0 or errors.bias[level][b] <= 0 else 1 - np.exp(-EDGE_GAIN * EDGE_GROWTH ** level * share)
            num, den = num + w * q, den + w
            # what the policy reports per node (bench_estimate.py --nodes): this q, this weight
            w_pol, q_pol = pol.node_estimates()[(level, b)]
            assert q_pol == pytest.approx(q, rel=1e-9, abs=1e-15) and w_pol == pytest.approx(w, rel=1e-6)
        assert set(pol.node_estimates()) == set(pol.node_data)
        assert {L for L, _ in pol.node_data} - {0}, "the cut must hold coarse nodes"
        assert pol.estimated_error == pytest.approx(shown_map.mean() * num / den, rel=1e-9)
        est[side] = pol.estimated_error
        assert any(scaled) == (distance > 200)  # the far view's voxels are smaller than the fitted ones
    assert est["left"] != pytest.approx(est["right"], rel=1e-3)
