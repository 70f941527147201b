"""`clipvol render scan.nii.gz --view anterior` and the turntable: the patient head-up, facing us,
whatever the file's storage order.

A synthetic RAS volume carries a bright marker at the patient's left-anterior-superior corner; its
LAS copy (x flipped) and a permuted-axes copy hold the same patient (nibabel's ``aff2axcodes`` and
``apply_affine`` say so). Seen from the front with the head up the marker must sit top right (the
patient's left is on the viewer's right), in every copy, and the three images must agree.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

nib = pytest.importorskip("nibabel")
pytest.importorskip("moderngl")

from world_volumes import RAS, SHAPE, marker_volume as _volume, write_copy as _write  # noqa: E402


def _render(tmp_path, name: str, *extra: str) -> np.ndarray:
    src = _write(tmp_path, name)
    out = tmp_path / f"{name}.png"
    assert main(["render", src, "--store", str(tmp_path / f"{name}.zarr"), "--out", str(out), "--view", "anterior",
                 "--size", "64x64", "--mode", "mip", "--tf", "grey", "--tf-range", "0,1000", "--ortho", *extra]) == 0
    return np.asarray(Image.open(out).convert("RGBA"), dtype=np.float64)


def _marker_centre(img: np.ndarray) -> np.ndarray:
    bright = img[..., 0] > 200
    assert bright.any()
    rows, cols = np.nonzero(bright)
    return np.array([rows.mean(), cols.mean()])


def test_anterior_view_shows_the_marker_top_right_in_every_storage_order(tmp_path):
    imgs = {n: _render(tmp_path, n, "--no-labels") for n in ("ras", "las", "perm")}
    for n, img in imgs.items():
        r, c = _marker_centre(img)
        assert r < 32 and c > 32, f"{n}: marker at row {r:.1f}, column {c:.1f}, expected top right"
    for n in ("las", "perm"):
        np.testing.assert_allclose(_marker_centre(imgs[n]), _marker_centre(imgs["ras"]), atol=1.0)
        assert np.abs(imgs[n] - imgs["ras"]).mean() < 4.0, n


def test_anterior_view_is_lettered_unless_no_labels(tmp_path):
    plain = _render(tmp_path, "las", "--no-labels")
    lettered = _render(tmp_path, "las")
    differs = np.any(plain != lettered, axis=-1)
    # letters at the middle of each edge (R left, L right, S top, I bottom), nothing in the centre
    assert differs[28:36, :10].any() and differs[28:36, -10:].any() and differs[:10, 28:36].any() and differs[-10:, 28:36].any()
    assert not differs[20:44, 20:44].any()


def test_turntable_starts_from_the_front_head_up(tmp_path):
    for name in ("ras", "las"):
        src = _write(tmp_path, name)
        out = tmp_path / f"{name}_frames"
        assert main(["view", src, "--store", str(tmp_path / f"{name}.zarr"), "--offscreen", "--converged", "--path", "turntable",
                     "--frames", "1", "--size", "64x64", "--mode", "mip", "--tf", "grey", "--tf-range", "0,1000",
                     "--no-labels", "--out", str(out)]) == 0
        img = np.asarray(Image.open(out / "frame_0000.png").convert("RGBA"), dtype=np.float64)
        r, c = _marker_centre(img)
        assert r < 32 and c > 32, f"{name}: marker at row {r:.1f}, column {c:.1f}, expected top right"


def test_show_takes_a_nifti_and_shows_it_head_up_in_grey(tmp_path):
    pytest.importorskip("anywidget")
    import clipvol

    src = _write(tmp_path, "las")
    with clipvol.show(src, store=str(tmp_path / "las.zarr"), size=(64, 64), mode="mip", threads=2, labels=False) as v:
        img = v.snapshot().astype(np.float64)
        assert v.tf == "grey"  # a scan in a patient frame is shown in grey
        np.testing.assert_array_equal(img[..., 0], img[..., 1])
        lum = img[..., 0]
        rows, cols = np.nonzero(lum > 0.9 * lum.max())
        assert rows.mean() < 32 and cols.mean() > 32, "the marker (left, anterior, superior) top right from the front"


def test_render_scan_with_a_map_in_another_orientation_and_grid_shows_the_map(tmp_path):
    # a T1-like RAS scan (a solid head) and a signed map stored LAS on a coarser grid (3 mm), its
    # positive blob at the patient's left-anterior-superior: with no flags the map shows, in place
    t1 = np.zeros((40, 40, 40), np.float32)
    ii, jj, kk = np.meshgrid(*(np.arange(40),) * 3, indexing="ij")
    t1[(ii - 19.5) ** 2 + (jj - 19.5) ** 2 + (kk - 19.5) ** 2 < 18 ** 2] = 300.0
    t1_aff = np.array([[2.0, 0, 0, -39], [0, 2.0, 0, -39], [0, 0, 2.0, -39], [0, 0, 0, 1]])
    nib.save(nib.Nifti1Image(t1, t1_aff), tmp_path / "t1.nii.gz")
    m = np.zeros((26, 26, 26), np.float32)
    m_aff = np.array([[-3.0, 0, 0, 37.5], [0, 3.0, 0, -37.5], [0, 0, 3.0, -37.5], [0, 0, 0, 1]])  # LAS
    assert nib.aff2axcodes(m_aff) == ("L", "A", "S")
    centre = np.linalg.solve(m_aff, [-15.0, 15.0, 15.0, 1.0])[:3]  # left (-x), anterior, superior, in mm
    a, b, c = np.meshgrid(*(np.arange(26),) * 3, indexing="ij")
    m[(a - centre[0]) ** 2 + (b - centre[1]) ** 2 + (c - centre[2]) ** 2 < 3.5 ** 2] = 5.0
    m[0, 0, 0] = -5.0  # signed: the diverging map
    nib.save(nib.Nifti1Image(m, m_aff), tmp_path / "map.nii.gz")
    out = tmp_path / "both.png"
    cwd = tmp_path / "cache"
    cwd.mkdir()
    import os

    old = os.getcwd()
    os.chdir(cwd)  # the bricked stores go to the working folder
    try:
        assert main(["render", str(tmp_path / "t1.nii.gz"), "--overlay", str(tmp_path / "map.nii.gz"), "--view", "anterior",
                     "--size", "96x96", "--ortho", "--no-labels", "--out", str(out)]) == 0
    finally:
        os.chdir(old)
    assert (cwd / "t1.zarr").is_dir() and (cwd / "map.zarr").is_dir()
    img = np.asarray(Image.open(out).convert("RGBA"), dtype=np.float64)
    red = (img[..., 0] - np.maximum(img[..., 1], img[..., 2])) > 40  # the map's positive colour
    assert red.sum() > 10, "the map is hidden"
    rows, cols = np.nonzero(red)
    assert rows.mean() < 48 and cols.mean() > 48, f"map at row {rows.mean():.1f}, column {cols.mean():.1f}: expected top right"
    grey = (np.abs(img[..., 0] - img[..., 2]) < 3) & (img[..., 3] > 0)
    assert grey.sum() > 1000  # the scan shows as grey context around it


def test_turntable_starts_from_the_side_view_names(tmp_path):
    # from the patient's left, head up: anterior is on the image's left, so the marker is top left
    src = _write(tmp_path, "las")
    out = tmp_path / "left"
    assert main(["view", src, "--store", str(tmp_path / "las.zarr"), "--offscreen", "--converged", "--path", "turntable", "--view", "left",
                 "--frames", "1", "--size", "64x64", "--mode", "mip", "--tf", "grey", "--tf-range", "0,1000",
                 "--no-labels", "--out", str(out)]) == 0
    r, c = _marker_centre(np.asarray(Image.open(out / "frame_0000.png").convert("RGBA"), dtype=np.float64))
    assert r < 32 and c < 32, f"marker at row {r:.1f}, column {c:.1f}, expected top left"
    assert main(["view", src, "--store", str(tmp_path / "las.zarr"), "--offscreen", "--converged", "--path", "orbit", "--view", "left",
                 "--frames", "1", "--out", str(tmp_path / "o")]) == 2


def test_orbit_of_a_patient_is_head_up(tmp_path):
    # the default offscreen path: a patient-frame store circles head-up from the front, raised 25 degrees
    src = _write(tmp_path, "perm")
    out = tmp_path / "orbit"
    assert main(["view", src, "--store", str(tmp_path / "perm.zarr"), "--offscreen", "--converged", "--frames", "1", "--size", "64x64",
                 "--mode", "mip", "--tf", "grey", "--tf-range", "0,1000", "--no-labels", "--out", str(out)]) == 0
    r, c = _marker_centre(np.asarray(Image.open(out / "frame_0000.png").convert("RGBA"), dtype=np.float64))
    assert r < 32 and c > 32, f"marker at row {r:.1f}, column {c:.1f}, expected top right"


def test_anatomical_view_of_a_store_without_a_patient_frame_is_refused(tmp_path, capsys):
    np.save(tmp_path / "v.npy", np.ones((8, 8, 8), np.float32))
    assert main(["render", str(tmp_path / "v.npy"), "--view", "anterior", "--out", str(tmp_path / "v.png")]) == 2
    assert "--view anterior: expected a store with a patient frame" in capsys.readouterr().err
    assert not (tmp_path / "v.png").exists()
