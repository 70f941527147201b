"""The straight-alpha RGBA that `render` returns: colour 0 wherever the 8-bit alpha is 0."""

from __future__ import annotations

import numpy as np

from clipvol.render.paths.setup import premultiplied_to_uint8


def test_colour_is_zero_where_alpha_rounds_to_zero():
    prem = np.zeros((1, 4, 4), np.float32)
    prem[0, 0] = (0.001, 0.001, 0.001, 0.001)  # a faint full-white sample: alpha 0.255 of an 8-bit step
    prem[0, 1] = (0.0, 0.0, 0.0, 0.0)
    prem[0, 2] = (0.5, 0.25, 0.0, 0.5)
    prem[0, 3] = (0.0025, 0.0, 0.0, 0.0025)  # alpha 0.6375 of a step: rounds to 1, keeps its colour
    out = premultiplied_to_uint8(prem)
    alpha = np.rint(np.clip(prem[..., 3], 0, 1) * 255)
    np.testing.assert_array_equal(out[..., 3], alpha)
    assert (out[alpha == 0][:, :3] == 0).all()
    np.testing.assert_array_equal(out[0, 2], [255, 128, 0, 128])
    np.testing.assert_array_equal(out[0, 3], [255, 0, 0, 1])
