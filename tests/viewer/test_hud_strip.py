"""The HUD's histogram strip: bars where the data are, the opacity curve where the TF says."""

from __future__ import annotations

import numpy as np

from clipvol.scene.transfer import TransferFunction
from clipvol.viewer.hud import stack_images, tf_strip


def test_strip_draws_histogram_bars_opacity_curve_and_window_ticks():
    counts = np.zeros(64, dtype=np.int64)
    counts[10] = 1000  # one populated bin
    edges = np.linspace(0.0, 64.0, 65)
    tf = TransferFunction.preset("grey", value_range=(32.0, 48.0), opacity="step")  # opaque from 40
    img = tf_strip(counts, edges, tf, (0.0, 64.0), width=134, height=60, padding=3)
    assert img.shape == (60, 134, 4)
    x0, x1 = 3, 131
    col = lambda v: x0 + int((v / 64.0) * (x1 - x0))  # noqa: E731
    grey = (img[..., 0] == 110) & (img[..., 1] == 110) & (img[..., 2] == 110)
    # bars only over bin 10 (values 10..11)
    bar_cols = np.flatnonzero(grey.any(axis=0))
    assert bar_cols.size and bar_cols.min() >= col(10) - 1 and bar_cols.max() <= col(11) + 1
    # the white opacity curve is at the bottom below 40 and at the top above it
    white = (img[..., :3] == 255).all(axis=-1)
    top, base = 3, 60 - 3 - 8 - 1
    assert white[base, col(20)] and not white[top, col(20)]
    assert white[top, col(44)] and not white[base, col(44)]
    # yellow ticks at the window's ends
    yellow = (img[..., 0] == 255) & (img[..., 1] == 220) & (img[..., 2] == 0)
    ticks = np.flatnonzero(yellow.any(axis=0))
    assert set(ticks.tolist()) == {col(32), col(48)}
    s = stack_images([img, np.full((5, 10, 4), 7, np.uint8)])
    assert s.shape == (65, 134, 4) and (s[60:, :10] == 7).all() and (s[60:, 10:] == 0).all()
