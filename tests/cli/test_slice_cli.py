"""``clipvol slice``: the values it writes equal the source's slice, its statistics, bad input (exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

SRC = "procedural:fractal?size=48"


def _source():
    from clipvol.bricking.generators import parse_procedural

    return parse_procedural(SRC).region(0, (0, 0, 0), (48, 48, 48))


def test_slice_writes_png_values_and_stats(tmp_path, capsys):
    out, npy, st = tmp_path / "s.png", tmp_path / "s.npy", tmp_path / "s.json"
    rc = main(["slice", SRC, "--brick", "16", "--plane", "y=20", "--level", "0", "--out", str(out), "--npy", str(npy),
               "--stats", str(st), "--window", "0.5,1"])
    assert rc == 0, capsys.readouterr().err
    vol = _source()
    v = np.load(npy)
    ref = vol[:, 20, :][::-1]  # coronal: superior (high z) at the top
    assert v.dtype == np.float32 and v.shape == ref.shape
    assert np.max(np.abs(v - ref)) <= 1e-6 * max(1.0, float(np.ptp(vol)))
    img = np.asarray(Image.open(out))
    assert img.shape == (48, 48, 4)
    grey = np.clip(np.rint(np.clip(ref, 0.0, 1.0) * 255), 0, 255)
    assert np.max(np.abs(img[..., 0].astype(int) - grey)) <= 1
    doc = json.loads(st.read_text())
    assert doc["tiles_per_level"] == {"0": 9} and doc["bytes_needed"] == 9 * 16**3 * 4
    assert {"bytes_loaded", "times", "converged"} <= set(doc)
    assert "tiles" in capsys.readouterr().err


def test_multiresolution_slice_with_poi_needs_fewer_bytes(tmp_path):
    full, multi = tmp_path / "f.json", tmp_path / "m.json"
    assert main(["slice", "procedural:fractal?size=128", "--brick", "8", "--axis", "axial", "--index", "60", "--level", "0",
                 "--stats", str(full)]) == 0
    assert main(["slice", "procedural:fractal?size=128", "--brick", "8", "--axis", "axial", "--index", "60", "--poi", "10,10,60",
                 "--stats", str(multi)]) == 0
    f, m = json.loads(full.read_text()), json.loads(multi.read_text())
    assert f["bricks_needed"] == 16 * 16
    assert m["bytes_needed"] * 2 < f["bytes_needed"] and "0" in m["tiles_per_level"] and len(m["tiles_per_level"]) >= 3


@pytest.mark.parametrize("args,name", [
    (["--plane", "z=48"], "index"),
    (["--plane", "w=3"], "--plane"),
    (["--through", "1,1,1", "--normal", "0,0,0"], "normal"),
    (["--through", "1,1,500", "--normal", "0,0,1"], "plane"),
    (["--through", "1,1,1"], "--normal"),
    (["--plane", "z=3", "--axis", "axial"], "plane"),
    (["--level", "9"], "--level"),
    (["--pixel-size", "0"], "--pixel-size"),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, args, name):
    out = tmp_path / "x.png"
    assert main(["slice", SRC, "--brick", "16", "--out", str(out)] + args) == 2
    err = capsys.readouterr().err.strip()
    assert name in err and len(err.splitlines()) == 1
    assert not out.exists() and not list(tmp_path.iterdir())


@pytest.mark.parametrize("flag,name", [("--out", "s.png"), ("--npy", "s.npy"), ("--stats", "s.json")])
def test_an_output_in_a_missing_folder_is_refused_before_any_output(tmp_path, capsys, flag, name):
    """Before: the slice was drawn, the outputs before it written, then a traceback (exit 1) at the
    one whose folder is missing. Now: one line naming the flag and folder, exit 2, nothing written."""
    outs = {"--out": tmp_path / "s.png", "--npy": tmp_path / "s.npy", "--stats": tmp_path / "s.json"}
    outs[flag] = tmp_path / "missing" / name
    argv = ["slice", SRC, "--brick", "16"] + [a for f, p in outs.items() for a in (f, str(p))]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert flag in err and "missing" in err and "does not exist" in err and len(err.splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_slice_of_a_nifti_store_labels_its_edges_like_nibabel(tmp_path):
    nib = pytest.importorskip("nibabel")
    data = np.arange(21 * 17 * 13, dtype=np.int16).reshape(21, 17, 13)  # nibabel order (i, j, k)
    aff = np.array([[-0.9, 0.0, 0.0, 60.0], [0.0, 0.0, 1.1, -40.0], [0.0, 1.7, 0.0, 12.0], [0, 0, 0, 1.0]])
    nib.save(nib.Nifti1Image(data, aff), tmp_path / "head.nii.gz")
    store = tmp_path / "head.zarr"
    assert main(["brick", str(tmp_path / "head.nii.gz"), str(store), "--brick", "8", "--quiet"]) == 0
    st, npy = tmp_path / "s.json", tmp_path / "s.npy"
    # voxels of 0.9 (i) x 1.7 (j) mm and square pixels of 1.7 mm: rows hit the j voxel centres,
    # columns fall between i voxels (linear interpolation along i)
    assert main(["slice", str(store), "--plane", "z=5", "--level", "0", "--pixel-size", "1.7", "--size", "10x17",
                 "--stats", str(st), "--npy", str(npy)]) == 0
    # the store's array is nibabel's (i, j, k) transposed to (z, y, x) = (k, j, i): the axial preset
    # shows vol[5] = data[:, :, 5].T, rows along j, columns along i
    v = np.load(npy)
    assert v.shape == (17, 10) and np.all(np.isfinite(v))
    x_world = (np.arange(10) + 0.5 - 5) * 1.7 + (21 - 1) / 2 * 0.9
    ref = np.array([np.interp(x_world / 0.9, np.arange(21), data[:, j, 5].astype(float)) for j in range(17)])
    assert np.max(np.abs(v - ref)) <= 1e-3 * np.ptp(data)
    codes = nib.aff2axcodes(aff)  # the patient direction of +i, +j, +k
    flip = {"L": "R", "R": "L", "A": "P", "P": "A", "S": "I", "I": "S"}
    edges = json.loads(st.read_text())["edges"]
    assert edges == {"right": codes[0], "left": flip[codes[0]], "top": flip[codes[1]], "bottom": codes[1]}


def test_exact_tol_reads_coarser_bricks_where_the_colours_cannot_tell(tmp_path, capsys):
    """A store (with its summary tables) whose x < 32 half is a gentle gradient and whose other half
    holds thin bright lines: by default the slice with a point of interest reads no level-0 brick
    over the gradient and its values there differ from level 0's by less than the grey window can
    show; ``--exact-tol off`` reads level 0 there (distance alone); ``--exact-tol 0`` reads level 0
    wherever any voxel changes. The values against numpy's plane; bytes from the statistics."""
    from clipvol.bricking.pipeline import brick_volume

    z, y, x = np.ogrid[:32, :32, :64]
    vol = np.broadcast_to((100 + x).astype(np.uint8), (32, 32, 64)).copy()  # one value a voxel along x
    vol[:, :, 32:] = 100
    vol[::4, ::4, 32:] = 250
    store = tmp_path / "v.zarr"
    brick_volume(vol, store, brick=8, progress=False)
    got = {}
    for name, extra in (("default", []), ("off", ["--exact-tol", "off"]), ("zero", ["--exact-tol", "0"])):
        st, npy = tmp_path / f"{name}.json", tmp_path / f"{name}.npy"
        rc = main(["slice", str(store), "--plane", "z=20", "--poi", "32,16,20", "--distance-factor", "8",
                   "--window", "175,150", "--stats", str(st), "--npy", str(npy), *extra])
        assert rc == 0, capsys.readouterr().err
        got[name] = (json.loads(st.read_text()), np.load(npy))
    ref = vol[20].astype(np.float64)
    for name, (doc, v) in got.items():
        assert np.allclose(v[:, 32:], ref[:, 32:], atol=1e-3), name  # the lines at level 0 in every case
    assert got["off"][0]["tiles_per_level"] == {"0": 32}  # distance alone: level 0 everywhere in reach
    assert got["zero"][0]["tiles_per_level"] == {"0": 32}  # the gradient changes voxel by voxel
    coarse = got["default"]
    assert coarse[0]["bytes_needed"] < got["off"][0]["bytes_needed"]
    assert set(coarse[0]["tiles_per_level"]) - {"0"}  # coarser tiles over the gradient
    # over the gradient the coarser values stay within what the window shows as the same: each of
    # them maps to a grey within Delta E 6 of numpy's level-0 voxel there
    from clipvol.scene.metrics import percent_delta_e

    def grey(a):
        g = np.rint(np.clip((a - 100.0) / 150.0, 0, 1) * 255).astype(np.uint8)
        return np.dstack([g, g, g, np.full_like(g, 255)])

    assert percent_delta_e(grey(coarse[1][:, :32]), grey(ref[:, :32])) == 0.0


@pytest.mark.parametrize("value", ["-1", "nan", "loose"])
def test_a_bad_exact_tol_is_one_line_exit_2(tmp_path, capsys, value):
    st = tmp_path / "s.json"
    assert main(["slice", SRC, "--brick", "16", "--plane", "z=20", "--poi", "20,20,20", "--stats", str(st),
                 "--exact-tol", value]) == 2
    err = capsys.readouterr().err
    assert "--exact-tol" in err and len(err.strip().splitlines()) == 1
    assert not st.exists()
