"""Stability matrix, values: opacity at 0 / 1e-7 / 1-1e-7 / 1, opacity correction over six decades of
spacing ratio, every integer dtype at its full range, floats with NaN / Inf / denormals / huge
magnitudes, all-negative and constant data (zero-width normalisation).

Every row of ``docs/stability.md`` marked *values* is one test here. References are independent:
``decimal`` arithmetic at 50 digits for the opacity formula, Python integers for the integer mean,
and the numpy ray caster of ``reference_raycast.py`` (or plain ``vol.max(axis=0)``) for images.
"""

from __future__ import annotations

import decimal
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.scene.camera import Camera
from clipvol.paging.cliptexture import ClipTexture
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.bricking.pyramid import downsample
from clipvol.scene.transfer import TransferFunction, correct_opacity

import reference_raycast as ref

ALPHAS = (0.0, 1e-7, 1.0 - 1e-7, 1.0)
RATIOS = np.logspace(-3, 3, 25)
GREY = TransferFunction.preset("grey")

INT_DTYPES = ("int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64")
FLOAT_DTYPES = ("float16", "float32", "float64")


# -- opacity (pure numpy) ------------------------------------------------------------------------
def _decimal_correct(a: float, r: float) -> decimal.Decimal:
    """``1 - (1 - a) ** r`` at 50 significant digits (an independent reference)."""
    with decimal.localcontext() as c:
        # enough digits that 1 - a and 1 - exp(...) keep 50 significant digits however small a is
        c.prec = 60 + (int(-math.log10(a)) if 0 < a < 1 else 0) + int(abs(math.log10(r)))
        a_d, r_d = decimal.Decimal(a), decimal.Decimal(r)
        if a_d == 1:
            return decimal.Decimal(1)
        if a_d == 0:
            return decimal.Decimal(0)
        return 1 - ((1 - a_d).ln() * r_d).exp()


def test_correct_opacity_matches_high_precision_over_six_decades():
    """alpha in {0, 1e-7, 1-1e-7, 1} x ratio in [1e-3, 1e3]: no NaN, no overflow, within 1e-13 relative."""
    a = np.repeat(np.array(ALPHAS), len(RATIOS))
    r = np.tile(RATIOS, len(ALPHAS))
    got = np.asarray(correct_opacity(a, r))
    assert got.dtype == np.float64 and np.all(np.isfinite(got))
    assert np.all((got >= 0.0) & (got <= 1.0))
    want = np.array([float(_decimal_correct(float(x), float(y))) for x, y in zip(a, r)])
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-300)
    # the two exact ends stay exact
    assert np.all(got[a == 0.0] == 0.0) and np.all(got[a == 1.0] == 1.0)


def test_correct_opacity_monotone_in_ratio_and_alpha():
    grid_a = np.concatenate([np.array(ALPHAS), np.linspace(0, 1, 101), 1 - np.logspace(-16, -1, 30), np.logspace(-16, -1, 30)])
    grid_a = np.unique(np.clip(grid_a, 0, 1))
    A, R = np.meshgrid(grid_a, RATIOS, indexing="ij")
    out = np.asarray(correct_opacity(A, R))
    assert np.all(np.diff(out, axis=0) >= 0)  # non-decreasing in alpha
    assert np.all(np.diff(out, axis=1) >= 0)  # non-decreasing in ratio
    # the naive form loses everything at tiny alpha; ours keeps the first-order term a * r
    tiny = np.asarray(correct_opacity(1e-12, RATIOS))
    np.testing.assert_allclose(tiny, 1e-12 * RATIOS, rtol=1e-9)


