"""``overlay_voxel``: the smallest voxel edge of an overlay's level in the primary's drawing frame,
the length the overlay's own sample spacing follows, against nibabel's ``voxel_sizes`` of the affine."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.worldframe import WorldFrame
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.scene.overlay import Overlay, overlay_voxel

nib = pytest.importorskip("nibabel")
from nibabel.affines import from_matvec, voxel_sizes  # noqa: E402


def _rot(deg_z: float, deg_x: float) -> np.ndarray:
    cz, sz = np.cos(np.radians(deg_z)), np.sin(np.radians(deg_z))
    cx, sx = np.cos(np.radians(deg_x)), np.sin(np.radians(deg_x))
    return np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]]) @ np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])


@pytest.mark.parametrize("primary_spacing", [(1.0, 1.0, 1.0), (2.5, 0.8, 1.2)])
def test_smallest_voxel_edge_of_a_rotated_anisotropic_overlay(primary_spacing):
    aff = from_matvec(_rot(15.0, 10.0) @ np.diag([2.0, 1.5, 3.0]), (5.0, -3.0, 2.0))  # voxel (x, y, z) -> world
    primary = NumpyLoader(np.zeros((20, 22, 24), np.float32), brick=8, spacing=primary_spacing)
    data = np.zeros((10, 12, 14), np.float32)  # (z, y, x): 14 x 12 x 10 voxels of 2 x 1.5 x 3 mm
    ov = Overlay(NumpyLoader(data, brick=8, spacing=(3.0, 1.5, 2.0)), "grey", frame=WorldFrame(aff, ""))
    assert overlay_voxel(ov, 0, primary) == pytest.approx(float(voxel_sizes(aff).min()), rel=1e-9)
    # level 1 halves every axis (ceil): each voxel edge of the level is twice as long
    assert ov.loader.pyramid.levels[1].shape == (5, 6, 7)
    assert overlay_voxel(ov, 1, primary) == pytest.approx(2.0 * float(voxel_sizes(aff).min()), rel=1e-9)
