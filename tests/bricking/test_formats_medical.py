"""NIfTI and DICOM inputs: bytes and geometry end to end, from files written by nibabel / pydicom.

References: nibabel's own full read (``get_fdata``) and ``aff2axcodes``; the numpy volume and the
positions written into the DICOM slices (LPS, converted by hand to RAS here).
"""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.sources import open_source
from clipvol.errors import ClipvolError, InputFormatError
from clipvol.scene.orientation import axis_codes
from clipvol.tools.cli import main
from format_files import write_dicom_series

nib = pytest.importorskip("nibabel")
pytest.importorskip("pydicom")


def _attrs(store):
    return json.loads((store / "zarr.json").read_text())["attributes"]


def _level0(store):
    return zarr.open_group(str(store), mode="r")["0"][:]


def _ome(store, level=0):
    ds = _attrs(store)["ome"]["multiscales"][0]["datasets"][level]
    tr = {t["type"]: t[t["type"]] for t in ds["coordinateTransformations"]}
    return np.array(tr["scale"]), np.array(tr["translation"])


# -- NIfTI ---------------------------------------------------------------------------------------
@pytest.fixture
def nifti(tmp_path, rng):
    data = rng.integers(-500, 1500, size=(21, 17, 13)).astype(np.int16)  # nibabel order (i, j, k)
    aff = np.array([[-0.9, 0.0, 0.0, 60.0], [0.0, 0.0, 1.1, -40.0], [0.0, 1.7, 0.0, 12.0], [0, 0, 0, 1.0]])
    p = tmp_path / "head.nii.gz"
    nib.save(nib.Nifti1Image(data, aff), p)
    return p, data, aff


def test_nifti_bytes_and_geometry(nifti, tmp_path):
    p, data, aff = nifti
    out = tmp_path / "head.zarr"
    brick_volume(p, out, brick=8, progress=False)
    img = nib.load(p)
    np.testing.assert_array_equal(_level0(out), np.asarray(img.get_fdata()).transpose(2, 1, 0))
    cv = _attrs(out)["clipvol"]
    np.testing.assert_allclose(cv["affine"], img.affine, atol=1e-6)
    assert cv["world_frame"] == "RAS" and cv["unit"] == "millimeter"
    # OME scale: the column lengths of the affine (nibabel's zooms), z, y, x
    scale, trans = _ome(out)
    np.testing.assert_allclose(scale, np.array(img.header.get_zooms())[::-1], rtol=1e-6)
    # OME translation: voxel 0's world position along the array axes; mapping it back through the
    # rotation gives the affine's offset (nibabel: apply_affine of voxel 0)
    rot = aff[:3, :3] / np.linalg.norm(aff[:3, :3], axis=0)
    np.testing.assert_allclose(rot @ trans[::-1], nib.affines.apply_affine(aff, [0, 0, 0]), atol=1e-5)
    # level 1: the OME translation moves by the mean filter's half-voxel, still in world units
    s1, t1 = _ome(out, 1)
    np.testing.assert_allclose(t1 - trans, scale / 2, rtol=1e-6)
    assert axis_codes(cv["affine"]) == nib.aff2axcodes(img.affine) == ("L", "S", "A")


def test_nifti_scaled_is_float_with_scaling(tmp_path, rng):
    data = rng.integers(0, 100, size=(9, 10, 11)).astype(np.int16)
    img = nib.Nifti1Image(data, np.diag([2.0, 2.0, 3.0, 1.0]))
    img.header.set_slope_inter(0.5, -7.0)
    p = tmp_path / "scaled.nii"
    nib.save(img, p)
    src = open_source(p)
    assert src.dtype == np.float32
    np.testing.assert_allclose(src.read((0, 0, 0), src.shape), nib.load(p).get_fdata().transpose(2, 1, 0), rtol=1e-6)


def test_nifti_truncated_is_refused_naming_the_file(tmp_path, rng):
    p = tmp_path / "cut.nii"
    nib.save(nib.Nifti1Image(rng.random((16, 16, 16)).astype(np.float32), np.eye(4)), p)
    p.write_bytes(p.read_bytes()[:-1000])
    with pytest.raises(InputFormatError, match=r"cut\.nii: truncated"):
        open_source(p)


