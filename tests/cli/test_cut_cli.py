"""``--crop-voxels`` / ``--clip-plane`` on ``clipvol slice`` and ``clipvol view --offscreen``: values
inside the cut are the source's, outside NaN (slice); the offscreen frame changes with the cut."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

SRC = "procedural:fractal?size=48"


def _source():
    from clipvol.bricking.generators import parse_procedural

    return parse_procedural(SRC).region(0, (0, 0, 0), (48, 48, 48))


def test_slice_keeps_the_cut_and_leaves_the_rest_out(tmp_path, capsys):
    npy, out = tmp_path / "s.npy", tmp_path / "s.png"
    rc = main(["slice", SRC, "--brick", "16", "--plane", "y=20", "--level", "0", "--npy", str(npy), "--out", str(out),
               "--window", "0.5,1", "--crop-voxels", "5:30,:,10:40", "--clip-plane", "0,0,20,1,0,1"])
    assert rc == 0, capsys.readouterr().err
    v = np.load(npy)
    ref = _source()[:, 20, :][::-1]  # coronal: superior (high z) at the top; rows z = 47 - r, columns x
    z = 47 - np.arange(48)[:, None] + np.zeros((1, 48))
    x = np.arange(48)[None, :] + np.zeros((48, 1))
    # inside: z in 10..39, x in 5..29 (voxel cells, centres strictly inside), and x + z >= 20
    inside = (z >= 10) & (z <= 39) & (x >= 5) & (x <= 29) & (x + z - 20 >= 0)
    on_plane = x + z == 20  # exactly on the plane: a float rounding decides, either is right
    keep, drop = inside & ~on_plane, ~inside & ~on_plane
    assert keep.sum() > 200 and drop.sum() > 200
    assert np.all(np.isnan(v[drop]))
    assert np.max(np.abs(v[keep] - ref[keep])) <= 1e-6
    img = np.asarray(Image.open(out))
    assert np.all(img[drop][:, 3] == 0) and np.all(img[keep][:, 3] == 255)


def test_view_offscreen_draws_the_cut(tmp_path, capsys):
    base = ["view", SRC, "--brick", "16", "--offscreen", "--frames", "1", "--size", "48x48", "--converged"]
    assert main(base + ["--out", str(tmp_path / "a")]) == 0
    assert main(base + ["--out", str(tmp_path / "b"), "--crop-voxels", ":,:,0:24"]) == 0
    a = np.asarray(Image.open(next((tmp_path / "a").glob("*.png")))).astype(int)
    b = np.asarray(Image.open(next((tmp_path / "b").glob("*.png")))).astype(int)
    assert np.abs(a - b).max() > 50
    assert main(base + ["--out", str(tmp_path / "c"), "--clip-plane", "0,0,0,0,0,0"]) == 2
    assert "--clip-plane" in capsys.readouterr().err
