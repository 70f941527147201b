"""The manifest pins each level's array metadata and the multiscale transforms: a store whose
``zarr.json`` files differ from it (byte order, a codec chain without its compressor, fill value,
another build's level, a shortened multiscale list) is refused on opening, naming the level and the
field, and ``clipvol repair`` puts the metadata back. References: the source array (numpy), the
level arrays as zarr-python reads them, the image rendered before the edit, the JSON files as
the build wrote them."""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest
import zarr
from PIL import Image

from clipvol.tools.cli import main

B = 16
RENDER = ["--size", "48x40", "--view", "iso", "--tf", "viridis", "--memory-budget", "16MB"]


def _volume():
    z, y, x = np.indices((36, 40, 34))
    vol = np.clip(2000 + 1500 * np.sin(z / 4.0) * np.cos(y / 5.0) + 400 * np.sin(x / 3.0), 1, 4095).astype(np.uint16)
    vol[:16] = 0  # whole bricks of fill value: never written, read back as the fill value
    return vol


@pytest.fixture
def built(tmp_path):
    vol = _volume()
    src = tmp_path / "v.npy"
    np.save(src, vol)
    out = tmp_path / "o.zarr"
    assert main(["brick", str(src), str(out), "--brick", str(B), "--quiet"]) == 0
    return src, out, vol


def _edit_json(path, change):
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def _big_endian(doc):
    for c in doc["codecs"]:
        if c["name"] == "bytes":
            c["configuration"]["endian"] = "big"


def _no_compressor(doc):
    doc["codecs"] = [c for c in doc["codecs"] if c["name"] != "blosc"]


def _fill_500(doc):
    doc["fill_value"] = 500


EDITS = {"byte order": (_big_endian, "level 1: codecs differ"),
         "codecs without the compressor": (_no_compressor, "level 1: codecs differ"),
         "fill value": (_fill_500, "level 1: fill_value differs: manifest has 0, zarr.json has 500")}


def _levels(out):
    return [np.asarray(zarr.open_array(str(out / str(L)), mode="r")[...]) for L in range(3)]


def _image(p):
    return np.asarray(Image.open(p))


def _refused(out, tmp_path, capsys, *needles):
    """Every reading command refuses the store (exit 2) with one line naming the level and field."""
    capsys.readouterr()
    for cmd in (["info", str(out)], ["check", str(out), "--quiet"],
                ["export", str(out), "--box", ":,:,:", "--out", str(tmp_path / "e.npy")]):
        assert main(cmd) == 2, cmd
        err = capsys.readouterr().err
        assert "metadata differs from the store's manifest" in err and "Traceback" not in err, err
        for n in needles:
            assert n in err, (n, err)
    assert not (tmp_path / "e.npy").exists()


@pytest.mark.gl
@pytest.mark.parametrize("edit", ["byte order", *(pytest.param(e, marks=pytest.mark.slow) for e in list(EDITS)[1:])])
def test_an_edited_level_zarr_json_is_refused_and_repair_restores_it(built, tmp_path, capsys, edit):
    src, out, vol = built
    change, needle = EDITS[edit]
    before = _levels(out)
    original = (out / "1" / "zarr.json").read_bytes()
    assert main(["render", str(out), "--out", str(tmp_path / "a.png"), "--level", "0", *RENDER]) == 0
    _edit_json(out / "1" / "zarr.json", change)
    _refused(out, tmp_path, capsys, needle)
    assert main(["render", str(out), "--out", str(tmp_path / "x.png"), *RENDER]) == 2
    assert not (tmp_path / "x.png").exists()
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert "restored the metadata of level 1 (1/zarr.json)" in capsys.readouterr().out
    assert json.loads((out / "1" / "zarr.json").read_bytes()) == json.loads(original)
    for a, b in zip(_levels(out), before):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(_levels(out)[0], vol)
    assert main(["check", str(out), "--all", "--quiet"]) == 0
    assert main(["render", str(out), "--out", str(tmp_path / "b.png"), "--level", "0", *RENDER]) == 0
    np.testing.assert_array_equal(_image(tmp_path / "b.png"), _image(tmp_path / "a.png"))


