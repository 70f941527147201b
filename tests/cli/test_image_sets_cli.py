"""The root of a 4-D ``clipvol brick`` (``--axes czyx`` or ``tzyx``) is one thing: ``info`` describes
every member and exits 0, ``render ROOT --t K`` / ``--c K`` draws exactly what rendering the member's
own store draws, ``view --offscreen`` opens it, and ``--axes`` on a 3-D input exits 2 naming it."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    d = tmp_path_factory.mktemp("sets")
    z, y, x = np.mgrid[0:16, 0:14, 0:18].astype(np.float32)
    steps = [np.exp(-((z - 8) ** 2 + (y - 7) ** 2 + (x - 4 - 5 * k) ** 2) / 12.0) for k in range(3)]
    np.save(d / "blob.npy", np.stack(steps).astype(np.float32))
    assert main(["brick", str(d / "blob.npy"), str(d / "blob.zarr"), "--brick", "8", "--axes", "tzyx", "--quiet"]) == 0
    return d


def test_info_of_a_time_series_root(series, capsys):
    assert main(["info", str(series / "blob.zarr")]) == 0
    out = capsys.readouterr().out
    assert "time series: one OME-Zarr 0.5 image, axes t, z, y, x" in out
    assert out.count("complete   yes") == 3 and "--- t = 2" in out


def test_info_of_an_incomplete_member_exits_1(tmp_path, capsys):
    import json

    data = np.random.default_rng(1).random((2, 8, 8, 8)).astype(np.float32)
    np.save(tmp_path / "c.npy", data)
    assert main(["brick", str(tmp_path / "c.npy"), str(tmp_path / "c.zarr"), "--brick", "8", "--quiet"]) == 0
    meta = tmp_path / "c.zarr" / "clipvol_members" / "c" / "1" / "zarr.json"
    doc = json.loads(meta.read_text())
    doc["attributes"]["clipvol"]["complete"] = False
    meta.write_text(json.dumps(doc))
    assert main(["info", str(tmp_path / "c.zarr")]) == 1
    assert "incomplete" in capsys.readouterr().err


def test_axes_on_a_3d_input_is_refused(tmp_path, capsys):
    np.save(tmp_path / "v.npy", np.zeros((8, 8, 8), np.float32))
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "v.zarr"), "--axes", "tzyx", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--axes" in err and "4-D" in err and not (tmp_path / "v.zarr").exists()


@pytest.mark.gl
def test_render_of_the_root_is_the_members_render(series, tmp_path, capsys):
    def render(src, *extra):
        out = tmp_path / f"r{len(list(tmp_path.iterdir()))}.png"
        assert main(["render", str(src), "--out", str(out), "--size", "48x40", "--tf-range", "0,1", *extra]) == 0
        return np.asarray(Image.open(out)).astype(int)

    root = series / "blob.zarr"
    first, last = render(root), render(root, "--t", "2")
    steps = np.load(series / "blob.npy")
    for k, img in ((0, first), (2, last)):  # the step bricked alone as a 3-D store draws the same picture
        np.save(series / f"step{k}.npy", steps[k])
        if not (series / f"step{k}.zarr").exists():
            assert main(["brick", str(series / f"step{k}.npy"), str(series / f"step{k}.zarr"), "--brick", "8",
                         "--quiet"]) == 0
        np.testing.assert_array_equal(img, render(series / f"step{k}.zarr"))
    assert np.abs(first - last).max() > 50  # the blob moved
    capsys.readouterr()
    assert main(["render", str(root), "--out", str(tmp_path / "x.png"), "--t", "3"]) == 2
    assert "0..2" in capsys.readouterr().err
    assert main(["render", str(root), "--out", str(tmp_path / "x.png"), "--c", "1"]) == 2
    assert "no 'c' axis" in capsys.readouterr().err


@pytest.mark.gl
def test_view_offscreen_opens_the_root(series, tmp_path):
    out = tmp_path / "frames"
    assert main(["view", str(series / "blob.zarr"), "--offscreen", "--frames", "1", "--size", "32x32",
                 "--out", str(out)]) == 0
    assert len(list(out.glob("*.png"))) == 1
