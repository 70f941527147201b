"""A served view's state: the camera it means (against the preset camera and plain vector geometry)
and its checks (a wrong field refused whole, naming it)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.app.serve.state import ViewState, orbit_camera
from clipvol.scene.views import ARRAY_VIEWS, view_camera


@pytest.fixture
def pyr():
    return Pyramid.build((40, 48, 56), (16, 16, 16), (1.0, 1.0, 2.0))


def _d(cam):
    return np.asarray(cam.eye, dtype=float) - np.asarray(cam.target, dtype=float)


def test_unturned_is_the_presets_camera(pyr):
    for view in ARRAY_VIEWS:
        assert orbit_camera(pyr, view, (64, 48)) == view_camera(pyr, view, (64, 48))


def test_azimuth_turns_about_up_elevation_tilts_zoom_nears(pyr):
    base = view_camera(pyr, "front", (64, 64))
    d0, up = _d(base), np.asarray(base.up, dtype=float)
    a = orbit_camera(pyr, "front", (64, 64), azimuth=90.0)
    d1 = _d(a)
    assert np.linalg.norm(d1) == pytest.approx(np.linalg.norm(d0))
    assert abs(d1 @ d0) < 1e-9 * np.linalg.norm(d0) ** 2  # a quarter turn
    assert d1 @ up == pytest.approx(d0 @ up, abs=1e-9)  # about the up axis
    np.testing.assert_allclose(a.target, base.target)
    e = orbit_camera(pyr, "front", (64, 64), elevation=30.0)
    cos = _d(e) @ d0 / np.linalg.norm(d0) ** 2
    assert math.degrees(math.acos(min(1.0, cos))) == pytest.approx(30.0)
    z = orbit_camera(pyr, "front", (64, 64), zoom=2.0)
    np.testing.assert_allclose(_d(z), d0 / 2.0)


def _state(pyr):
    return ViewState(tuple(ARRAY_VIEWS), ("auto", "grey"), tuple(pyr.shape))


def test_apply_checks_every_field_and_applies_all_or_nothing(pyr):
    s = _state(pyr)
    assert s.apply({"azimuth": 10.0, "zoom": 2.0}) == {"camera"}
    assert s.apply({"tf": "grey", "mode": "mip"}) == {"look"}
    assert s.apply({"tf": "grey"}) == set()
    before = s.public()
    for bad, field in [({"zoom": 2.5, "tf": "nope"}, "tf"), ({"elevation": 120}, "elevation"),
                       ({"zoom": float("nan")}, "zoom"), ({"mode": "x"}, "mode"), ({"view": "anterior"}, "view"),
                       ({"window": [3, 1]}, "window"), ({"crop_voxels": [0, 0, 0, 8, 8, 41]}, "crop_voxels"),
                       ({"crop_voxels": "0,0"}, "crop_voxels"), ({"clip_plane": [0, 0, 0, 0, 0, 0]}, "clip_plane"),
                       ({"slice": "oblique"}, "slice"), ({"handled": 3}, "handled"), ({"zoom": True}, "zoom")]:
        with pytest.raises(ParameterError, match=field):
            s.apply(bad)
        assert s.public() == before  # nothing of the message applied
    assert s.apply({"view": "side"}) == {"camera", "look"}  # a preset: its own camera, unturned
    assert (s.azimuth, s.elevation, s.zoom) == (0.0, 0.0, 1.0)


def test_the_cut_is_the_crop_box_in_voxels(pyr):
    s = _state(pyr)
    assert s.cut(pyr) is None
    s.apply({"crop_voxels": [0, 0, 0, 56, 48, 20]})  # x, y, z
    shape = s.cut(pyr)
    sp = np.asarray(pyr.spacing, dtype=float)[::-1]
    inside = np.array([[10, 10, 10], [10, 10, 30]], dtype=float) * sp  # (x, y, z) points: z 10 in, z 30 out
    assert shape.contains(inside).tolist() == [True, False]
