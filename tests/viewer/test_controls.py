"""Viewer input mapping without a window: orbit/pan/zoom/fly and the keys' settings."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.viewer.controls import MODES, OrbitControls, ViewState
from clipvol.viewer.hud import composite_over, hud_lines, render_text
from clipvol.app.overlay import (
    box_segments,
    clip_segment,
    draw_outlines,
    project_points,
)


@pytest.fixture
def pyr():
    return Pyramid.build((32, 48, 64), (16, 16, 16))


def _pixel(cam, p):
    """Independent projection: pixel (col, row) of world point p from the camera's rays geometry."""
    d = p - cam.eye
    z = d @ cam.forward
    w, h = cam.size
    t = np.tan(np.radians(cam.fov_y) / 2)
    x = (d @ cam.right) / z / (t * w / h)
    y = (d @ cam.up) / z / t
    return np.array([(x + 1) / 2 * w, (1 - y) / 2 * h])


def test_orbit_keeps_distance_and_target(pyr):
    c = OrbitControls.for_pyramid(pyr, size=(64, 64))
    t0, eye0 = c.target.copy(), c.eye.copy()
    c.orbit(40, -25)
    np.testing.assert_allclose(c.target, t0)
    np.testing.assert_allclose(np.linalg.norm(c.eye - c.target), np.linalg.norm(eye0 - t0))
    assert not np.allclose(c.eye, eye0)
    cam = c.camera((64, 64))
    np.testing.assert_allclose(cam.eye, c.eye)
    np.testing.assert_allclose(cam.forward, c.forward, atol=1e-12)
    # elevation is clamped short of the pole
    c.orbit(0, 1e6)
    assert c.elevation <= 89.0
    c.camera((64, 64))  # still a valid camera


def test_drag_right_moves_the_data_right(pyr):
    c = OrbitControls(target=(0, 0, 0), distance=10.0, azimuth=0.0, elevation=0.0)
    p = np.array([0.0, 0.0, -1.0])  # a point on the front face, between eye and target
    before = _pixel(c.camera((100, 100)), p)
    c.orbit(10, 0)
    after = _pixel(c.camera((100, 100)), p)
    assert after[0] > before[0]


def test_pan_moves_the_target_point_with_the_cursor(pyr):
    c = OrbitControls.for_pyramid(pyr, size=(80, 60))
    p = c.target.copy()
    cam0 = c.camera((80, 60))
    np.testing.assert_allclose(_pixel(cam0, p), [40, 30], atol=1e-9)
    c.pan(7, -5, size=(80, 60))
    cam1 = c.camera((80, 60))
    np.testing.assert_allclose(_pixel(cam1, p), [47, 25], atol=1e-6)
    np.testing.assert_allclose(project_points(cam1, p), [47, 25], atol=1e-6)


def test_zoom_scales_distance_and_wheel_sign(pyr):
    c = OrbitControls.for_pyramid(pyr)
    d0 = c.distance
    c.zoom(2)
    np.testing.assert_allclose(c.distance, d0 / c.zoom_step**2)
    c.zoom(-2)
    np.testing.assert_allclose(c.distance, d0)
    c.zoom(1e6)
    assert c.distance == pytest.approx(c.min_distance)


def test_fly_moves_eye_and_centre_together_inside_the_box(pyr):
    c = OrbitControls.for_pyramid(pyr)
    c.zoom(8)
    lo, hi = pyr.volume_box()
    eye0, t0 = c.eye.copy(), c.target.copy()
    assert c.move_keys({"W"}, dt=0.5, speed=4.0)
    np.testing.assert_allclose(c.target - t0, 2.0 * c.forward, atol=1e-9)
    np.testing.assert_allclose(c.eye - eye0, c.target - t0, atol=1e-9)
    t1 = c.target.copy()
    c.move_keys({"D"}, dt=1.0, speed=1.0)
    _, right, _ = c.basis()
    np.testing.assert_allclose(c.target - t1, right, atol=1e-9)
    assert not c.move_keys(set(), dt=1.0, speed=1.0)
    for _ in range(50):
        c.move_keys({"W", "Q"}, dt=1.0, speed=100.0)
        assert np.all(c.center_of_interest >= lo) and np.all(c.center_of_interest <= hi)
    c.reset()
    np.testing.assert_allclose(c.target, t0)


def test_controls_validate():
    with pytest.raises(ParameterError, match="distance"):
        OrbitControls(target=(0, 0, 0), distance=0)
    with pytest.raises(ParameterError, match="target"):
        OrbitControls(target=(0, 0), distance=1)
    with pytest.raises(ParameterError, match="fov_y"):
        OrbitControls(target=(0, 0, 0), distance=1, fov_y=180)


def test_view_state_keys():
    s = ViewState(num_levels=4)
    seen = []
    for _ in range(3):
        assert s.handle_key("m")
        seen.append(s.mode)
    assert seen == list(MODES[1:]) + [MODES[0]]
    s.handle_key("]")
    s.handle_key("]")
    assert (s.mode, s.level) == ("fixed", 2)
    for _ in range(10):
        s.handle_key("]")
    assert s.level == 3
    for _ in range(10):
        s.handle_key("[")
    assert s.level == 0
    t0 = s.lod_threshold
    s.handle_key("+")
    assert s.lod_threshold == 2 * t0
    s.handle_key("-")
    s.handle_key("-")
    assert s.lod_threshold == t0 / 2
    s.handle_key("I")
    assert s.render_mode == "mip"
    s.handle_key("I")
    assert s.render_mode == "composite"
    names = [s.tf_name]
    for _ in range(len(s.tf_presets)):
        s.handle_key("T")
        names.append(s.tf_name)
    assert names[0] == names[-1] and len(set(names)) == len(s.tf_presets)
    assert not s.outlines and s.handle_key("B") and s.outlines
    assert s.hud and s.handle_key("H") and not s.hud
    s.handle_key("P")
    s.handle_key("ESCAPE")
    assert s.screenshot and s.quit
    assert not s.handle_key("Z")


