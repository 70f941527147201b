"""The image policy end to end (GL): occluded bricks are neither requested nor drawn, at equal
block budget its image is at least as close to full resolution as projected size's, its error
falls as the budget grows, and a store without summary tables is refused with the fix named."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from clipvol.bricking.generators import ct_head
from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.summary import SummaryMissingError
from clipvol.errors import ParameterError
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.open import open_store
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.metrics import percent_delta_e
from clipvol.scene.params import RenderParams
from clipvol.scene.selection.coherence import node_order
from clipvol.scene.transfer import TransferFunction
from render_helpers import render_converged

TF = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.3, (0, 0, 0, 0)), (0.45, (0.2, 0.9, 0.3, 0.5)),
                                   (1.0, (1, 1, 1, 1))])


@pytest.fixture(scope="module")
def slab_store(tmp_path_factory):
    """An opaque slab in front (small z) of a visible blob (large z)."""
    vol = np.zeros((48, 32, 32), np.uint8)
    vol[4:12] = 255
    vol[30:44, 8:24, 8:24] = 128
    path = tmp_path_factory.mktemp("slab") / "slab.zarr"
    brick_volume(vol, path, brick=8, progress=False)
    return path


@pytest.fixture(scope="module")
def head_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("head") / "head.zarr"
    brick_volume(ct_head((64, 64, 64), seed=1), path, brick=8, progress=False)
    return path


def _slab_camera():
    return Camera.perspective((16.0, 16.0, -60.0), (16.0, 16.0, 24.0), up=(0, -1, 0), fov_y=30, size=(64, 64))


def test_bricks_behind_an_opaque_slab_are_not_requested(gl, slab_store):
    loader = open_store(slab_store)
    with ClipTexture(loader, "64MB") as clip, ClipRenderAction(gl, clip, policy="image", block_budget=10_000) as act:
        render_converged(act, _slab_camera(), TF)
        wanted = act.last_selection.wanted
        behind = [(L, b) for L, b in wanted if (b[0] + 1) * 8 * 2**L > 12 and b[0] * 8 * 2**L >= 24]
        assert not behind, behind
        assert not any(it.level == 0 and it.index[0] >= 3 for it in act.last_selection.items)
        # the estimate itself: the blob's level-0 bricks are (almost) invisible, the slab's are visible
        layers = act.image_lod.layers
        lo, hi = loader.pyramid.node_box(0, np.array([[4, 2, 2], [0, 2, 2]]))
        v = layers.visibility(lo, hi, _slab_camera())
        assert v[0] < 0.01 and v[1] > 0.99
        # without the estimate the same budget asks for the blob's bricks: the cull above is visibility's
        act.set_params(replace(act.params, visibility=False))
        render_converged(act, _slab_camera(), TF)
        assert any(b[0] * 8 * 2**L >= 24 for L, b in act.last_selection.wanted)


def _head_view(pyr, size=96):
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    d = np.array([0.3, 0.2, 1.0])
    d /= np.linalg.norm(d)
    return Camera.perspective(tuple(c - d * 0.62 * float(np.linalg.norm(hi - lo))), tuple(c), up=(0, -1, 0),
                              fov_y=40, size=(size, size))


def _errors(gl, store, policy_params, budgets):
    loader = open_store(store)
    tf = TransferFunction.preset("bone", value_range=loader.pyramid.value_range)
    cam = _head_view(loader.pyramid)
    out = []
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="fixed", level=0) as act:
        ref = render_converged(act, cam, tf)
        for b in budgets:
            act.set_params(RenderParams(**policy_params(b)))
            img = render_converged(act, cam, tf)
            out.append((act.last_frame_stats.bricks_distinct, percent_delta_e(img, ref)))
    return out


def test_image_policy_beats_projected_size_at_equal_budget(gl, head_store):
    budgets = [32, 64, 96]
    image = _errors(gl, head_store, lambda b: dict(policy="image", block_budget=b), budgets)
    proj = _errors(gl, head_store, lambda b: dict(policy="texel-budget", max_texels_drawn=b * 512), budgets)
    for b, (n_i, e_i), (n_p, e_p) in zip(budgets, image, proj):
        assert n_i <= b and n_p <= b
        assert e_i <= e_p, (b, image, proj)


def test_image_error_falls_as_the_budget_grows(gl, head_store):
    budgets = [8, 16, 32, 64, 128, 256]
    errs = [e for _, e in _errors(gl, head_store, lambda b: dict(policy="image", block_budget=b), budgets)]
    assert all(b <= a + 0.25 for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 0.5 * errs[0], errs


def test_store_without_tables_is_refused(gl, tmp_path):
    path = tmp_path / "bare.zarr"
    brick_volume(np.zeros((16, 16, 16), np.uint8), path, brick=8, progress=False, summary=False)
    for loader in (open_store(path), open_store("procedural:fractal?size=16", brick=8)):
        with ClipTexture(loader, "16MB") as clip, ClipRenderAction(gl, clip, policy="image") as act:
            with pytest.raises(SummaryMissingError, match="clipvol summarize"):
                act.render(_slab_camera(), TF)


def test_block_budget_must_be_positive():
    with pytest.raises(ParameterError, match="block_budget"):
        RenderParams(policy="image", block_budget=0)
    assert RenderParams(policy="image").block_budget >= 1


def _turned(cam, deg):
    """``cam`` with its eye turned by ``deg`` degrees about the vertical axis through its target."""
    th = np.radians(deg)
    r = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    t = np.asarray(cam.target)
    return Camera.perspective(tuple(t + r @ (np.asarray(cam.eye) - t)), tuple(t), up=(0, -1, 0), fov_y=cam.fov_y,
                              size=tuple(cam.size))


def test_cut_is_replayed_only_for_small_turns(gl, head_store):
    """A turn of 1 degree replays the last cut (the same bricks, drawn in the new view's back-to-front
    order); 10 degrees, a new transfer function or a new budget make a new cut; the stored cut is the
    one a fresh action makes for the same view."""
    loader = open_store(head_store)
    tf = TransferFunction.preset("bone", value_range=loader.pyramid.value_range)
    cam = _head_view(loader.pyramid)
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="image", block_budget=48) as act:
        render_converged(act, cam, tf)
        lod = act.image_lod
        first = sorted(act.last_selection.wanted)
        cuts = lod.cuts
        render_converged(act, _turned(cam, 1.0), tf)
        assert lod.cuts == cuts and act.last_policy.reused
        assert sorted(act.last_selection.wanted) == first
        # the replayed items are drawn back to front for the turned eye: box a can hide box b only if
        # the eye lies on a's side of every axis-aligned plane that separates them; then a comes later
        eye = np.asarray(_turned(cam, 1.0).eye)
        items = act.last_selection.items
        if not act.last_selection.ordered:  # a cut of whole nodes left in depth-first order: the order drawn
            items = [items[i] for i in node_order(items, act.pyramid, act._selection_camera(_turned(cam, 1.0)))]
        assert len(items) > 1
        for i, a in enumerate(items):
            for b in items[i + 1:]:
                sides = []
                for ax in range(3):
                    if a.hi[ax] <= b.lo[ax]:
                        sides.append(eye[ax] <= a.hi[ax])
                    elif b.hi[ax] <= a.lo[ax]:
                        sides.append(eye[ax] >= a.lo[ax])
                assert sides and not all(sides), (a, b)
        render_converged(act, _turned(cam, 10.0), tf)
        assert lod.cuts == cuts + 1 and not act.last_policy.reused
        render_converged(act, _turned(cam, 10.0), TransferFunction.preset("viridis", value_range=loader.pyramid.value_range))
        assert lod.cuts == cuts + 2
        act.set_params(replace(act.params, block_budget=64))
        render_converged(act, _turned(cam, 10.0), TransferFunction.preset("viridis", value_range=loader.pyramid.value_range))
        assert lod.cuts == cuts + 3
    # the replayed cut is the cut a fresh action makes for the first view (the cache returns what it stored)
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="image", block_budget=48) as act:
        render_converged(act, cam, tf)
        assert sorted(act.last_selection.wanted) == first


def test_cpu_estimate_sees_through_a_coarse_brick_the_loader_fails_to_read(slab_store):
    """An unreadable coarse brick hides nothing (the cautious answer): the blob behind the lost quarter
    of the slab counts as visible, the blob behind the rest stays hidden, and the failure is listed."""
    from clipvol.render.visibility import CpuVisibilityEstimator

    inner = open_store(slab_store)

    class Failing:
        pyramid = inner.pyramid

        def read_brick(self, level, index):
            if (level, tuple(index)) == (1, (0, 1, 1)):
                raise OSError("disk gone")
            return inner.read_brick(level, index)

    est = CpuVisibilityEstimator(Failing())
    assert est.level == 1
    layers = est.estimate(_slab_camera(), TF)
    assert [k for k, _ in est.failed] == [(1, (0, 1, 1))]
    # the blob's first level-0 bricks (z 24..32: nothing but the slab in front), one behind the lost
    # quarter (y, x >= 16), one behind the intact slab
    lo, hi = inner.pyramid.node_box(0, np.array([[3, 2, 2], [3, 1, 1]]))
    v = layers.visibility(lo, hi, _slab_camera())
    assert v[0] > 0.9 and v[1] < 0.1, v  # (the second's footprint rectangle touches the lost quarter's edge)
    # with every brick readable both are hidden
    v_all = CpuVisibilityEstimator(inner).estimate(_slab_camera(), TF).visibility(lo, hi, _slab_camera())
    assert np.all(v_all < 0.01), v_all


def test_cut_is_not_replayed_when_a_culled_region_turns_into_view(gl, head_store):
    """A close view sees part of the head (the frustum culls the rest); a turn smaller than the reuse
    angle that brings culled bricks into view must make a new cut - a replay would leave those
    bricks out and draw a hole at the image's edge. The turned frame equals a fresh action's frame."""
    loader = open_store(head_store)
    # faint everywhere but air: nothing is occluded, so the cut refines to level 0 up to the frustum's edge
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.1, (0.5, 0.5, 0.5, 0.02)), (1.0, (1, 1, 1, 0.05))])
    lo, hi = loader.pyramid.volume_box()
    c = (lo + hi) / 2
    eye = c - np.array([0.0, 0.0, 40.0])
    cam = Camera.perspective(tuple(eye), tuple(c), up=(0, -1, 0), fov_y=30, size=(64, 64))
    th = np.radians(2.0)  # the view direction turns about the eye
    turned = Camera.perspective(tuple(eye), tuple(eye + 40.0 * np.array([np.sin(th), 0.0, np.cos(th)])), up=(0, -1, 0),
                                fov_y=30, size=(64, 64))
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="image", block_budget=400) as act:
        render_converged(act, cam, tf)
        policy = act.last_policy
        assert len(policy._culled[0]), "the close view must cull part of the head for this test to mean anything"
        assert not policy.covers(turned)
        cuts = act.image_lod.cuts
        img = render_converged(act, turned, tf)
        assert act.image_lod.cuts == cuts + 1 and not act.last_policy.reused
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="image", block_budget=400) as act:
        fresh = render_converged(act, turned, tf)
    assert np.abs(img.astype(int) - fresh.astype(int)).max() <= 1