@settings(max_examples=200, deadline=None)
@given(a=st.floats(0.0, 1.0), r1=st.floats(1e-3, 1e3), r2=st.floats(1e-3, 1e3))
def test_correct_opacity_composes(a, r1, r2):
    """Two corrections in a row equal one with the product ratio (the defining property)."""
    twice = correct_opacity(correct_opacity(a, r1), r2)
    once = correct_opacity(a, r1 * r2)
    assert math.isfinite(twice) and math.isfinite(once)
    want = float(_decimal_correct(a, r1 * r2))
    assert once == pytest.approx(want, rel=1e-12, abs=1e-300)
    # composition passes through an intermediate alpha rounded to float64: its transmittance
    # 1 - alpha carries an absolute error of ~1e-16, which r2 amplifies; compare transmittances
    mid = correct_opacity(a, r1)
    t_mid, t_once = 1.0 - mid, 1.0 - once
    # a relative error e in T_mid becomes r2 * e in T = T_mid ** r2 (first order)
    tol = 4 * r2 * 2.3e-16 / max(t_mid, 1e-300) * t_once + 1e-15
    assert abs((1.0 - twice) - t_once) <= tol


def test_transfer_function_keeps_extreme_alphas():
    """Table entries 0, 1e-7, 1-1e-7, 1 are looked up as stored; only the exact 0 is 'transparent'."""
    tf = TransferFunction(np.array([[1, 0, 0, a] for a in ALPHAS]), value_range=(0.0, 3.0))
    centres = (np.arange(4) + 0.5) / 4 * 3.0  # values that hit each texel centre
    rgba = tf.lookup(centres)
    np.testing.assert_array_equal(rgba[:, 3], np.asarray(ALPHAS, dtype=np.float32).astype(np.float64))
    assert np.all(np.isfinite(rgba))
    # ranges sitting on one texel: transparent only where alpha is exactly 0 (1e-7 must be drawn)
    ranges = np.stack([centres, centres], axis=1)
    np.testing.assert_array_equal(tf.transparent_mask(ranges), [True, False, False, False])


# -- rendering helpers -----------------------------------------------------------------------------

@pytest.fixture
def gl_clean(ctx):
    assert ctx.error == "GL_NO_ERROR"
    yield ctx
    assert ctx.error == "GL_NO_ERROR"


def render(ctx, vol, tf, *, mode="composite", step=0.5, brick=8, offset=(0.0, 0.0, 0.0), spacing=(1.0, 1.0, 1.0)):
    """Axis-aligned orthographic view along +z, one pixel per voxel; returns (image, loader, camera)."""
    from clipvol.render.action import ClipRenderAction

    loader = NumpyLoader(vol, brick=brick, spacing=spacing)
    pyr = loader.pyramid
    lo, hi = pyr.volume_box()
    Z, Y, X = vol.shape
    sz, sy, sx = spacing
    c = (lo + hi) / 2 + np.asarray(offset) * np.array([sx, sy, sz])
    cam = Camera.orthographic(c, (0, 0, 1), (0, -1, 0), X * sx, Y * sy, size=(X, Y))
    with ClipTexture(loader, "16MB", threads=2) as clip:
        # every brick in RAM first: which neighbours reach the GPU (open vs clamped faces) must not
        # depend on load timing (see test_stability_geometry::test_converged_render_independent_of_load_timing)
        assert clip.wait_until_idle(timeout=30)
        action = ClipRenderAction(ctx, clip, mode=mode, step=step)
        try:
            img = action.render(cam, tf, wait=True, timeout=20)
            for _ in range(3):  # see test_stability_faults.py::test_wait_survives_slow_upload (a race in wait)
                if action.last_frame_stats.converged:
                    break
                img = action.render(cam, tf, wait=True, timeout=20)
            assert action.last_frame_stats.converged
        finally:
            action.close()
    return img, loader, cam.fit_depth(lo, hi)


def reference(vol, loader, cam, tf, mode="composite", step=0.5):
    pyr = loader.pyramid
    with np.errstate(invalid="ignore", over="ignore"):
        prem = ref.raycast(vol, pyr.spacing, cam, tf.table, tf.window(pyr.value_range), step, mode)
    return ref.to_uint8(prem)


