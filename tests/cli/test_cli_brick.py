"""`clipvol brick`, `clipvol info`, `clipvol check` through the CLI entry point."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from clipvol.tools.cli import main
from build_hooks import after_each_brick


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def npy(tmp_path, rng):
    vol = rng.integers(0, 1000, size=(20, 12, 18)).astype(np.uint16)
    p = tmp_path / "v.npy"
    np.save(p, vol)
    return p, vol


@pytest.mark.parametrize(
    "extra,needles",
    [
        (["--brick", "4"], ["brick", "8..256", "4"]),
        (["--brick", "300"], ["brick", "300"]),
        (["--brick", "9"], ["brick", "even"]),
        (["--filter", "median"], ["filter", "median"]),
        (["--codec", "gzip"], ["codec", "gzip"]),
        (["--spacing", "1,2"], ["--spacing", "1,2"]),
        (["--spacing", "1,0,2"], ["spacing"]),
        (["--threads", "0"], ["--threads", "0"]),
        (["--unit", " "], ["unit"]),
    ],
)
def test_bad_parameters(tmp_path, npy, capsys, extra, needles):
    assert main(["brick", str(npy[0]), str(tmp_path / "o.zarr"), "--quiet", *extra]) == 2
    _one_error_line(capsys, *needles)
    assert not (tmp_path / "o.zarr").exists()


def test_missing_input(tmp_path, capsys):
    assert main(["brick", str(tmp_path / "nope.npy"), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "nope.npy", "no such")


def test_unmatched_glob(tmp_path, capsys):
    assert main(["brick", str(tmp_path / "x*.tif"), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "x*.tif")


def test_unknown_format(tmp_path, capsys):
    (tmp_path / "v.dat").write_bytes(b"1234")
    assert main(["brick", str(tmp_path / "v.dat"), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "v.dat", "--shape")


def test_raw_size_mismatch(tmp_path, capsys):
    (tmp_path / "v.raw").write_bytes(bytes(1000))
    assert main(["brick", str(tmp_path / "v.raw"), str(tmp_path / "o.zarr"), "--shape", "10,10,10", "--dtype", "uint16", "--quiet"]) == 2
    _one_error_line(capsys, "v.raw", "2000", "1000")


def test_raw_needs_dtype(tmp_path, capsys):
    (tmp_path / "v.raw").write_bytes(bytes(1000))
    assert main(["brick", str(tmp_path / "v.raw"), str(tmp_path / "o.zarr"), "--shape", "10,10,10", "--quiet"]) == 2
    _one_error_line(capsys, "--dtype")


@pytest.mark.parametrize("dtype", ["complex64", "bool", "object"])
def test_unsupported_dtype_raw(tmp_path, capsys, dtype):
    (tmp_path / "v.raw").write_bytes(bytes(8))
    assert main(["brick", str(tmp_path / "v.raw"), str(tmp_path / "o.zarr"), "--shape", "1,1,1", "--dtype", dtype, "--quiet"]) == 2
    _one_error_line(capsys, "dtype", dtype)


@pytest.mark.parametrize("arr", [np.zeros((2, 2, 2), np.complex64), np.zeros((2, 2, 2), bool)])
def test_unsupported_dtype_npy(tmp_path, capsys, arr):
    np.save(tmp_path / "v.npy", arr)
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "v.npy", "dtype", str(arr.dtype))


def test_zero_axis(tmp_path, capsys):
    np.save(tmp_path / "v.npy", np.zeros((3, 0, 4), np.uint8))
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "v.npy", "(3, 0, 4)")


def test_unknown_procedural(tmp_path, capsys):
    assert main(["brick", "procedural:clouds?size=8", str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "clouds", "fractal")


def test_output_exists(tmp_path, npy, capsys):
    out = tmp_path / "o.zarr"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert main(["brick", str(npy[0]), str(out), "--quiet"]) == 2
    _one_error_line(capsys, "o.zarr", "not a clipvol store", "keep.txt")  # --overwrite is not suggested
    assert main(["brick", str(npy[0]), str(out), "--quiet", "--brick", "8", "--overwrite"]) == 2
    _one_error_line(capsys, "refusing to overwrite", "keep.txt")  # not a store: never removed
    assert (out / "keep.txt").read_text() == "x"
    (out / "keep.txt").unlink()  # an empty folder is replaced
    assert main(["brick", str(npy[0]), str(out), "--quiet", "--brick", "8", "--overwrite"]) == 0
    capsys.readouterr()
    assert main(["brick", str(npy[0]), str(out), "--quiet", "--brick", "8"]) == 2
    _one_error_line(capsys, "complete", "--overwrite")


def test_resume_with_other_parameters(tmp_path, npy, capsys, monkeypatch):
    out = tmp_path / "o.zarr"

    def crash(level, index):
        raise RuntimeError("crash")

    after_each_brick(monkeypatch, crash)
    with pytest.raises(RuntimeError):
        main(["brick", str(npy[0]), str(out), "--quiet", "--brick", "8"])
    after_each_brick(monkeypatch, None)
    capsys.readouterr()
    assert main(["brick", str(npy[0]), str(out), "--quiet", "--brick", "16"]) == 2
    _one_error_line(capsys, "brick_shape", "--overwrite")
    assert main(["info", str(out)]) == 1  # an interrupted build is described, but not a success
    assert "no (interrupted" in capsys.readouterr().out
    assert main(["check", str(out)]) == 1
    assert "incomplete" in capsys.readouterr().err
    assert main(["brick", str(npy[0]), str(out), "--quiet", "--brick", "8"]) == 0
    assert main(["check", str(out), "--samples", "100"]) == 0


def test_brick_info_check(tmp_path, npy, capsys):
    p, vol = npy
    out = tmp_path / "o.zarr"
    assert main(["brick", str(p), str(out), "--brick", "8", "--spacing", "1,1,2", "--unit", "nanometer", "--codec", "zstd"]) == 0
    cap = capsys.readouterr()
    assert "bricking" in cap.err  # the progress bar
    np.testing.assert_array_equal(zarr.open_group(str(out), mode="r")["0"][...], vol)
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    g = zarr.open_group(str(out), mode="r")
    for L, shape in enumerate(g.attrs["clipvol"]["levels"]):
        assert "x".join(map(str, shape)) in text
    assert "uint16" in text and "zstd" in text and "mean" in text and "nanometer" in text
    assert f"{vol.min():g} .. {vol.max():g}" in text
    assert "complete   yes" in text
    assert main(["check", str(out), "--samples", "3"]) == 0
    assert "ok" in capsys.readouterr().out


def _encode_like_store(out, level, block):
    from clipvol.bricking.pipeline import chunk_encoder

    return chunk_encoder("lz4", block.dtype)(block)


@pytest.mark.parametrize("how", ["garbage", "wrong data"])
def test_check_names_a_corrupted_brick(tmp_path, npy, capsys, how):
    p, vol = npy
    out = tmp_path / "o.zarr"
    assert main(["brick", str(p), str(out), "--brick", "8", "--quiet"]) == 0
    chunk = out / "1" / "c" / "1" / "0" / "1"
    assert chunk.exists()
    if how == "garbage":
        chunk.write_bytes(b"not a blosc chunk at all")
    else:
        blk = zarr.open_group(str(out), mode="r")["1"][0:8, 0:8, 0:8][...]  # brick (0,0,0), a valid one
        chunk.write_bytes(_encode_like_store(out, 1, blk))
    assert main(["check", str(out), "--samples", "1000"]) == 1
    err = capsys.readouterr().err
    assert "level 1 brick (1, 0, 1)" in err


def test_info_and_check_on_non_store(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing.zarr")]) == 2
    _one_error_line(capsys, "missing.zarr")
    (tmp_path / "d").mkdir()
    assert main(["check", str(tmp_path / "d")]) == 2
    _one_error_line(capsys, "zarr.json")


def test_spacing_and_origin_are_typed_x_y_z_like_every_coordinate(npy, tmp_path, capsys):
    # reference: the store's own attributes, z, y, x (the array's order), and info printing x, y, z back
    import json

    p, _ = npy
    out = tmp_path / "xyz.zarr"
    assert main(["brick", str(p), str(out), "--brick", "8", "--quiet", "--spacing", "0.5,2,3",
                 "--origin", "-7,1,40"]) == 0
    cv = json.loads((out / "zarr.json").read_text())["attributes"]["clipvol"]
    assert cv["spacing"] == [3.0, 2.0, 0.5] and cv["origin"] == [40.0, 1.0, -7.0]
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "spacing    0.5, 2, 3 " in text and "origin     -7, 1, 40 " in text, text


def test_info_shows_the_spread_arrays(npy, tmp_path, capsys):
    """`clipvol info` names the levels whose spread arrays the store holds (consistent coarse levels)
    and their bytes; a store without them says its coarse levels are classified by their mean.
    Reference: the store's own folders, listed and summed here."""
    import shutil

    from clipvol.units import format_bytes

    p, _ = npy
    out = tmp_path / "sp.zarr"
    assert main(["brick", str(p), str(out), "--brick", "8", "--quiet"]) == 0
    group = out / "clipvol_spread"
    levels = sorted(int(d.name) for d in group.iterdir() if d.is_dir())
    nbytes = sum(f.stat().st_size for f in group.rglob("*") if f.is_file())
    assert levels and levels[0] == 1
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("spread ")]
    assert len(line) == 1 and line[0].startswith(f"spread     levels {', '.join(map(str, levels))} ")
    assert f" {format_bytes(nbytes)}, " in line[0], line[0]
    shutil.rmtree(group)
    main(["info", str(out)])  # the manifest now misses the spread: info says so on stderr, the line still prints
    line = [s for s in capsys.readouterr().out.splitlines() if s.startswith("spread ")]
    assert line == ["spread     none (coarse levels are classified by their mean; clipvol brick writes the spread)"]
