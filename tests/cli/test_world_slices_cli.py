"""`clipvol slice scan.nii.gz --axis axial|coronal|sagittal`: the patient's planes, shown the
radiological way, the same for any storage order.

Reference: the RAS volume's numpy array indexed by hand (axial: anterior up, the patient's right on
the image's left; coronal: superior up, right on the left; sagittal: superior up, anterior on the
left) and nibabel's ``apply_affine`` for which voxel index of each copy holds the wanted plane.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.tools.cli import main

from world_volumes import RAS, SHAPE, marker_volume as _volume, write_copy as _write

nib = pytest.importorskip("nibabel")
pytest.importorskip("moderngl")
from nibabel.affines import apply_affine  # noqa: E402

#: the voxel (i, j, k) of the RAS volume each slice passes through: inside the marker
AT = np.array([1, SHAPE[1] - 2, SHAPE[2] - 2])


def _expected(axis: str, neurological: bool = False) -> np.ndarray:
    v = _volume()
    i, j, k = AT
    img = {"axial": lambda: v[:, :, k].T[::-1, ::-1],  # rows: anterior first; columns: right to left
           "coronal": lambda: v[:, j, :].T[::-1, ::-1],  # rows: superior first; columns: right to left
           "sagittal": lambda: v[i, :, :].T[::-1, ::-1]}[axis]()  # rows: superior first; columns: anterior to posterior
    return img[:, ::-1] if neurological and axis != "sagittal" else img


def _index(name: str, axis: str) -> float:
    """The index (along the copy's array axis nearest the plane normal) of the RAS voxel AT."""
    aff = {"ras": RAS, "las": RAS @ np.array([[-1.0, 0, 0, SHAPE[0] - 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
           "perm": RAS @ np.array([[0.0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])}[name]
    idx = apply_affine(np.linalg.inv(aff), apply_affine(RAS, AT))
    world_axis = {"axial": 2, "coronal": 1, "sagittal": 0}[axis]
    c = int(np.argmax(np.abs(aff[world_axis, :3])))  # the copy's array axis along that patient axis
    return float(idx[c])


@pytest.mark.parametrize("axis", ["axial", *(pytest.param(a, marks=pytest.mark.slow) for a in ("coronal", "sagittal"))])
def test_patient_planes_in_the_radiological_display(tmp_path, axis):
    for name in ("ras", "las", "perm"):
        src = _write(tmp_path, name)
        out = tmp_path / f"{name}_{axis}.npy"
        assert main(["slice", src, "--store", str(tmp_path / f"{name}.zarr"), "--axis", axis,
                     "--index", str(_index(name, axis)), "--npy", str(out), "--level", "0"]) == 0
        np.testing.assert_allclose(np.load(out), _expected(axis), atol=1e-3, err_msg=f"{name} {axis}")


def test_neurological_flag_puts_the_right_on_the_right(tmp_path):
    src = _write(tmp_path, "las")
    out = tmp_path / "n.npy"
    assert main(["slice", src, "--store", str(tmp_path / "las.zarr"), "--axis", "axial", "--neurological",
                 "--index", str(_index("las", "axial")), "--npy", str(out), "--level", "0"]) == 0
    np.testing.assert_allclose(np.load(out), _expected("axial", neurological=True), atol=1e-3)


def test_slice_png_is_lettered_unless_no_labels(tmp_path):
    from PIL import Image

    src = _write(tmp_path, "perm")
    imgs = []
    for extra in ((), ("--no-labels",)):
        out = tmp_path / f"c{len(extra)}.png"
        assert main(["slice", src, "--store", str(tmp_path / "perm.zarr"), "--axis", "coronal", "--size", "64x64",
                     "--pixel-size", "0.8", "--out", str(out), *extra]) == 0
        imgs.append(np.asarray(Image.open(out).convert("RGBA")))
    differs = np.any(imgs[0] != imgs[1], axis=-1)
    assert differs[26:38, :12].any() and differs[26:38, -12:].any() and differs[:12, 26:38].any() and differs[-12:, 26:38].any()
    assert not differs[20:44, 20:44].any()


def test_info_prints_voxel_0_in_the_ras_frame(tmp_path, capsys):
    # an LAS map with 3 mm voxels: voxel 0 lies 78 mm to the patient's right (x = +78 in RAS)
    aff = np.array([[-3.0, 0, 0, 78.0], [0, 3.0, 0, -112.0], [0, 0, 3.0, -50.0], [0, 0, 0, 1]])
    assert nib.aff2axcodes(aff) == ("L", "A", "S")
    nib.save(nib.Nifti1Image(np.ones((6, 5, 4), np.float32), aff), tmp_path / "map.nii.gz")
    store = tmp_path / "map.zarr"
    assert main(["brick", str(tmp_path / "map.nii.gz"), str(store), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["info", str(store)]) == 0
    line = next(t for t in capsys.readouterr().out.splitlines() if t.startswith("origin"))
    x, y, z = nib.affines.apply_affine(aff, (0, 0, 0))
    assert line.split()[1:4] == [f"{x:g},", f"{y:g},", f"{z:g}"] and "RAS" in line


def test_neurological_needs_a_patient_plane(tmp_path, capsys):
    np.save(tmp_path / "v.npy", np.ones((8, 8, 8), np.float32))
    assert main(["slice", str(tmp_path / "v.npy"), "--axis", "axial", "--neurological", "--npy", str(tmp_path / "a.npy")]) == 2
    assert "--neurological: expected an --axis slice" in capsys.readouterr().err
    src = _write(tmp_path, "ras")
    assert main(["slice", src, "--store", str(tmp_path / "ras.zarr"), "--plane", "z=3", "--neurological",
                 "--npy", str(tmp_path / "b.npy")]) == 2
    assert "got --plane or --through/--normal" in capsys.readouterr().err