def _diff(a, b):
    return np.abs(a.astype(np.int64) - b.astype(np.int64))


# -- opacity through the renderer -----------------------------------------------------------------
@pytest.mark.gl
@pytest.mark.parametrize("step", [1e-3, 0.01, 0.5, 2.0, 8.0])
def test_render_opacity_correction_is_step_invariant(gl_clean, step):
    """Constant data, alpha 0.02 per voxel: the image alpha is 1-(0.98)^depth for every ratio 1e-3..8."""
    Z = 16
    vol = np.full((Z, 6, 6), 0.5, dtype=np.float32)
    tf = TransferFunction.from_points([(0.0, (1, 1, 1, 0.02)), (1.0, (1, 1, 1, 0.02))])
    img, _, _ = render(gl_clean, vol, tf, step=step, brick=8)
    want = round((1 - 0.98**Z) * 255)
    assert np.all(np.abs(img[..., 3].astype(int) - want) <= 1), (img[..., 3].min(), img[..., 3].max(), want)


@pytest.mark.gl
@pytest.mark.parametrize("alpha", [1e-7, 1.0 - 1e-7])
def test_render_extreme_alpha_no_nan(gl_clean, alpha):
    """Near-0 alpha gives an invisible (not NaN/black-hole) image; near-1 alpha gives an opaque one."""
    vol = np.random.default_rng(3).random((12, 10, 14)).astype(np.float32)
    tf = TransferFunction.from_points([(0.0, (0.2, 0.6, 1.0, alpha)), (1.0, (0.2, 0.6, 1.0, alpha))])
    for step in (1e-2, 0.5, 4.0):
        img, loader, cam = render(gl_clean, vol, tf, step=step)
        want = reference(vol, loader, cam, tf, step=step)
        assert _diff(img, want).max() <= 1
        assert np.all(img[..., 3] == (0 if alpha < 0.5 else 255))


@pytest.mark.gl
def test_render_opaque_front_surface_only(gl_clean):
    """Alpha exactly 1 everywhere: each pixel is the transfer function of the first plane; what is
    behind it does not matter."""
    rng = np.random.default_rng(7)
    front = rng.random((10, 14))
    vol = rng.random((12, 10, 14))
    vol[:2] = front  # two identical planes: the first samples (z = 0 .. 0.5) read exactly `front`
    vol = vol.astype(np.float32)
    tf = TransferFunction.from_points([(0.0, (0, 0, 1, 1.0)), (1.0, (1, 1, 0, 1.0))])
    img, loader, _ = render(gl_clean, vol, tf)
    rgba = tf.lookup(front.astype(np.float32), loader.pyramid.value_range)
    want = np.rint(rgba * 255).astype(np.uint8)
    assert np.all(img[..., 3] == 255)
    assert _diff(img, want).max() <= 1
    # a different interior gives the same picture
    vol2 = vol.copy()
    vol2[2:] = rng.random(vol2[2:].shape).astype(np.float32)
    vol2[2:, 0, 0] = vol.min()  # keep the value range identical
    vol2[2:, 0, 1] = vol.max()
    img2, _, _ = render(gl_clean, vol2, tf)
    assert _diff(img, img2).max() <= 1