def test_nifti_gz_truncated_fails_cleanly_in_the_cli(tmp_path, rng, capsys):
    p = tmp_path / "cut.nii.gz"
    nib.save(nib.Nifti1Image(rng.random((16, 16, 40)).astype(np.float32), np.eye(4)), p)
    raw = gzip.decompress(p.read_bytes())
    p.write_bytes(gzip.compress(raw)[: len(gzip.compress(raw)) // 2])
    out = tmp_path / "cut.zarr"
    assert main(["brick", str(p), str(out), "--brick", "8", "--quiet"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "cut.nii.gz" in err[0] and "Traceback" not in err[0]
    assert not out.exists() or _attrs(out)["clipvol"]["complete"] is False  # never passed off as complete


def test_nifti_4d_with_many_volumes_is_refused(tmp_path):
    p = tmp_path / "fmri.nii"
    nib.save(nib.Nifti1Image(np.zeros((4, 4, 4, 3), np.float32), np.eye(4)), p)
    with pytest.raises(InputFormatError, match="fmri.nii: expected a 3-D"):
        open_source(p)


# -- DICOM ---------------------------------------------------------------------------------------
def test_dicom_series_sorted_by_position_with_rescale(tmp_path, rng):
    vol = rng.integers(0, 4000, size=(11, 14, 9)).astype(np.uint16)
    write_dicom_series(tmp_path / "ct", vol, spacing=(2.5, 0.8, 0.6), origin_lps=(-100, -120, 50), intercept=-1024)
    out = tmp_path / "ct.zarr"
    assert main(["brick", str(tmp_path / "ct"), str(out), "--brick", "8", "--quiet"]) == 0
    np.testing.assert_array_equal(_level0(out), vol.astype(np.int64) - 1024)
    cv = _attrs(out)["clipvol"]
    # by hand: LPS columns x = row direction * 0.6, y = column direction * 0.8, z = normal * 2.5,
    # origin (-100, -120, 50); RAS negates the first two rows
    want = np.array([[-0.6, 0, 0, 100], [0, -0.8, 0, 120], [0, 0, 2.5, 50], [0, 0, 0, 1]])
    np.testing.assert_allclose(cv["affine"], want, atol=1e-6)
    assert axis_codes(cv["affine"]) == nib.aff2axcodes(want) == ("L", "P", "S")
    scale, _ = _ome(out)
    np.testing.assert_allclose(scale, [2.5, 0.8, 0.6])


def test_dicom_oblique_orientation(tmp_path, rng):
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    row, col = (c, s, 0.0), (0.0, 0.0, -1.0)  # a coronal-ish plane rotated 30 degrees
    vol = rng.integers(0, 255, size=(5, 6, 7)).astype(np.uint8)
    write_dicom_series(tmp_path / "obl", vol, spacing=(3.0, 1.0, 2.0), row_dir=row, col_dir=col, origin_lps=(1, 2, 3))
    src = open_source(tmp_path / "obl")
    np.testing.assert_array_equal(src.read((0, 0, 0), src.shape), vol)
    normal = np.cross(row, col)
    lps = np.eye(4)
    lps[:3, 0], lps[:3, 1], lps[:3, 2], lps[:3, 3] = np.multiply(row, 2.0), np.multiply(col, 1.0), normal * 3.0, (1, 2, 3)
    np.testing.assert_allclose(src.frame.matrix, np.diag([-1, -1, 1, 1]) @ lps, atol=1e-5)
    assert src.frame.oblique
    assert axis_codes(src.frame.affine) == nib.aff2axcodes(src.frame.matrix)


def test_dicom_mixed_series_is_refused(tmp_path, rng):
    vol = rng.integers(0, 100, size=(3, 4, 4)).astype(np.uint16)
    write_dicom_series(tmp_path / "mix", vol, name_prefix="a")
    write_dicom_series(tmp_path / "mix", vol, name_prefix="b", origin_lps=(0, 0, 1.0))
    with pytest.raises(InputFormatError, match=r"mix: expected one DICOM series, got 2"):
        open_source(tmp_path / "mix")


def test_dicom_missing_slice_is_refused(tmp_path, rng):
    vol = rng.integers(0, 100, size=(6, 4, 4)).astype(np.uint16)
    files = write_dicom_series(tmp_path / "gap", vol, shuffle_seed=None)
    files[3].unlink()
    with pytest.raises(InputFormatError, match="gap: uneven slice spacing"):
        open_source(tmp_path / "gap")


def test_missing_extra_names_it(monkeypatch, tmp_path):
    import sys

    from clipvol.errors import MissingExtraError

    p = tmp_path / "x.nii"
    nib.save(nib.Nifti1Image(np.zeros((2, 2, 2), np.float32), np.eye(4)), p)
    monkeypatch.setitem(sys.modules, "nibabel", None)
    with pytest.raises(MissingExtraError, match=r"clipvol\[nifti\]"):
        open_source(p)
    assert issubclass(MissingExtraError, ClipvolError)