def test_outlines_project_box_edges(pyr):
    c = OrbitControls.for_pyramid(pyr, size=(64, 64), azimuth=0, elevation=0)
    cam = c.camera((64, 64))
    lo, hi = pyr.volume_box()
    segs = box_segments(cam, lo, hi)
    assert len(segs) == 12
    ends = np.array(segs).reshape(-1, 2)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    expect = np.array([_pixel(cam, p) for p in corners])
    # every segment end is one of the projected corners
    dist = np.linalg.norm(ends[:, None, :] - expect[None, :, :], axis=-1).min(axis=1)
    assert dist.max() < 1e-6

    class Item:
        level = 1

    item = Item()
    item.lo, item.hi = lo, hi
    img = draw_outlines(np.zeros((64, 64, 4), np.uint8), cam, [item])
    drawn = np.argwhere(img[..., 3] > 0)
    assert len(drawn)
    # drawn pixels lie inside the projected box's bounding rectangle and include its extreme corners
    assert drawn[:, 1].min() >= np.floor(expect[:, 0].min()) - 1 and drawn[:, 1].max() <= np.ceil(expect[:, 0].max())
    np.testing.assert_array_equal(img[drawn[0][0], drawn[0][1], :3], (255, 160, 32))


def test_outline_near_plane_clipping():
    c = OrbitControls(target=(0, 0, 0), distance=1.0, azimuth=0, elevation=0)
    cam = c.camera((32, 32))
    # a box around the eye: edges behind the eye are clipped, no NaN
    segs = box_segments(cam, cam.eye - 5, cam.eye + 5)
    assert all(np.all(np.isfinite(s)) for s in segs)
    assert clip_segment((-10, 5, 10, 5), (0, 0, 8, 8)) == (0, 5, 8, 5)
    assert clip_segment((-10, -5, -1, -5), (0, 0, 8, 8)) is None


def test_hud_text_and_composite():
    class FS:
        bricks_drawn = {0: 3, 2: 1}
        bytes_uploaded = 2_000_000
        texture_bytes = 10_000_000
        texture_budget = 64_000_000
        converged = False

    class TS:
        resident_bytes_per_level = (1_000_000, 0, 500_000)
        queued = 7
        loads_per_s = 12.0
        mb_per_s = 3.5
        failures = 0

    lines = hud_lines(fps=30.0, frame_stats=FS(), texture_stats=TS(), settings={"mode": "fixed"}, message="hi")
    text = "\n".join(lines)
    assert "30.0 fps" in text and "drawn 4 bricks" in text and "L0:3" in text and "L2:1" in text
    assert "resident 1.5 MB" in text and "queue 7" in text and "refining" in text and lines[-1] == "hi"
    img = render_text(lines)
    assert img.dtype == np.uint8 and img.shape[2] == 4
    assert (img[..., :3] == 255).any()  # some white text
    base = np.zeros((200, 400, 4), np.uint8)
    base[..., 3] = 255
    out = composite_over(base, img)
    # reference blend in float
    h, w = min(img.shape[0], 200), min(img.shape[1], 400)
    a = img[:h, :w, 3:4] / 255.0
    ref = img[:h, :w, :3] / 255.0 * a
    np.testing.assert_allclose(out[:h, :w, :3] / 255.0, ref, atol=1 / 255 + 1e-6)


def test_render_params_validate():
    from clipvol.scene.params import RenderParams

    assert RenderParams(policy="fixed").level == 0
    assert RenderParams().policy == "projected-size"
    with pytest.raises(ParameterError, match="selection"):  # no second name for policy
        RenderParams.from_kwargs(selection="fixed")
    for bad in (dict(lod_threshold=0), dict(policy="best"), dict(policy="multiresolution"), dict(mode="x-ray"), dict(step=-1), dict(level=-1),
                dict(texture_budget="lots"), dict(focus=(1, 2)), dict(background=(0, 0, 0))):
        with pytest.raises(ParameterError):
            RenderParams(**bad)


@pytest.mark.parametrize("rig", [{}, {"up": (0.0, 0.0, 1.0), "front": (0.0, -1.0, 0.0)}])
def test_set_camera_restores_a_saved_view(rig):
    """A bookmark (eye, target, fov) read back into the rig gives the same camera, rotated rig too."""
    from clipvol.scene.bookmarks import camera_from_json, camera_to_json

    pyr = Pyramid.build((40, 50, 60), (16, 16, 16))
    a = OrbitControls.for_pyramid(pyr, size=(96, 64), **rig)
    a.orbit(37, -21)
    a.pan(5, 3, (96, 64))
    a.zoom(2)
    cam = camera_from_json(camera_to_json(a.camera((96, 64))))
    b = OrbitControls.for_pyramid(pyr, size=(96, 64), **rig)
    b.set_camera(cam)
    got = b.camera((96, 64))
    np.testing.assert_allclose(got.eye, cam.eye, atol=1e-9)
    np.testing.assert_allclose(got.target, cam.target, atol=1e-9)
    np.testing.assert_allclose(got.up, cam.up, atol=1e-9)
    assert got.fov_y == cam.fov_y
