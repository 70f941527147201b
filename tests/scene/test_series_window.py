"""A time series gets one automatic contrast window for all its steps (brightness comparable
across t), from every step's statistics: the window of a dim step equals the bright step's, and
both are the window of the histogram numpy takes over all steps' values together."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from clipvol.paging.open import open_store
from clipvol.scene.auto_tf import ValueHistogram, auto_window
from clipvol.tools.cli import main


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    d = tmp_path_factory.mktemp("series")
    z, y, x = np.mgrid[0:24, 0:20, 0:22].astype(np.float32)
    blob = np.exp(-((z - 12) ** 2 + (y - 10) ** 2 + (x - 11) ** 2) / 30.0)
    steps = np.stack([blob * 1000 * (1.0 - 0.4 * k) for k in range(3)]).astype(np.float32)  # fading
    np.save(d / "s.npy", steps)
    assert main(["brick", str(d / "s.npy"), str(d / "s.zarr"), "--brick", "8", "--axes", "tzyx", "--quiet"]) == 0
    return d / "s.zarr", steps


def _args(**kw):
    base = dict(tf="auto", tf_range=None, window=None, opacity=None, tf_points=None, overlay=None)
    return argparse.Namespace(**{**base, **kw})


def test_every_step_gets_the_series_window(series):
    from clipvol.tools.tf_args import transfer_function_from_args

    root, steps = series
    tfs = [transfer_function_from_args(_args(), open_store(root, t=k)) for k in range(3)]
    assert tfs[0].value_range == tfs[1].value_range == tfs[2].value_range
    # the reference: numpy's histogram of every step's voxels together, over the series' range
    edges = np.linspace(float(steps.min()), float(steps.max()), 65)
    counts = np.histogram(steps.ravel(), bins=edges)[0]
    want = auto_window(ValueHistogram(counts, edges, 0, False)).window
    width = edges[1] - edges[0]
    np.testing.assert_allclose(tfs[2].value_range, want, atol=2 * width)
    # a preset without a range spans the series' range at every step, not the step's own
    grey = [transfer_function_from_args(_args(tf="grey"), open_store(root, t=k)) for k in (0, 2)]
    assert grey[0].value_range == grey[1].value_range == (float(steps.min()), float(steps.max()))


@pytest.mark.gl
def test_a_dim_step_renders_dimmer(series, tmp_path):
    """Under one window the last step (0.2 of the first's values) draws darker than the first."""
    from PIL import Image

    root, _ = series
    imgs = []
    for k in (0, 2):
        out = tmp_path / f"t{k}.png"
        assert main(["render", str(root), "--t", str(k), "--out", str(out), "--size", "40x40"]) == 0
        imgs.append(np.asarray(Image.open(out).convert("RGBA")).astype(float))
    assert imgs[1][..., 3].sum() < 0.8 * imgs[0][..., 3].sum()
