"""WorldFrame: spacing, origin and obliqueness derived from an affine, against plain numpy algebra."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from clipvol.bricking.worldframe import WorldFrame
from clipvol.errors import ParameterError, StoreFormatError


@pytest.mark.parametrize("seed", range(5))
def test_origin_and_spacing_reproduce_the_affine(seed):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(random_state=seed).as_matrix()
    sp = rng.uniform(0.2, 3.0, 3)  # x, y, z
    aff = np.eye(4)
    aff[:3, :3] = rot * sp
    aff[:3, 3] = rng.uniform(-100, 100, 3)
    f = WorldFrame(tuple(map(tuple, aff)), "RAS")
    np.testing.assert_allclose(f.spacing, sp[::-1])
    # a voxel at index i sits at R @ (origin + spacing * i): the frame clipvol draws in, rotated
    idx = rng.uniform(0, 50, (7, 3))
    local = np.array(f.origin)[::-1] + idx * sp
    np.testing.assert_allclose(local @ rot.T, idx @ aff[:3, :3].T + aff[:3, 3], atol=1e-9)
    assert f.oblique


def test_axis_aligned_frame_and_with_spacing():
    f = WorldFrame.from_spacing((3.0, 2.0, 1.0), (30.0, 20.0, 10.0), "RAS")
    assert f.origin == (30.0, 20.0, 10.0) and f.spacing == (3.0, 2.0, 1.0) and not f.oblique
    g = WorldFrame(((-1, 0, 0, 5), (0, 0, 2, 0), (0, 3, 0, 0), (0, 0, 0, 1)))  # flipped + permuted: not oblique
    assert not g.oblique and g.with_spacing((1, 1, 1)).spacing == (1.0, 1.0, 1.0)
    assert g.with_spacing((1, 1, 1)).origin == g.origin


def test_bad_affines_are_refused():
    with pytest.raises(ParameterError, match="4x4"):
        WorldFrame(((1, 0), (0, 1)))
    with pytest.raises(ParameterError, match="independent"):
        WorldFrame(((1, 1, 0, 0), (0, 0, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1)))
    with pytest.raises(ParameterError, match="frame"):
        WorldFrame.from_spacing((1, 1, 1), frame="LPS")
    with pytest.raises(StoreFormatError, match=r"s\.zarr: attrs\['clipvol'\]\['affine'\]"):
        WorldFrame.from_attrs({"affine": [[1, 2, 3]]}, "s.zarr")