@pytest.mark.slow
@pytest.mark.gl
def test_a_level_replaced_by_another_builds_is_refused_and_repair_rebuilds_it(built, tmp_path, capsys):
    src, out, vol = built
    other_src = tmp_path / "w.npy"
    np.save(other_src, (vol[::-1] // 2).copy())
    other = tmp_path / "w.zarr"
    assert main(["brick", str(other_src), str(other), "--brick", str(B), "--codec", "zstd", "--quiet"]) == 0
    assert main(["render", str(out), "--out", str(tmp_path / "a.png"), *RENDER]) == 0
    shutil.rmtree(out / "1")
    shutil.copytree(other / "1", out / "1")  # its zarr.json and its chunks
    _refused(out, tmp_path, capsys, "level 1: codecs differ")
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert "rebuilt" in capsys.readouterr().out  # the other build's chunks fail their checks: rebuilt from the input
    assert main(["check", str(out), "--all", "--quiet"]) == 0
    ref = vol[:, :, :].astype(np.float64)
    lv1 = _levels(out)[1]
    assert lv1.shape == (18, 20, 17)
    np.testing.assert_allclose(lv1[:8, :8, :8], ref[:16, :16, :16].reshape(8, 2, 8, 2, 8, 2).mean(axis=(1, 3, 5)),
                               atol=1)
    assert main(["render", str(out), "--out", str(tmp_path / "b.png"), *RENDER]) == 0
    np.testing.assert_array_equal(_image(tmp_path / "b.png"), _image(tmp_path / "a.png"))


@pytest.mark.gl
def test_a_shortened_multiscales_list_is_refused_and_repair_restores_it(built, tmp_path, capsys):
    src, out, vol = built
    original = json.loads((out / "zarr.json").read_text())["attributes"]["ome"]
    assert main(["render", str(out), "--out", str(tmp_path / "a.png"), *RENDER]) == 0
    _edit_json(out / "zarr.json", lambda d: d["attributes"]["ome"]["multiscales"][0]["datasets"].pop())
    _refused(out, tmp_path, capsys, "level 2: missing from the multiscales list")
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert json.loads((out / "zarr.json").read_text())["attributes"]["ome"] == original
    assert main(["render", str(out), "--out", str(tmp_path / "b.png"), *RENDER]) == 0
    np.testing.assert_array_equal(_image(tmp_path / "b.png"), _image(tmp_path / "a.png"))


def test_a_moved_level_transform_is_refused_naming_the_level(built, tmp_path, capsys):
    src, out, vol = built

    def move(d):
        d["attributes"]["ome"]["multiscales"][0]["datasets"][1]["coordinateTransformations"][0]["scale"] = [3.0, 2.0, 2.0]

    _edit_json(out / "zarr.json", move)
    _refused(out, tmp_path, capsys, "level 1: multiscale transform differs")


def _unpin(out):
    """The store as a build before metadata pins wrote it: its manifest without ``arrays`` and ``ome``,
    recorded in the root metadata with its new checksum."""
    mpath = out / "clipvol_manifest" / "manifest.json"
    doc = json.loads(mpath.read_text())
    doc.pop("multiscales")
    for lv in doc["levels"]:
        lv.pop("arrays")
    data = json.dumps(doc, indent=1, sort_keys=True).encode()
    mpath.write_bytes(data)
    g = zarr.open_group(str(out), mode="r+")
    cv = dict(g.attrs["clipvol"])
    cv["manifest"] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    g.attrs["clipvol"] = cv


def test_a_manifest_written_before_metadata_pins_opens_marked_and_repair_pins(built, tmp_path, capsys):
    src, out, vol = built
    _unpin(out)
    _edit_json(out / "1" / "zarr.json", _fill_500)  # nothing pins it: not caught on opening
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "verified" in first and "not the arrays' metadata" in first and "clipvol repair" in first, first
    _edit_json(out / "1" / "zarr.json", lambda d: d.update(fill_value=0))
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert "wrote the manifest" in capsys.readouterr().out
    assert main(["info", str(out)]) == 0
    assert "every level's metadata" in capsys.readouterr().out.splitlines()[0]
    _edit_json(out / "1" / "zarr.json", _fill_500)
    _refused(out, tmp_path, capsys, "level 1: fill_value differs")


@pytest.mark.slow
@pytest.mark.gl
def test_a_levels_chunks_replaced_by_another_builds_with_the_same_metadata_exit_3_and_repair_rebuilds(
        built, tmp_path, capsys):
    """The same metadata, other chunks: nothing differs on opening, so each chunk is caught when it is
    read (its size or crc32c is not the one the manifest records for the brick) and a one-shot render exits 3
    instead of drawing level 0 from its ancestors (issue 40, item 3)."""
    src, out, vol = built
    other_src = tmp_path / "w.npy"
    np.save(other_src, (vol[::-1] // 2).copy())
    other = tmp_path / "w.zarr"
    assert main(["brick", str(other_src), str(other), "--brick", str(B), "--quiet"]) == 0
    fixed = [*RENDER, "--policy", "fixed", "--level", "0"]
    assert main(["render", str(out), "--out", str(tmp_path / "a.png"), *fixed]) == 0
    shutil.rmtree(out / "0" / "c")
    shutil.copytree(other / "0" / "c", out / "0" / "c")
    capsys.readouterr()
    assert main(["render", str(out), "--out", str(tmp_path / "x.png"), *fixed]) == 3
    err = capsys.readouterr().err
    assert "brick(s) of the view failed" in err and "manifest" in err and not (tmp_path / "x.png").exists()
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    np.testing.assert_array_equal(_levels(out)[0], vol)
    assert main(["render", str(out), "--out", str(tmp_path / "b.png"), *fixed]) == 0
    np.testing.assert_array_equal(_image(tmp_path / "b.png"), _image(tmp_path / "a.png"))


def test_an_array_added_beside_a_levels_statistics_is_pinned_the_same_way(built, tmp_path, capsys):
    """Arrays are found by walking ``clipvol_stats/<L>/``: one added there (as per-level tables are)
    is pinned without a change to the manifest code, its metadata checked when the level's
    statistics are read, and restored by repair."""
    from clipvol.bricking.manifest import write_manifest

    src, out, vol = built
    extra = zarr.create_array(str(out / "clipvol_stats" / "1" / "extra"), shape=(3, 3, 3), chunks=(3, 3, 3),
                              dtype="float32", fill_value=0.0)
    extra[...] = np.arange(27, dtype=np.float32).reshape(3, 3, 3)
    g = zarr.open_group(str(out), mode="r+")
    cv = dict(g.attrs["clipvol"])
    cv["manifest"] = write_manifest(out, [(3, 3, 3), (2, 2, 2), (1, 1, 1)])
    g.attrs["clipvol"] = cv
    doc = json.loads((out / "clipvol_manifest" / "manifest.json").read_text())
    assert "clipvol_stats/1/extra" in doc["levels"][1]["arrays"]
    original = json.loads((out / "clipvol_stats" / "1" / "extra" / "zarr.json").read_text())
    _edit_json(out / "clipvol_stats" / "1" / "extra" / "zarr.json", lambda d: d.update(fill_value=7.0))
    capsys.readouterr()
    assert main(["check", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "clipvol_stats/1/extra: fill_value differs: manifest has 0.0, zarr.json has 7.0" in err, err
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert json.loads((out / "clipvol_stats" / "1" / "extra" / "zarr.json").read_text()) == original
    assert main(["check", str(out), "--all", "--quiet"]) == 0
