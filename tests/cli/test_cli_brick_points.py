"""``clipvol brick-points`` and the point-store branches of ``info``, ``check`` and ``render``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr
from PIL import Image

from clipvol.tools.cli import main

from optional import needs


def test_brick_points_info_check_render(tmp_path, capsys, rng):
    pts = rng.random((3000, 5))
    np.save(tmp_path / "p.npy", pts)
    out = tmp_path / "p.zarr"
    assert main(["brick-points", str(tmp_path / "p.npy"), str(out), "--max-points", "16", "--value", "v1", "--quiet"]) == 0
    attrs = json.loads((out / "zarr.json").read_text())["attributes"]["clipvol"]
    assert attrs["complete"] and attrs["num_points"] == 3000 and attrs["value_names"] == ["v1"]
    # the store opens in zarr itself; the kept value column is the input's column 3 + 1
    g = zarr.open_group(str(out), mode="r")
    vals = np.asarray(g["points/values"][:])[:, 0].astype(np.float64)
    ref = np.sort(pts[:, 4])
    near = ref[np.clip(np.searchsorted(ref, vals), 0, len(ref) - 1)]
    near2 = ref[np.clip(np.searchsorted(ref, vals) - 1, 0, len(ref) - 1)]
    assert np.all(np.minimum(abs(near - vals), abs(near2 - vals)) < 1e-6)
    assert main(["info", str(out)]) == 0
    o = capsys.readouterr().out
    assert "points     3,000" in o and "v1:" in o
    assert main(["check", str(out)]) == 0
    assert "ok" in capsys.readouterr().out
    png = tmp_path / "p.png"
    assert main(["render", str(out), "--out", str(png), "--size", "64x48", "--tolerance", "4px"]) == 0
    img = np.asarray(Image.open(png))
    assert img.shape == (48, 64, 4) and img[..., 3].any()
    assert "points drawn" in capsys.readouterr().err
    assert main(["render", str(out), "--out", str(png), "--tolerance", "lots"]) == 2
    assert "tolerance: expected a fraction" in capsys.readouterr().err
    # the volume-only commands say what a point store is instead of failing on missing volume metadata
    assert main(["view", str(out), "--offscreen", "--out", str(tmp_path / "v")]) == 2
    assert "a point store" in capsys.readouterr().err
    # a second build into the complete store is refused; --overwrite rebuilds it
    assert main(["brick-points", str(tmp_path / "p.npy"), str(out), "--quiet"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert main(["brick-points", str(tmp_path / "p.npy"), str(out), "--quiet", "--overwrite"]) == 0


def test_check_reports_a_corrupt_node_table(tmp_path, capsys, rng):
    np.save(tmp_path / "p.npy", rng.random((2000, 4)))
    out = tmp_path / "p.zarr"
    assert main(["brick-points", str(tmp_path / "p.npy"), str(out), "--max-points", "8", "--quiet"]) == 0
    g = zarr.open_group(str(out), mode="r+")
    w = np.asarray(g["nodes/weight"][:])
    w[0] += 1
    g["nodes/weight"][:] = w
    assert main(["check", str(out)]) == 1
    assert "weight" in capsys.readouterr().err


@pytest.mark.parametrize("args, message", [
    (["missing.npy"], "missing.npy: no such file"),
    pytest.param(["bad.csv", "--value", "rho"], "bad.csv: no value column named 'rho'", marks=needs("pandas")),
    (["nan.npy"], "nan.npy: expected finite x, y, z coordinates"),
    (["p.npy", "--max-points", "3"], "--max-points: expected 8..65536, got 3"),
    (["p.txt"], "unknown point format"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, rng, args, message):
    np.save(tmp_path / "p.npy", rng.random((10, 4)))
    bad = rng.random((10, 4))
    bad[4, 0] = np.inf
    np.save(tmp_path / "nan.npy", bad)
    (tmp_path / "bad.csv").write_text("x,y,z,temp\n0,0,0,1\n")
    (tmp_path / "p.txt").write_text("1 2 3\n")
    argv = ["brick-points", str(tmp_path / args[0]), str(tmp_path / "o.zarr"), "--quiet", *args[1:]]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "o.zarr").exists()
