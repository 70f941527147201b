"""GPU brick cache arithmetic without GL: window allocation under the budget, texel formats."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.render.gpu_cache import allocate_gpu_windows, convert_brick, texture_format


def _bytes(pyr, windows, itemsize):
    bb = int(np.prod(pyr.brick_shape)) * itemsize
    return sum(int(np.prod(w)) * bb for w in windows if w is not None)


@pytest.mark.parametrize("shape", [(640, 640, 640), (17, 1000, 3), (1, 1, 1), (300, 200, 100)])
def test_windows_fit_the_budget_and_grow_with_it(shape):
    pyr = Pyramid.build(shape, (32, 32, 32))
    bb = 32**3 * 4
    prev = -1
    for budget in [bb, 3 * bb, 10 * bb, 100 * bb, 1000 * bb, 10**10]:
        w = allocate_gpu_windows(pyr, budget, 4)
        used = _bytes(pyr, w, 4)
        assert used <= budget
        assert w[-1] is not None  # the coarsest level always has a texture
        for L, wl in enumerate(w):
            if wl is not None:
                assert all(1 <= a <= g for a, g in zip(wl, pyr.grid(L)))
                assert int(np.prod(wl)) * bb <= 1 << 30  # one texture at most 1 GiB
        assert used >= prev  # more budget never means fewer texels
        prev = used
    # a budget that holds everything holds every level whole (up to the per-texture cap)
    w = allocate_gpu_windows(pyr, 10**12, 4)
    for L, wl in enumerate(w):
        if int(np.prod(pyr.grid(L))) * bb <= 1 << 30:
            assert wl == pyr.grid(L)


def test_tight_budget_serves_coarse_levels_first_and_refuses_less_than_a_brick():
    pyr = Pyramid.build((256, 256, 256), (32, 32, 32))  # 4 levels
    bb = 32**3 * 2
    w = allocate_gpu_windows(pyr, 2 * bb, 2)
    assert w[-1] == (1, 1, 1) and w[-2] == (1, 1, 1) and w[0] is None
    with pytest.raises(ParameterError, match="texture_budget"):
        allocate_gpu_windows(pyr, bb - 1, 2)


@pytest.mark.parametrize("dtype", ["uint8", "int8", "uint16", "int16", "int32", "uint64", "float16", "float32", "float64"])
def test_texel_formats_map_back_to_the_values(dtype):
    rng = np.random.default_rng(0)
    dt = np.dtype(dtype)
    if dt.kind in "iu":
        info = np.iinfo(dt)
        lo, hi = max(info.min, -(2**40)), min(info.max, 2**40)
        brick = rng.integers(lo, hi, size=(4, 5, 6), endpoint=True).astype(dt)
    else:
        brick = (rng.random((4, 5, 6)) * 200 - 50).astype(dt)
    vr = (float(brick.min()), float(brick.max()))
    fmt = texture_format(dt, vr)
    tex = convert_brick(brick, fmt)
    assert tex.flags.c_contiguous and tex.shape == brick.shape
    assert tex.dtype == {"f1": np.uint8, "nu2": np.uint16, "f4": np.float32}[fmt.gl_dtype]
    # the shader sees normalised integers (value / max) or floats
    texel = tex / 255.0 if fmt.gl_dtype == "f1" else tex / 65535.0 if fmt.gl_dtype == "nu2" else tex.astype(np.float64)
    back = fmt.a * texel + fmt.b
    span = max(vr[1] - vr[0], 1.0)
    np.testing.assert_allclose(back, brick.astype(np.float64), atol=span * 2e-7 + (1e-3 if dt.itemsize <= 2 else 0), rtol=1e-6)


def test_float_ranges_float32_cannot_handle_are_normalised():
    tiny = texture_format(np.float32, (0.0, 1e-39))
    const = texture_format(np.float32, (3.5, 3.5))
    ok = texture_format(np.float32, (-5.0, 7.0))
    assert (ok.a, ok.b) == (1.0, 0.0)  # raw values, no conversion
    assert tiny.a == 1e-39 and const.b == 3.5
    brick = np.full((2, 2, 2), 3.5, np.float32)
    assert np.all(convert_brick(brick, const) == 0.0)
    nan = np.array([[[np.nan, 1.0]]], dtype=np.float64)
    assert np.isnan(convert_brick(nan, texture_format(np.float64, (0.0, 1.0)))[0, 0, 0])
