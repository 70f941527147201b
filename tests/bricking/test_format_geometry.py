"""Geometry that is not one rigid, orthogonal, evenly spaced grid is refused by the readers, saying
what differs; rotated but orthogonal geometry is kept.

The files are written here with pydicom (one slice per file, then single tags edited with
pydicom) and nibabel; the expected angles and offsets are computed by hand from what was written.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipvol.bricking.sources import open_source
from clipvol.errors import InputFormatError
from clipvol.tools.cli import main
from format_files import write_dicom_series

pydicom = pytest.importorskip("pydicom")
nib = pytest.importorskip("nibabel")

SPACING = (2.5, 0.8, 0.6)  # z (slice step), rows, columns in mm


def _series(tmp_path, **kw):
    vol = np.arange(6 * 5 * 4, dtype=np.uint16).reshape(6, 5, 4)
    folder = tmp_path / "dcm"
    write_dicom_series(folder, vol, spacing=SPACING, shuffle_seed=None, **kw)
    return folder, sorted(folder.glob("*.dcm"))


def _edit(path, **tags):
    ds = pydicom.dcmread(path)
    for k, v in tags.items():
        setattr(ds, k, v)
    ds.save_as(path)


def _position(path):
    return np.array([float(v) for v in pydicom.dcmread(path).ImagePositionPatient])


def test_a_slice_shifted_sideways_is_refused_naming_it(tmp_path):
    folder, files = _series(tmp_path)
    p = _position(files[3]) + np.array([3.0, 0.0, 0.0])  # 3 mm along the rows
    _edit(files[3], ImagePositionPatient=[f"{v:.6f}" for v in p])
    with pytest.raises(InputFormatError, match=rf"{files[3].name} lies 3 mm sideways.*row \+3 mm"):
        open_source(folder)


def test_rounding_of_positions_is_not_a_shift(tmp_path):
    folder, files = _series(tmp_path)
    p = _position(files[2]) + np.array([0.01, -0.01, 0.0])  # under 5 % of a 0.6 mm pixel
    _edit(files[2], ImagePositionPatient=[f"{v:.6f}" for v in p])
    assert open_source(folder).shape == (6, 5, 4)


def test_a_slice_with_another_pixel_spacing_is_refused(tmp_path, capsys):
    folder, files = _series(tmp_path)
    _edit(files[4], PixelSpacing=["0.900000", "0.600000"])
    with pytest.raises(InputFormatError, match=rf"{files[4].name}: PixelSpacing \(0.9, 0.6\) mm differs"):
        open_source(folder)
    assert main(["brick", str(folder), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "PixelSpacing" in err and not (tmp_path / "o.zarr").exists()


def test_gantry_tilt_is_refused_with_its_angle(tmp_path):
    folder, files = _series(tmp_path)
    shift = 0.5  # mm along the columns per slice: a stack tilted by atan(0.5 / 2.5)
    first = _position(files[0])
    for k, f in enumerate(files):
        p = first + np.array([0.0, k * shift, k * SPACING[0]])
        _edit(f, ImagePositionPatient=[f"{v:.6f}" for v in p])
    tilt = math.degrees(math.atan2(shift, SPACING[0]))
    with pytest.raises(InputFormatError, match=rf"tilted by {tilt:.2f}°.*gantry tilt"):
        open_source(folder)


def test_uneven_slice_spacing_is_refused(tmp_path):
    folder, files = _series(tmp_path)
    p = _position(files[3]) + np.array([0.0, 0.0, 0.4])
    _edit(files[3], ImagePositionPatient=[f"{v:.6f}" for v in p])
    with pytest.raises(InputFormatError, match="uneven slice spacing"):
        open_source(folder)


def test_rotated_orthogonal_series_is_accepted(tmp_path):
    c, s = math.cos(0.3), math.sin(0.3)
    folder, _ = _series(tmp_path, row_dir=(c, s, 0.0), col_dir=(0.0, 0.0, -1.0))
    src = open_source(folder)
    a = np.asarray(src.frame.affine)
    # RAS columns: LPS row direction * 0.6 with x, y negated
    np.testing.assert_allclose(a[:3, 0], np.array([-c, -s, 0.0]) * SPACING[2], atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(a[:3, :3], axis=0), [SPACING[2], SPACING[1], SPACING[0]], rtol=1e-5)


def _nifti(tmp_path, affine):
    img = nib.Nifti1Image(np.zeros((4, 5, 6), np.int16), np.eye(4))
    img.set_sform(affine, code=2)  # the sform as given (the qform, a rotation, cannot hold a shear)
    p = tmp_path / "v.nii"
    nib.save(img, p)
    return p


def test_sheared_nifti_sform_is_refused_with_its_angle(tmp_path, capsys):
    a = np.diag([1.0, 1.0, 2.5, 1.0])
    a[1, 2] = 0.5  # k moves 0.5 mm in y per slice: the j and k axes meet at acos(0.5 / |(0, 0.5, 2.5)|)
    p = _nifti(tmp_path, a)
    angle = math.degrees(math.acos(0.5 / math.hypot(0.5, 2.5)))
    with pytest.raises(InputFormatError, match=rf"sform affine is sheared: its j \(y\) and k \(z\) axes meet at {angle:.3f}°"):
        open_source(p)
    assert main(["brick", str(p), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    assert "sheared" in capsys.readouterr().err and not (tmp_path / "o.zarr").exists()


def test_rotated_nifti_is_accepted_as_it_is(tmp_path):
    c, s = math.cos(0.4), math.sin(0.4)
    a = np.eye(4)
    a[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([0.7, 0.9, 3.0])
    a[:3, 3] = (10.0, -20.0, 5.0)
    src = open_source(_nifti(tmp_path, a))
    np.testing.assert_allclose(np.asarray(src.frame.affine), a, atol=1e-5)


def test_singular_nifti_affine_is_refused(tmp_path):
    a = np.diag([1.0, 0.0, 2.0, 1.0])
    with pytest.raises(InputFormatError, match=r"j \(y\) axis zero length"):
        open_source(_nifti(tmp_path, a))


mrcfile = pytest.importorskip("mrcfile")


@pytest.mark.parametrize("cella,needles", [
    ((0.0, 0.0, 0.0), ["records no voxel size", "--spacing"]),
    ((float("nan"), 8.0, 8.0), ["cell size", "nan"]),
    ((0.0, 8.0, 8.0), ["cell size", "0.0, 8.0, 8.0"]),
    ((-8.0, 8.0, 8.0), ["cell size", "-8.0"]),
])
def test_mrc_cell_size_that_is_no_size_is_refused(tmp_path, capsys, cella, needles):
    p = tmp_path / "m.mrc"
    with mrcfile.new(p) as m:
        m.set_data(np.ones((4, 4, 4), np.float32))
        m.header.cella = cella
    assert main(["brick", str(p), str(tmp_path / "o.zarr"), "--quiet", "--brick", "8"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "m.mrc" in err and all(n in err for n in needles), err
    assert not (tmp_path / "o.zarr").exists()


def test_mrc_without_a_voxel_size_bricks_with_spacing(tmp_path):
    import json

    p = tmp_path / "m.mrc"
    with mrcfile.new(p) as m:
        m.set_data(np.ones((4, 4, 4), np.float32))
    assert main(["brick", str(p), str(tmp_path / "o.zarr"), "--quiet", "--brick", "8", "--spacing", "1,2,3"]) == 0  # x,y,z
    attrs = json.loads((tmp_path / "o.zarr" / "zarr.json").read_text())["attributes"]
    assert attrs["clipvol"]["spacing"] == [3.0, 2.0, 1.0]
