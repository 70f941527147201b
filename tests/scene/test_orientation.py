"""Anatomical labels: array-axis codes against nibabel's aff2axcodes, view and slice edges by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.scene.orientation import axis_codes, direction_label, opposite, plane_labels, view_labels

nib = pytest.importorskip("nibabel")


def _signed_permutations():
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            m = np.zeros((4, 4))
            m[3, 3] = 1
            for c, (r, s) in enumerate(zip(perm, signs)):
                m[r, c] = s * (c + 1.5)
            yield m


@pytest.mark.parametrize("aff", list(_signed_permutations()), ids=lambda a: "".join(nib.aff2axcodes(a)))
def test_axis_codes_match_nibabel_for_all_48_orientations(aff):
    assert axis_codes(aff) == nib.aff2axcodes(aff)


def test_axis_codes_match_nibabel_for_small_obliques():
    from scipy.spatial.transform import Rotation

    for seed in range(20):
        rot = Rotation.from_rotvec(np.random.default_rng(seed).normal(size=3) * 0.3).as_matrix()
        base = next(itertools.islice(_signed_permutations(), seed * 2, None))
        aff = base.copy()
        aff[:3, :3] = rot @ base[:3, :3]
        assert axis_codes(aff) == nib.aff2axcodes(aff)


def test_direction_labels():
    assert direction_label((1, 0, 0)) == "R"
    assert direction_label((-0.2, 0, -1)) == "I"
    assert direction_label((0.7, -0.7, 0.1)) == "RP"
    assert direction_label((0, 0, 2), frame="") == "+Z"
    assert opposite("RP") == "LA" and opposite("-X") == "+X"
    with pytest.raises(ParameterError):
        direction_label((0, 0, 0))


def test_view_from_the_front_in_ras():
    # identity RAS volume: array x -> R, y -> A, z -> S. Looking at the face (from +A towards -A),
    # the patient's left is on screen right, superior up (radiological front view).
    labels = view_labels(np.eye(4), right=(-1, 0, 0), up=(0, 0, 1))
    assert labels == {"right": "L", "left": "R", "top": "S", "bottom": "I"}


def test_axial_slice_of_an_lps_dicom_volume():
    # DICOM axial series: columns run to patient's left, rows to posterior (LPS); in RAS the affine
    # negates x and y. Image vol[k]: column index -> right edge, row index -> bottom edge.
    aff = np.diag([-0.7, -0.7, 2.0, 1.0])
    assert plane_labels(aff, "z") == {"right": "L", "left": "R", "top": "A", "bottom": "P"}
    # a coronal image vol[:, j] of the same volume: columns L, rows S (row index = z grows up S)
    assert plane_labels(aff, "y") == {"right": "L", "left": "R", "top": "I", "bottom": "S"}
    with pytest.raises(ParameterError):
        plane_labels(aff, "w")