# -- data values -----------------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", INT_DTYPES)
def test_integer_mean_exact_at_full_range(dtype):
    """The 2x2x2 mean of dtype min/max extremes equals floor((sum + 4) / 8) in Python integers."""
    info = np.iinfo(dtype)
    rng = np.random.default_rng(11)
    vol = np.where(rng.random((6, 5, 7)) < 0.5, info.min, info.max).astype(dtype)
    vol[0, 0, 0], vol[1, 1, 1] = info.min + 1, info.max - 1
    got = downsample(vol, "mean")
    pad = np.pad(vol, [(0, s % 2) for s in vol.shape], mode="edge").astype(object)
    blocks = pad.reshape(3, 2, 3, 2, 4, 2)
    s = blocks.sum(axis=(1, 3, 5))
    want = np.vectorize(lambda v: (v + 4) // 8, otypes=[object])(s)
    assert got.dtype == np.dtype(dtype)
    assert [int(v) for v in got.ravel()] == [int(v) for v in want.ravel()]
    loader = NumpyLoader(vol, brick=4)
    assert loader.pyramid.value_range == (float(vol.min()), float(vol.max()))


@pytest.mark.gl
@pytest.mark.parametrize("dtype", INT_DTYPES)
def test_render_integer_full_range(gl_clean, dtype):
    """dtype min/max in one volume: MIP equals numpy's max projection, composite equals the reference."""
    info = np.iinfo(dtype)
    rng = np.random.default_rng(5)
    v = rng.random((12, 10, 14))
    vol = np.where(v > 0.7, info.max, np.where(v < 0.3, info.min, 0 if info.min < 0 else info.max // 2)).astype(dtype)
    img, loader, cam = render(gl_clean, vol, GREY, mode="mip")
    want = np.rint(GREY.lookup(vol.max(axis=0).astype(np.float64), loader.pyramid.value_range) * 255).astype(np.uint8)
    assert _diff(img, want).max() <= 1
    img, loader, cam = render(gl_clean, vol, GREY)
    assert _diff(img, reference(vol, loader, cam, GREY)).max() <= 2


@pytest.mark.gl
@pytest.mark.parametrize("dtype", FLOAT_DTYPES)
def test_render_float_nan_inf_transparent(gl_clean, dtype):
    """NaN and +-Inf voxels are transparent: the value range ignores them, no NaN reaches the image,
    pixels away from them are unaffected, and with every trilinear weight non-zero (samples off the
    voxel centres) the image equals the reference that drops non-finite samples."""
    rng = np.random.default_rng(9)
    vol = rng.random((12, 10, 14)).astype(dtype)
    bad = [(3, 2, 4, np.nan), (5, 6, 9, np.inf), (7, 1, 1, -np.inf)]
    for z, y, x, val in bad:
        vol[z, y, x] = val
    loader = NumpyLoader(vol, brick=8)
    lo, hi = loader.pyramid.value_range
    fin = vol[np.isfinite(vol)]
    assert (lo, hi) == (float(fin.min()), float(fin.max()))
    tf = TransferFunction.preset("viridis")
    clean = np.ones(vol.shape[1:], bool)  # pixel columns whose samples never touch a non-finite voxel
    for _, y, x, _ in bad:
        clean[max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2] = False
    # on the voxel centres: MIP equals numpy's max projection, composite the reference (clean columns)
    img, loader, cam = render(gl_clean, vol, tf, mode="mip")
    m = np.where(np.isfinite(vol), vol, -np.inf).astype(np.float64).max(axis=0)
    want = np.rint(tf.lookup(m, (lo, hi)) * 255).astype(np.uint8)
    assert _diff(img, want)[clean].max() <= 1
    assert np.all(img[..., 3] > 0)  # no column went missing
    img, loader, cam = render(gl_clean, vol, tf)
    assert _diff(img, reference(vol, loader, cam, tf))[clean].max() <= 2
    # off the voxel centres every trilinear weight is non-zero, so "a sample touching a non-finite
    # voxel is transparent" is unambiguous: the whole image equals the reference
    off = (0.25, 0.25, 0.25)
    for mode in ("mip", "composite"):
        img, loader, cam = render(gl_clean, vol, tf, offset=off, mode=mode)
        assert _diff(img, reference(vol, loader, cam, tf, mode=mode)).max() <= 2, mode


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["mip", "composite"])
@pytest.mark.parametrize("dtype,scale", [("float16", 5e-5), ("float32", 1e-39), ("float64", 1e-310)])
def test_render_float_denormal_range(gl_clean, mode, dtype, scale):
    """All data denormal in its own dtype: the window's 1/(hi-lo) overflows float32 if computed on
    the GPU, and GPUs flush float32 denormals to 0; the image must still equal the reference."""
    vol = (np.random.default_rng(2).random((12, 10, 14)) * scale).astype(dtype)
    assert np.all(np.abs(vol) < np.finfo(dtype).tiny)
    img, loader, cam = render(gl_clean, vol, GREY, mode=mode)
    if mode == "mip":
        want = np.rint(GREY.lookup(vol.max(axis=0).astype(np.float64), loader.pyramid.value_range) * 255).astype(np.uint8)
    else:
        want = reference(vol, loader, cam, GREY)
    assert want[..., 3].max() > 0
    assert _diff(img, want).max() <= 2


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["mip", "composite"])
def test_render_float64_huge_magnitudes(gl_clean, mode):
    """float64 values of +-1e300 (beyond float32): normalised before they reach the GPU."""
    vol = (np.random.default_rng(4).random((12, 10, 14)) - 0.5) * 2e300
    img, loader, cam = render(gl_clean, vol, GREY, mode=mode)
    if mode == "mip":
        want = np.rint(GREY.lookup(vol.max(axis=0), loader.pyramid.value_range) * 255).astype(np.uint8)
    else:
        want = reference(vol, loader, cam, GREY)
    assert _diff(img, want).max() <= 2


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["mip", "composite"])
def test_render_all_negative(gl_clean, mode):
    vol = -(np.random.default_rng(6).random((12, 10, 14)) * 100 + 1)
    img, loader, cam = render(gl_clean, vol, GREY, mode=mode)
    assert loader.pyramid.value_range[1] < 0
    if mode == "mip":
        want = np.rint(GREY.lookup(vol.max(axis=0), loader.pyramid.value_range) * 255).astype(np.uint8)
    else:
        want = reference(vol, loader, cam, GREY)
    assert _diff(img, want).max() <= 1


