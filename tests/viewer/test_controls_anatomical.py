"""The viewer's orbit rig on a patient-frame store: head-up, seen from the front, labels that follow.

References: anatomy by hand (an axial DICOM series: array x -> patient's left, y -> posterior,
z -> superior) and the default rig's behaviour (identity rotation unchanged).
"""

from __future__ import annotations

import numpy as np

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.orientation import anatomical_axes, view_labels
from clipvol.viewer.controls import OrbitControls

AFF = np.diag([-0.6, -0.8, 2.5, 1.0])  # RAS affine of an axial LPS series


def _pyr():
    return Pyramid.build((40, 64, 64), (16, 16, 16), (2.5, 0.8, 0.6), "mean", np.int16, (0.0, 1.0), 0.0)


def test_rig_starts_head_up_from_the_front_and_orbits_about_superior():
    up, front = anatomical_axes(AFF)
    rig = OrbitControls.for_pyramid(_pyr(), size=(96, 64), up=up, front=front, azimuth=0.0, elevation=0.0)
    cam = rig.camera((96, 64))
    assert view_labels(AFF, cam.right, cam.up) == {"right": "L", "left": "R", "top": "S", "bottom": "I"}
    for dx in (90 / rig.rotate_speed, 90 / rig.rotate_speed):  # two quarter turns by dragging
        rig.orbit(dx, 0.0)
        cam = rig.camera((96, 64))
        assert view_labels(AFF, cam.right, cam.up)["top"] == "S"  # stays head-up
    assert view_labels(AFF, cam.right, cam.up)["right"] == "R"  # half a turn: seen from behind
    f, r, u = rig.basis()
    np.testing.assert_allclose([f, r, u], [cam.forward, cam.right, cam.up], atol=1e-9)


def test_default_rig_is_unchanged():
    a = OrbitControls.for_pyramid(_pyr(), size=(96, 64))
    b = OrbitControls(a.target, a.distance, a.azimuth, a.elevation, rotation=np.eye(3))
    np.testing.assert_allclose(a.eye, b.eye)
    np.testing.assert_allclose(a.camera().up, b.camera().up)
    np.testing.assert_allclose(a.world_up, [0, -1, 0])


def test_hud_names_the_edges_of_the_current_view():
    from clipvol.viewer.hud import hud_lines

    up, front = anatomical_axes(AFF)
    rig = OrbitControls.for_pyramid(_pyr(), size=(96, 64), up=up, front=front, azimuth=0.0, elevation=0.0)
    cam = rig.camera((96, 64))
    lines = hud_lines(fps=10.0, orientation=view_labels(AFF, cam.right, cam.up))
    assert "left R  right L  top S  bottom I" in lines
    assert not any("left" in ln for ln in hud_lines(fps=10.0))
