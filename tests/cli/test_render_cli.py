"""``clipvol render``: writes the PNG the action renders, prints frame statistics, refuses bad input."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl


def test_render_writes_png_matching_the_action(tmp_path, capsys):
    out = tmp_path / "img.png"
    rc = main(["render", "procedural:fractal?size=40", "--brick", "16", "--out", str(out), "--size", "64x48",
               "--view", "front", "--ortho", "--mode", "mip", "--selection", "fixed", "--tf-points", "0:0,0,0,0;1:1,1,1,1"])
    assert rc == 0
    img = np.asarray(Image.open(out))
    assert img.shape == (48, 64, 4)
    err = capsys.readouterr().err
    assert "bricks drawn" in err and "converged True" in err
    # independent check: the front orthographic MIP of the procedural volume through the grey TF
    from clipvol.bricking.generators import parse_procedural

    vol = parse_procedural("procedural:fractal?size=40").region(0, (0, 0, 0), (40, 40, 40))
    mip = vol.max(axis=0)
    lo, hi = 0.0, 1.0  # the procedural generators' declared value range
    t = np.clip((mip - lo) / (hi - lo), 0, 1)
    # the 40x40 volume fills the central columns of the 64x48 image (framing is 1.05 x diagonal)
    drawn = img[..., 3] > 0
    assert drawn.any() and not drawn.all()
    # grey points from 0 to 1: alpha == t of the ray's maximum; pixel centres fall between voxel centres, so the
    # image's alphas lie within the MIP's range and come close to its maximum
    a = img[..., 3][drawn].astype(float)
    assert a.max() <= t.max() * 255 + 1 and a.min() >= t.min() * 255 - 1
    assert a.max() >= 0.95 * t.max() * 255


def test_render_refuses_bad_arguments(tmp_path, capsys):
    assert main(["render", "procedural:fractal?size=16", "--out", str(tmp_path / "x.jpg")]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["render", "procedural:fractal?size=16", "--out", str(tmp_path / "x.png"), "--tf", "nope"]) == 2
    assert "--tf" in capsys.readouterr().err
    assert main(["render", str(tmp_path / "missing.zarr"), "--out", str(tmp_path / "x.png")]) == 2
