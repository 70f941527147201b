"""The view's edge term of the visible-error estimate (clipvol.scene.visible_edges): the edge share
of an opacity map against a pixel-by-pixel count, and the image policy's estimate following it
(a view whose opacity map shows no edge is predicted to differ on fewer pixels than one full of
edges, for the same cut)."""

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
from clipvol.scene.visible_edges import EDGE_JUMP, edge_share, edge_weight


def _edge_share_by_loop(a, nonempty=0.02, jump=EDGE_JUMP):
    """The definition, one pixel at a time: shown pixels with a 4-neighbour at least ``jump`` away."""
    h, w = a.shape
    shown = edges = 0
    for y in range(h):
        for x in range(w):
            if a[y, x] <= nonempty:
                continue
            shown += 1
            for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                yy, xx = y + dy, x + dx
                if 0 <= yy < h and 0 <= xx < w and abs(a[yy, xx] - a[y, x]) >= jump:
                    edges += 1
                    break
    return edges / shown if shown else 0.0


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


def test_edge_weight_leaves_level_0_and_orders_views():
    assert np.all(edge_weight([0, 0], 0.3) == 0.0)
    smooth, edgy = edge_weight([1, 2, 3], 0.0), edge_weight([1, 2, 3], 0.2)
    assert np.all(smooth < edgy)
    assert np.all(np.diff(smooth) > 0)  # on a smooth view the coarser levels keep more of their bias


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
