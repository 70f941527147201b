"""Projections (``--mode mip|minip|average``) with the automatic transfer function show something:
their own values fill the table and its opacity, so the brightest MIP ray is opaque and an average
projection is not a faint fog (before: MIP opacity at most 0.6, the average's median 11/255, the
minIP almost empty).

Reference: numpy's own projections of the volume (``max``/``min``/``mean`` along z, the axis the
``front`` view looks along): where they are high (low for minIP) the image is opaque, where they
are the background it is clear.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytest.importorskip("moderngl")

N = 40


def _ball() -> np.ndarray:
    z, y, x = np.meshgrid(*(np.arange(N, dtype=np.float64),) * 3, indexing="ij")
    r = np.sqrt((x - 19.5) ** 2 + (y - 19.5) ** 2 + (z - 19.5) ** 2)
    return np.where(r < 16, 20 + 80 * (1 - r / 16), 0.0).astype(np.float32)  # bright core, dark air


def _tube() -> np.ndarray:
    v = np.full((N, N, N), 100.0, np.float32)
    y, x = np.mgrid[:N, :N]
    v[:, (x - 14) ** 2 + (y - 22) ** 2 < 25] = 10.0  # a low tube along z: what a minIP is for
    return v


def _render(tmp_path, vol, mode) -> np.ndarray:
    src = tmp_path / f"{mode}.npy"
    np.save(src, vol)
    out = tmp_path / f"{mode}.png"
    assert main(["render", str(src), "--store", str(tmp_path / f"{mode}.zarr"), "--mode", mode, "--view", "front",
                 "--ortho", "--size", "64x64", "--out", str(out)]) == 0
    return np.asarray(Image.open(out).convert("RGBA"))[..., 3] / 255.0


@pytest.mark.parametrize("mode, reduce", [("mip", np.max), ("average", np.mean)])
def test_mip_and_average_are_opaque_where_the_projection_is_high(tmp_path, mode, reduce):
    vol = _ball()
    proj = reduce(vol, axis=0)
    assert proj.max() > 40 and proj[0, 0] == 0  # numpy: a bright disc in air
    a = _render(tmp_path, vol, mode)
    assert a.max() >= 0.98  # the brightest rays opaque (before: <= 0.6 for MIP)
    hit = a > 0
    assert np.median(a[hit]) >= 0.3  # (before: 11/255 for the average)
    assert a[0, 0] == 0 and a[32, 32] > a[32, 20] > 0  # air clear; the centre (brightest) more opaque than the rim


def test_minip_is_opaque_where_the_projection_is_low(tmp_path):
    vol = _tube()
    proj = vol.min(axis=0)
    assert proj.min() == 10 and proj.max() == 100  # numpy: the tube's disc, low, in a high field
    a = _render(tmp_path, vol, "minip")
    assert a.max() >= 0.98  # the tube opaque (before: almost empty)
    assert (a > 0.9).sum() >= 40 and (a < 0.1).mean() > 0.5  # the tube's disc opaque, the rest clear
