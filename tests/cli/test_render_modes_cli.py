"""``clipvol render --mode minip|average|iso``: the modes reach the renderer from the command line,
and a mode that needs a value refuses to run without it."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl


def _sphere(tmp_path, n=32, R=10.0):
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    vol = (20.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)  # >= 20 - R inside
    p = tmp_path / "sphere.npy"
    np.save(p, vol)
    return p, vol


def test_iso_surface_of_a_sphere_is_an_opaque_disc(tmp_path):
    src, _ = _sphere(tmp_path)
    out = tmp_path / "iso.png"
    rc = main(["render", str(src), "--brick", "16", "--out", str(out), "--size", "96x96", "--view", "front", "--ortho",
               "--mode", "iso", "--iso-value", "10", "--policy", "fixed"])
    assert rc == 0
    img = np.asarray(Image.open(out))
    drawn = img[..., 3] == 255
    assert ((img[..., 3] == 0) | drawn).all()  # opaque surface or nothing
    rows, cols = np.nonzero(drawn)
    h, w = rows.max() - rows.min() + 1, cols.max() - cols.min() + 1
    assert abs(h - w) <= 2  # a disc: as high as wide, and filling pi/4 of its bounding square
    assert abs(drawn.sum() / (h * w) - np.pi / 4) < 0.05
    # lit from the eye: the disc's centre faces the view, brighter than its rim
    cy, cx = (rows.min() + rows.max()) // 2, (cols.min() + cols.max()) // 2
    assert img[cy, cx, :3].astype(int).sum() > img[rows[0], cols[0], :3].astype(int).sum()


@pytest.mark.parametrize("command", ["render", "view"])
@pytest.mark.parametrize("where", ["above", "below"])
def test_iso_value_outside_the_data_is_refused_naming_the_range(tmp_path, capsys, command, where):
    # above the maximum no ray hits (an empty image), at the minimum every ray hits at once (an
    # opaque box): exit 0 with such a picture says nothing; the range comes from numpy
    src, vol = _sphere(tmp_path)
    iso = float(vol.max()) + 1.0 if where == "above" else float(vol.min())
    out = tmp_path / ("frames" if command == "view" else "none.png")
    extra = ["--offscreen", "--frames", "1"] if command == "view" else []
    assert main([command, str(src), "--brick", "16", "--size", "48x48", "--mode", "iso", "--iso-value", str(iso),
                 "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert "iso" in err and f"{float(vol.min()):g}" in err and f"{float(vol.max()):g}" in err, err
    assert not out.exists()


def test_iso_without_a_value_is_refused(tmp_path, capsys):
    src, _ = _sphere(tmp_path)
    assert main(["render", str(src), "--out", str(tmp_path / "x.png"), "--mode", "iso"]) == 2
    assert "iso_value" in capsys.readouterr().err


@pytest.mark.parametrize("mode", ["minip", "average"])
def test_projection_modes_draw_the_volume_footprint(tmp_path, mode):
    """Every ray through the volume has samples: a projection covers the volume's whole footprint
    (the front orthographic view of a cube is a square) and nothing beside it."""
    src, vol = _sphere(tmp_path)
    out = tmp_path / f"{mode}.png"
    assert main(["render", str(src), "--brick", "16", "--out", str(out), "--size", "64x64", "--view", "front",
                 "--ortho", "--mode", mode, "--tf-points", "0:1,1,1,1;1:1,1,1,1"]) == 0
    a = np.asarray(Image.open(out))[..., 3] > 0
    rows, cols = np.nonzero(a)
    assert a[rows.min():rows.max() + 1, cols.min():cols.max() + 1].all()
    assert abs((rows.max() - rows.min()) - (cols.max() - cols.min())) <= 1
    assert not a.all()


def test_view_offscreen_draws_the_iso_surface(tmp_path):
    """``clipvol view --offscreen --mode iso --iso-value``: every frame shows the surface (opaque
    pixels only, and some of them) - the mode and its value reach the viewer's session."""
    src, _ = _sphere(tmp_path)
    out = tmp_path / "frames"
    assert main(["view", str(src), "--brick", "16", "--offscreen", "--path", "orbit", "--frames", "2", "--size", "40x30",
                 "--mode", "iso", "--iso-value", "10", "--out", str(out)]) == 0
    pngs = sorted(out.glob("frame_*.png"))
    assert len(pngs) == 2
    for p in pngs:
        a = np.asarray(Image.open(p))[..., 3]
        assert ((a == 0) | (a == 255)).all() and (a == 255).sum() > 20
