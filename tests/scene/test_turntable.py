"""The turntable path: one upright turn about a given axis, first seen from a given side (pure numpy)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.scene.orientation import anatomical_axes, view_labels
from clipvol.scene.paths import make_path, turntable


def _pyr():
    return Pyramid.build((11, 14, 9), (8, 8, 8), (2.5, 0.8, 0.6), "mean", np.uint16, (0.0, 1.0), 0.0)


def test_turntable_geometry():
    pyr = _pyr()
    up = np.array([0.0, 0.0, 1.0])
    n = 8
    cams = list(turntable(pyr, n, size=(64, 48), up=up, front=(0.2, -1.0, 0.3)))
    assert len(cams) == n
    c = cams[0][1]
    lo, hi = pyr.volume_box()
    np.testing.assert_allclose(c, (lo + hi) / 2)
    eyes = np.array([cam.eye for cam, _ in cams]) - c
    dist = np.linalg.norm(eyes, axis=1)
    np.testing.assert_allclose(dist, dist[0])  # a circle ...
    np.testing.assert_allclose(eyes @ up, 0.0, atol=1e-9)  # ... in the plane perpendicular to up
    f0 = eyes[0] / dist[0]
    np.testing.assert_allclose(f0, np.array([0.2, -1.0, 0.0]) / np.hypot(0.2, 1.0))  # first eye: front's horizontal part
    ang = [np.degrees(np.arctan2(np.cross(f0, e / dist[0]) @ up, f0 @ e / dist[0])) % 360 for e in eyes]
    np.testing.assert_allclose(ang, np.arange(n) * 360.0 / n, atol=1e-6)  # equal steps, one turn, no repeat
    for cam, _ in cams:
        assert cam.up @ up > 0.999  # upright
    assert len(list(make_path("turntable", pyr, 3))) == 3
    with pytest.raises(ParameterError, match="front"):
        list(turntable(pyr, 2, up=(0, 0, 1), front=(0, 0, 5)))


def test_turntable_of_a_dicom_patient_starts_from_the_front():
    # an axial DICOM series in RAS: array x -> patient's left, y -> posterior, z -> superior
    aff = np.diag([-0.6, -0.8, 2.5, 1.0])
    up, front = anatomical_axes(aff)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(front, [0, -1, 0], atol=1e-12)
    cams = [cam for cam, _ in turntable(_pyr(), 4, up=up, front=front)]
    # facing the patient: their left on screen right, head up
    assert view_labels(aff, cams[0].right, cams[0].up) == {"right": "L", "left": "R", "top": "S", "bottom": "I"}
    # a quarter turn (right-handed about S) puts the eye at the patient's left: anterior on screen left
    assert view_labels(aff, cams[1].right, cams[1].up) == {"right": "P", "left": "A", "top": "S", "bottom": "I"}
    assert view_labels(aff, cams[2].right, cams[2].up)["right"] == "R"  # from behind