def test_constant_volume_normalises_without_division():
    """Zero-width data range: t = 0.5 (the step) at the value, 0 below, 1 above; never NaN/Inf."""
    vol = np.full((9, 10, 11), 3.5, np.float32)
    loader = NumpyLoader(vol, brick=4)
    assert loader.pyramid.value_range == (3.5, 3.5)
    with np.errstate(all="raise"):
        t = GREY.normalise(np.array([3.0, 3.5, 4.0, np.nan]), loader.pyramid.value_range)
        rgba = GREY.lookup(np.array([3.0, 3.5, 4.0]), loader.pyramid.value_range)
        step = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.25, (0, 0, 0, 0)), (1.0, (1, 1, 1, 1))])
        mask = step.transparent_mask([[3.5, 3.5], [0.0, 3.0]], loader.pyramid.value_range)
    np.testing.assert_array_equal(t, [0.0, 0.5, 1.0, 0.0])
    assert np.all(np.isfinite(rgba))
    np.testing.assert_array_equal(mask, [False, True])


@pytest.mark.gl
@pytest.mark.parametrize("value", [0.0, 3.5, -2.0])
@pytest.mark.parametrize("mode", ["mip", "composite"])
def test_render_constant_volume(gl_clean, mode, value):
    """MIP and composite of constant data: every pixel is the transfer function at t = 0.5."""
    vol = np.full((9, 10, 11), value, np.float32)
    tf = TransferFunction.preset("viridis")
    img, loader, cam = render(gl_clean, vol, tf, mode=mode)
    if mode == "mip":
        want = np.rint(tf.lookup(vol.max(axis=0), loader.pyramid.value_range) * 255).astype(np.uint8)
    else:
        want = reference(vol, loader, cam, tf)
    assert np.all(want[..., 3] > 0)  # the reference is not trivially empty
    assert _diff(img, want).max() <= 1
