"""Refuse what cannot be right, and say what is actually wrong (issue 40, item 6): a NIfTI with no
voxel size, a step that skips bricks, and four messages that named the wrong cause (a codec list
edited since the build, a multiscale list shorter than the levels, a manifest of another length,
a brick into its own input store).

References: the NIfTI header bytes written here with nibabel (pixdim read back raw), the store's
JSON edited here with ``json`` (what changed is known by construction), and ``os.stat`` for the
manifest's length.
"""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest

from clipvol.tools.cli import main


def _err_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("refusals")
    v = np.random.default_rng(4).integers(1, 250, size=(16, 16, 16)).astype(np.uint8)
    np.save(d / "v.npy", v)
    assert main(["brick", str(d / "v.npy"), str(d / "S.zarr"), "--quiet", "--brick", "8"]) == 0
    return d / "S.zarr"


def _copy(store, tmp_path, name="C.zarr"):
    out = tmp_path / name
    shutil.copytree(store, out)
    return out


def _edit_json(path, change):
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


# -- a NIfTI that records no voxel size ------------------------------------------------------------------------
def _zero_pixdim_nifti(path):
    nib = pytest.importorskip("nibabel")
    img = nib.Nifti1Image(np.arange(8 * 8 * 8, dtype=np.int16).reshape(8, 8, 8), None)
    img.header["pixdim"][1:4] = 0
    img.header.set_sform(None, code=0)
    img.header.set_qform(None, code=0)
    nib.save(img, path)
    raw = nib.Nifti1Header.from_fileobj(open(path, "rb"), check=False)  # as on disk, before nibabel's fix to 1
    assert list(raw["pixdim"][1:4]) == [0, 0, 0] and raw["sform_code"] == 0 and raw["qform_code"] == 0


def test_a_nifti_with_no_voxel_size_is_refused_unless_spacing_is_given(tmp_path, capsys):
    p = tmp_path / "flat.nii"
    _zero_pixdim_nifti(p)
    assert main(["brick", str(p), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    line = _err_line(capsys)
    assert "flat.nii" in line and "pixdim" in line and "--spacing" in line, line
    assert not (tmp_path / "o.zarr").exists()
    assert main(["brick", str(p), str(tmp_path / "o.zarr"), "--quiet", "--spacing", "0.5,1.5,2"]) == 0  # typed x,y,z
    cv = json.loads((tmp_path / "o.zarr" / "zarr.json").read_text())["attributes"]["clipvol"]
    assert cv["spacing"] == [2.0, 1.5, 0.5]  # stored z,y,x


# -- a step that steps over bricks ------------------------------------------------------------------------------
def test_a_step_longer_than_a_brick_is_refused_naming_the_range(store, tmp_path, capsys):
    out = tmp_path / "a.png"
    assert main(["render", str(store), "--step", "1e9", "--size", "16x16", "-o", str(out)]) == 2
    line = _err_line(capsys)  # past any brick edge: refused naming this store's range
    assert "step" in line and "(0, 8]" in line and "1e+09" in line, line
    assert main(["render", str(store), "--step", "9", "--size", "16x16", "-o", str(out)]) == 2
    line = _err_line(capsys)  # past this store's brick edge (8): refused when drawn
    assert "step" in line and "(0, 8]" in line and "got 9" in line, line
    assert not out.exists()
    assert main(["render", str(store), "--step", "8", "--size", "16x16", "-o", str(out)]) == 0  # one brick edge
    assert out.exists()


# -- messages that named the wrong cause --------------------------------------------------------------------
def _trust(path) -> str:
    from clipvol.loaders.zarr_store import ZarrLoader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ZarrLoader(str(path)).trust


def _drop_crc(doc):
    doc["codecs"] = [c for c in doc["codecs"] if c.get("name") != "crc32c"]


def test_a_codec_list_edited_to_drop_crc32c_is_not_called_old(store, tmp_path, capsys):
    c = _copy(store, tmp_path)
    _edit_json(c / "0" / "zarr.json", _drop_crc)
    # the manifest pins the codec list: the edit is refused at open, named as what it is
    assert main(["info", str(c)]) == 2
    line = _err_line(capsys)
    assert "before chunk checksums" not in line and "level 0: codecs differ" in line and "crc32c" in line, line


def test_a_store_with_no_crc32c_anywhere_and_no_manifest_is_old(store, tmp_path):
    c = _copy(store, tmp_path)
    for L in (0, 1):
        _edit_json(c / str(L) / "zarr.json", _drop_crc)
    _edit_json(c / "zarr.json", lambda d: d["attributes"]["clipvol"].pop("manifest"))
    assert "written before chunk checksums" in _trust(c)


def test_a_multiscale_list_shorter_than_the_levels_says_so(store, tmp_path, capsys):
    c = _copy(store, tmp_path)
    _edit_json(c / "zarr.json", lambda d: d["attributes"]["ome"]["multiscales"][0]["datasets"].pop())
    assert main(["info", str(c)]) == 2  # the manifest pins the list: the level missing from it is named
    line = _err_line(capsys)
    assert "zip()" not in line and "level 1: missing from the multiscales list" in line, line
    _edit_json(c / "zarr.json", lambda d: d["attributes"]["clipvol"].pop("manifest"))  # no manifest to hold it to
    assert main(["info", str(c)]) == 2
    line = _err_line(capsys)
    assert "zip()" not in line and "datasets" in line and "lists 1 level" in line and "expected 2" in line, line


def test_a_manifest_one_byte_longer_is_named_a_change_not_a_size_cap(store, tmp_path):
    c = _copy(store, tmp_path)
    m = c / "clipvol_manifest" / "manifest.json"
    n = m.stat().st_size
    m.write_bytes(m.read_bytes() + b" ")
    trust = _trust(c)
    assert f"{n + 1} bytes" in trust and f"records {n}" in trust and "changed" in trust, trust
    assert "may hold" not in trust
