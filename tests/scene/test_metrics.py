"""Image metrics against published CIELUV values and direct numpy formulas."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.scene.metrics import (
    composite,
    delta_e_luv,
    percent_delta_e,
    psnr,
    rgb_to_luv,
    rmse,
    srgb_to_linear,
)

# sRGB primaries in CIE L*u*v* (D65), as published e.g. by Bruce Lindbloom's calculator
PUBLISHED = {
    (1.0, 1.0, 1.0): (100.0, 0.0, 0.0),
    (0.0, 0.0, 0.0): (0.0, 0.0, 0.0),
    (1.0, 0.0, 0.0): (53.2408, 175.0151, 37.7564),
    (0.0, 1.0, 0.0): (87.7347, -83.0776, 107.3985),
    (0.0, 0.0, 1.0): (32.2970, -9.4054, -130.3423),
}


@pytest.mark.parametrize("rgb", list(PUBLISHED))
def test_luv_of_known_colours(rgb):
    np.testing.assert_allclose(rgb_to_luv(np.array(rgb)), PUBLISHED[rgb], atol=0.02)


def test_srgb_curve_and_grey_axis():
    c = np.linspace(0, 1, 101)
    ref = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(srgb_to_linear(c), ref)
    luv = rgb_to_luv(np.repeat(c[:, None], 3, axis=1))
    np.testing.assert_allclose(luv[:, 1:], 0, atol=1e-9)  # greys are neutral
    assert np.all(np.diff(luv[:, 0]) > 0)
    # L* of mid-grey 0.5 (sRGB 128/255 ~ 53.585 published for 128)
    assert rgb_to_luv(np.array([128, 128, 128], dtype=np.uint8))[0] == pytest.approx(53.585, abs=0.01)


def test_delta_e_symmetric_zero_on_identity_and_euclidean():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, size=(16, 20, 4), dtype=np.uint8)
    b = rng.integers(0, 256, size=(16, 20, 4), dtype=np.uint8)
    d = delta_e_luv(a, b)
    assert d.shape == (16, 20) and np.all(d >= 0)
    np.testing.assert_allclose(d, delta_e_luv(b, a))
    np.testing.assert_array_equal(delta_e_luv(a, a), 0)
    ref = np.linalg.norm(rgb_to_luv(composite(a)) - rgb_to_luv(composite(b)), axis=-1)
    np.testing.assert_allclose(d, ref)
    assert delta_e_luv(np.array([[[255, 255, 255]]], np.uint8), np.array([[[0, 0, 0]]], np.uint8))[0, 0] == pytest.approx(100)


def test_compositing_over_background():
    px = np.array([[[100, 50, 0, 128]]], dtype=np.uint8)
    bg = (0.2, 0.4, 0.6)
    a = 128 / 255
    np.testing.assert_allclose(composite(px, bg)[0, 0], np.array([100, 50, 0]) / 255 + np.array(bg) * (1 - a))
    np.testing.assert_allclose(composite(px, bg, premultiplied=False)[0, 0], np.array([100, 50, 0]) / 255 * a + np.array(bg) * (1 - a))
    # over black, premultiplied RGBA equals its RGB
    np.testing.assert_allclose(delta_e_luv(px, px[..., :3].copy()), 0)


def test_percent_rmse_psnr():
    a = np.zeros((10, 10, 4), dtype=np.uint8)
    a[..., 3] = 255
    b = a.copy()
    b[:3, :, 0] = 255  # 30 pixels bright red: Delta E ~ 176
    b[5, :2, 1] = 1  # 2 pixels imperceptibly different
    assert percent_delta_e(a, b) == pytest.approx(30.0)
    assert percent_delta_e(a, a) == 0.0
    ref = np.sqrt(np.mean((a[..., :3].astype(float) - b[..., :3].astype(float)) ** 2))
    assert rmse(a, b) == pytest.approx(ref)
    assert psnr(a, b) == pytest.approx(20 * np.log10(255 / ref))
    assert psnr(a, a) == float("inf")


def test_shape_mismatch_is_an_error():
    with pytest.raises(ParameterError):
        delta_e_luv(np.zeros((4, 4, 4), np.uint8), np.zeros((4, 5, 4), np.uint8))
    with pytest.raises(ParameterError):
        rgb_to_luv(np.zeros((4, 2)))
