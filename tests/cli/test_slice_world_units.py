"""`clipvol slice --through/--normal/--up/--poi` take world points (RAS+ mm of a NIfTI), x,y,z.

Reference: a NIfTI written here with an oblique, shifted affine (nibabel); each pixel's RAS point
(from the flags alone) goes through nibabel's inverse affine to a voxel, where scipy's trilinear
``map_coordinates`` of the array gives the value the slice must show.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.tools.cli import main

nib = pytest.importorskip("nibabel")
ndi = pytest.importorskip("scipy.ndimage")
pytest.importorskip("moderngl")
from nibabel.affines import apply_affine  # noqa: E402

SHAPE = (40, 36, 32)  # i, j, k of the NIfTI array
SIZE, PX = 24, 1.0


def _affine() -> np.ndarray:
    t = np.radians(20.0)  # rotated 20 degrees about x (an oblique acquisition), 1.5 x 1 x 2 mm, shifted
    rot = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    a = np.eye(4)
    a[:3, :3] = rot @ np.diag([1.5, 1.0, 2.0])
    a[:3, 3] = (-30.0, -25.0, 20.0)
    return a


def _volume() -> np.ndarray:
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float32) for n in SHAPE), indexing="ij")
    return (100 + 40 * np.sin(i / 5.0) + 30 * np.cos(j / 4.0) + 20 * np.sin(k / 3.0 + 1.0)).astype(np.float32)


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    d = tmp_path_factory.mktemp("oblique")
    path = d / "scan.nii.gz"
    nib.save(nib.Nifti1Image(_volume(), _affine()), str(path))
    # one brick: the values between bricks are not what this test is about
    assert main(["brick", str(path), str(d / "scan.zarr"), "--brick", "64"]) == 0
    return d / "scan.zarr"


def _reference(origin, right, up) -> np.ndarray:
    """Values at the pixel centres of a SIZE x SIZE image (row 0 at the top) through world ``origin``."""
    u = (np.arange(SIZE) + 0.5 - SIZE / 2.0) * PX
    v = (SIZE / 2.0 - (np.arange(SIZE) + 0.5)) * PX
    pts = np.asarray(origin) + u[None, :, None] * np.asarray(right) + v[:, None, None] * np.asarray(up)
    ijk = apply_affine(np.linalg.inv(_affine()), pts.reshape(-1, 3)).T
    inside = np.all((ijk >= 0) & (ijk <= np.array(SHAPE)[:, None] - 1), axis=0).reshape(SIZE, SIZE)
    vals = ndi.map_coordinates(_volume().astype(np.float64), ijk, order=1).reshape(SIZE, SIZE)
    return np.where(inside, vals, np.nan)


def _slice(scan, tmp_path, *flags) -> np.ndarray:
    out = tmp_path / "s.npy"
    assert main(["slice", str(scan), *flags, "--size", f"{SIZE}x{SIZE}", "--pixel-size", str(PX), "--level", "0",
                 "--npy", str(out)]) == 0
    return np.load(out)


def _close(got, want):
    both = np.isfinite(got) & np.isfinite(want)
    assert both.sum() > 0.8 * SIZE * SIZE  # the plane is inside the scan
    np.testing.assert_allclose(got[both], want[both], atol=1.0)  # values span 10..190: 8-bit GL weights


def test_origin_is_a_ras_point_in_mm(scan, tmp_path):
    origin = (-2.0, -19.0, 46.0)  # RAS z = 46 mm, far from array index 46 of any axis
    got = _slice(scan, tmp_path, "--through", "-2,-19,46", "--normal", "0,0,1", "--up", "0,1,0")
    _close(got, _reference(origin, right=(-1, 0, 0), up=(0, 1, 0)))  # right = normal x up, in the world


def test_oblique_normal_and_up_are_world_directions(scan, tmp_path):
    n = np.array([0.0, -0.3, 1.0]) / np.linalg.norm([0.0, -0.3, 1.0])
    up = np.array([0.0, 1.0, 0.3]) / np.linalg.norm([0.0, 1.0, 0.3])
    got = _slice(scan, tmp_path, "--through", "-2,-19,50", "--normal", "0,-0.3,1", "--up", "0,1,0.3")
    _close(got, _reference((-2.0, -19.0, 50.0), right=np.cross(n, up), up=up))


def test_poi_moves_the_axial_plane_to_its_ras_z(scan, tmp_path):
    # the axial plane of the patient through the poi: centred on the scan's centre moved onto it,
    # anterior up, the patient's right on the image left (radiological)
    centre = apply_affine(_affine(), (np.array(SHAPE) - 1) / 2.0)
    got = _slice(scan, tmp_path, "--axis", "axial", "--poi", "0,0,46")
    _close(got, _reference((centre[0], centre[1], 46.0), right=(-1, 0, 0), up=(0, 1, 0)))
    default = _slice(scan, tmp_path, "--axis", "axial")
    assert np.nanmax(np.abs(default - got)) > 5.0  # without --poi: the middle plane, elsewhere
