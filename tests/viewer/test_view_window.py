"""The viewer window under Xvfb: it opens, renders, takes screenshots, and shows what offscreen renders."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("glfw")
pytest.importorskip("moderngl")


def _free_display() -> int:
    # each pytest-xdist worker looks among its own numbers: two workers starting their servers at
    # once never both take the same free one
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    first = 91 + 20 * int(worker[2:] or 0)
    for n in range(first, first + 20):
        if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists():
            return n
    pytest.skip(f"no free X display number in :{first}..:{first + 19}")


@pytest.fixture(scope="module")
def xdisplay():
    if not shutil.which("Xvfb"):
        pytest.skip("Xvfb not installed: the window test needs a virtual X server (apt install xvfb)")
    n = _free_display()
    proc = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", "640x480x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    sock = Path(f"/tmp/.X11-unix/X{n}")
    for _ in range(100):
        if sock.exists() or proc.poll() is not None:
            break
        time.sleep(0.05)
    if proc.poll() is not None or not sock.exists():
        proc.kill()
        pytest.skip(f"Xvfb :{n} did not start")
    old = os.environ.get("DISPLAY")
    os.environ["DISPLAY"] = f":{n}"
    try:
        yield f":{n}"
    finally:
        if old is None:
            os.environ.pop("DISPLAY", None)
        else:
            os.environ["DISPLAY"] = old
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:  # pragma: no cover
            proc.kill()


@pytest.fixture(scope="module")
def loader():
    from clipvol.loaders.procedural import ProceduralLoader

    return ProceduralLoader("procedural:fractal?size=48&seed=2", brick=16)


def _converge(viewer, limit=200):
    for _ in range(limit):
        viewer.step()
        fs = viewer.session.frame_stats
        if fs is not None and fs.converged and viewer.session.clip_texture.stats.queued == 0:
            break
        time.sleep(0.01)
    viewer.step(force=True)
    assert viewer.session.frame_stats.converged


def _over_black(img):
    return img[..., :3].astype(np.float64) * img[..., 3:4] / 255.0


def test_window_matches_offscreen_render(xdisplay, loader, tmp_path):
    """Also: an offscreen EGL context made *before* the window keeps working after it (see _EglUnbound)."""
    from clipvol.app.session import RenderSession
    from clipvol.render.context import create_context
    from clipvol.viewer.window import Viewer

    ctx = create_context()
    with Viewer(loader, size=(96, 72), tf="viridis", screenshot_dir=tmp_path, visible=False) as v:
        v.key("H")  # HUD off: the screen then shows the frame only
        _converge(v)
        screen = v.read_screen()
        cam = v.camera()
        coi = v.controls.center_of_interest
        v.key("P")
        v.step()
        shot = v.last_screenshot
        assert shot is not None and shot.is_file()
        from PIL import Image

        np.testing.assert_array_equal(np.asarray(Image.open(shot)), screen)
        # outlines change the picture (B), and the HUD draws text over it (H)
        v.key("B")
        v.step(force=True)
        outlined = v.read_screen()
        v.key("H")
        v.step(force=True)
        with_hud = v.read_screen()
    assert screen.shape == (72, 96, 3)
    assert screen.max() > 50 and (screen.sum(axis=-1) > 0).mean() > 0.1  # not blank
    assert np.abs(outlined.astype(int) - screen).max() > 50
    assert np.abs(with_hud[:20, :40].astype(int) - outlined[:20, :40]).max() > 0
    # the same view rendered offscreen (EGL), composited over the window's black background
    try:
        from clipvol.scene.params import RenderParams

        # the viewer jitters its lattice (a stable per-pixel offset): so does this render
        with RenderSession(loader, ctx, tf="viridis", params=RenderParams(jitter=True)) as s:
            ref = s.render(cam, coi, wait=True)
    finally:
        ctx.release()
    diff = np.abs(screen.astype(np.float64) - _over_black(ref))
    assert diff.max() <= 3.0, diff.max()
    assert diff.mean() < 0.6


def test_window_controls_change_the_view(xdisplay, loader):
    from clipvol.viewer.window import Viewer

    with Viewer(loader, size=(64, 64), visible=False) as v:
        v.key("H")
        _converge(v)
        a = v.read_screen()
        v.controls.orbit(60, 0)
        v.step()
        b = v.read_screen()
        assert np.abs(a.astype(int) - b).max() > 20
        v.key("M")  # roaming
        v.key("]")  # fixed level 1
        assert v.session.params.policy == "fixed" and v.session.params.level == 1
        v.step()
        assert set(v.session.frame_stats.bricks_drawn) <= {1, 2}
        unlit = v.read_screen()
        v.key("N")  # gradient lighting: the lit shader variant draws, opacity unchanged
        v.step()
        assert v.session.action.params.shading and v.session.action.defines()["SHADING"]
        lit = v.read_screen()
        assert np.abs(lit.astype(int) - unlit)[..., :3].max() > 10
        v.key("N")
        assert not v.session.params.shading
        v.key("I")
        v.step()
        assert v.session.action.params.mode == "mip"
        v.key("ESCAPE")
        assert v.should_close()


def test_view_cli_runs_a_few_frames(xdisplay):
    from clipvol.tools.cli import main

    assert main(["view", "procedural:fractal?size=32", "--brick", "16", "--size", "64x48", "--max-frames", "3"]) == 0


def test_no_display_is_a_clear_error(monkeypatch, capsys):
    from clipvol.tools.cli import main

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", "procedural:fractal?size=16", "--max-frames", "1"]) == 2
    err = capsys.readouterr().err
    assert "display" in err and "--offscreen" in err and err.count("\n") == 1


def test_window_adapts_while_moving_and_refines_when_still(xdisplay, loader):
    """While the camera moves the frame is smaller than the window (scaled up), once still it is full size."""
    from clipvol.viewer.window import Viewer

    with Viewer(loader, size=(128, 96), visible=False, frame_time=1e-4) as v:  # an unreachable target
        _converge(v)
        assert v._frame.shape[:2] == (96, 128)
        v.controls.orbit(30, 0)
        v.step()
        assert not v._quality.full and v._frame.shape[0] < 96 and v._frame.shape[1] < 128
        assert v.session.params.step > 0.5  # the sample step grows too
        assert v.session.params.policy == "fixed"  # one whole level: a cut drawn again while the view turns
        v.controls.orbit(2, 0)
        v.step()
        assert v.session.frame_stats.replayed and not v._quality.full
        time.sleep(v.adaptive.settle_s + 0.05)
        v.step()
        assert v._quality.full and v._frame.shape[:2] == (96, 128) and v.session.params.step == 0.5
        assert v.session.params.policy == v.state.mode and v.session.params.level is None
        assert v.adaptive.state == "refined"
        _converge(v)
        still, cam, coi = v._frame, v._frame_camera, v.controls.center_of_interest
    # the still frame after a drag is the frame of a session that never moved (the user's LOD and step)
    from clipvol.app.session import RenderSession
    from clipvol.render.context import create_context
    from clipvol.scene.params import RenderParams

    ctx = create_context()
    try:
        with RenderSession(loader, ctx, params=RenderParams(jitter=True)) as s:
            ref = s.render(cam, coi, wait=True)
    finally:
        ctx.release()
    np.testing.assert_array_equal(still, ref)


def test_window_saves_tf_and_camera_and_takes_screenshots_without_hud(xdisplay, loader, tmp_path):
    import json

    from PIL import Image

    from clipvol.app.session import RenderSession
    from clipvol.render.context import create_context
    from clipvol.scene.bookmarks import load_camera
    from clipvol.scene.transfer import TransferFunction
    from clipvol.viewer.window import Viewer

    shots = tmp_path / "shots"
    with Viewer(loader, size=(96, 72), visible=False, screenshot_dir=shots) as v:
        _converge(v)
        w0 = v.tf.window(loader.pyramid.value_range)
        v.key("RIGHT")
        v.key("UP")
        w1 = v.tf.window(loader.pyramid.value_range)
        span = loader.pyramid.value_range[1] - loader.pyramid.value_range[0]
        assert (w1[0] + w1[1]) / 2 == pytest.approx((w0[0] + w0[1]) / 2 + 0.05 * span)
        assert w1[1] - w1[0] == pytest.approx(1.25 * (w0[1] - w0[0]))
        assert v.session.transfer_function.value_range == pytest.approx(w1)
        v.key("shift+S")
        tf_file = shots / "tf-0000.json"
        assert json.loads(tf_file.read_text())["value_range"] == pytest.approx(list(w1))
        np.testing.assert_array_equal(TransferFunction.load(tf_file).table, v.tf.table)
        v.controls.orbit(40, 10)
        v.key("C")
        cam = v.camera()
        v.key("shift+P")
        nohud = shots / "clipvol-0000-nohud.png"
        img = np.asarray(Image.open(nohud))
        # the camera file restores the view; a second viewer started from it sees the same camera
        saved = load_camera(shots / "camera-0000.json", size=cam.size)
        np.testing.assert_allclose(saved.eye, cam.eye)
        np.testing.assert_allclose(saved.target, cam.target)
        tf = v.tf
    with Viewer(loader, size=(96, 72), visible=False, camera=saved) as v2:
        np.testing.assert_allclose(v2.camera().eye, cam.eye, atol=1e-9)
        np.testing.assert_allclose(v2.camera().target, cam.target, atol=1e-9)
    # the screenshot without HUD is the offscreen render of that camera (RGBA, no text)
    assert img.shape == (72, 96, 4)
    ctx = create_context()
    try:
        from clipvol.scene.params import RenderParams

        with RenderSession(loader, ctx, params=RenderParams(jitter=True)) as s:  # the viewer's default
            s.update(tf=tf)
            ref = s.render(cam, None, wait=True)
    finally:
        ctx.release()
    assert np.abs(img.astype(int) - ref).max() <= 2


def test_dragging_on_the_histogram_moves_and_widens_the_window(xdisplay, loader):
    from clipvol.viewer.window import Viewer

    with Viewer(loader, size=(320, 240), visible=False) as v:
        v.step(force=True)  # draws the HUD, which places the histogram strip
        assert v._strip_rect is not None
        x0, y0, x1, y1 = v._strip_rect
        h = v._histogram()
        span = float(h.edges[-1] - h.edges[0])
        lo, hi = v.tf.window(loader.pyramid.value_range)
        lo2, hi2 = v.drag_window(0.5 * (x1 - x0 - 12))  # half the plot's width to the right
        assert lo2 == pytest.approx(lo + 0.5 * span) and hi2 == pytest.approx(hi + 0.5 * span)
        lo3, hi3 = v.drag_window(100, widen=True)  # x2
        assert hi3 - lo3 == pytest.approx(2 * (hi2 - lo2)) and (lo3 + hi3) / 2 == pytest.approx((lo2 + hi2) / 2)
        assert v.session.transfer_function.value_range == pytest.approx((lo3, hi3))


def test_window_on_a_dicom_store_is_head_up_and_labelled(xdisplay, tmp_path):
    """A patient-frame store opens seen from the front, head up, and the HUD names the edges."""
    pytest.importorskip("pydicom")
    from format_files import write_dicom_series

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.viewer.window import Viewer

    vol = np.zeros((16, 16, 16), np.uint16)
    vol[10:14, 4:12, 10:14] = 1000  # patient's left (high x), superior (high z)
    write_dicom_series(tmp_path / "ct", vol, spacing=(1.0, 1.0, 1.0))
    brick_volume(tmp_path / "ct", tmp_path / "ct.zarr", brick=8, progress=False)
    with Viewer(str(tmp_path / "ct.zarr"), size=(96, 96), tf="grey") as viewer:
        _converge(viewer)
        assert viewer._orientation() == {"right": "L", "left": "R", "top": "S", "bottom": "I"}
        assert any("left R  right L  top S  bottom I" in ln for ln in (viewer._hud_text or []))


def test_window_draws_an_overlay_like_the_offscreen_session(xdisplay, loader, tmp_path):
    """``Viewer(params=RenderParams(overlays=...))``: the OVERLAY variant draws, the screen equals an
    offscreen session with the same overlay, and MIP (key I) is refused with a message, not a crash."""
    from clipvol.app.session import RenderSession
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.render.context import create_context
    from clipvol.scene.overlay import Overlay
    from clipvol.scene.params import RenderParams
    from clipvol.viewer.window import Viewer

    z, y, x = np.mgrid[0:20, 0:20, 0:20].astype(np.float32)
    blob = np.exp(-((x - 10) ** 2 + (y - 10) ** 2 + (z - 10) ** 2) / 30.0) * 4.0 - 1.0
    from clipvol.scene.transfer import TransferFunction

    tf = TransferFunction.preset("diverging", value_range=(-0.5, 0.5))
    prim = TransferFunction.preset("grey", value_range=(0.6, 1.0))  # see-through: the overlay shows
    ov = Overlay(NumpyLoader(blob, brick=16, spacing=(1.5, 1.5, 1.5)), tf, origin=(10.0, 10.0, 10.0))
    params = RenderParams(jitter=True, overlays=(ov,))
    ctx = create_context()
    with Viewer(loader, size=(80, 64), tf=prim, params=params, visible=False) as v:
        v.key("H")
        _converge(v)
        assert v.session.action.defines()["OVERLAY"] == 1
        screen = v.read_screen()
        cam, coi = v.camera(), v.controls.center_of_interest
        v.key("I")  # MIP: refused while overlays are drawn
        v.step()
        assert v.session.params.mode == "composite" and "overlay" in v.state.message
    try:
        with RenderSession(loader, ctx, tf=prim, params=params) as s:
            ref = s.render(cam, coi, wait=True)
        with RenderSession(loader, ctx, tf=prim, params=RenderParams(jitter=True)) as s:
            plain = s.render(cam, coi, wait=True)
    finally:
        ctx.release()
    assert np.abs(_over_black(ref) - _over_black(plain)).max() > 40  # the overlay shows
    diff = np.abs(screen.astype(np.float64) - _over_black(ref))
    assert diff.max() <= 3.0 and diff.mean() < 0.6, (diff.max(), diff.mean())


def test_view_cli_with_an_overlay_runs_a_few_frames(xdisplay, tmp_path):
    from clipvol.tools.cli import main

    np.save(tmp_path / "m.npy", np.linspace(-1, 1, 16 ** 3, dtype=np.float32).reshape(16, 16, 16))
    assert main(["brick", str(tmp_path / "m.npy"), str(tmp_path / "m.zarr"), "--brick", "8", "--quiet", "--no-summary",
                 "--origin", "4,4,4"]) == 0
    assert main(["view", "procedural:fractal?size=32", "--brick", "16", "--size", "64x48", "--max-frames", "3",
                 "--overlay", f"{tmp_path / 'm.zarr'}:diverging"]) == 0
    # a segmentation of the store, each label its colour, one hidden
    img = np.random.default_rng(1).random((16, 16, 16)).astype(np.float32)
    seg = np.zeros((16, 16, 16), dtype=np.uint8)
    seg[4:10, 4:10, 4:10], seg[10:14, 2:8, 8:14] = 3, 7
    np.save(tmp_path / "img.npy", img)
    np.save(tmp_path / "seg.npy", seg)
    assert main(["brick", str(tmp_path / "img.npy"), str(tmp_path / "img.zarr"), "--brick", "8", "--quiet", "--no-summary",
                 "--labels", f"{tmp_path / 'seg.npy'}:seg"]) == 0
    assert main(["view", str(tmp_path / "img.zarr"), "--size", "48x48", "--max-frames", "2", "--label-overlay", "seg",
                 "--label-colors", "3=#ff0000:0.6,7=hide"]) == 0


def test_window_plays_pauses_and_steps_a_time_series(xdisplay):
    """Space plays (a step is shown once it is drawn), J / K step, the HUD shows t, the rate and the
    prefetch state; the frame of step t is the frame of a session over step t alone."""
    from clipvol.app.session import RenderSession
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.render.context import create_context
    from clipvol.scene.params import RenderParams
    from clipvol.viewer.window import Viewer

    z, y, x = np.mgrid[:24, :24, :24].astype(np.float32)
    steps = [np.exp(-((x - 6 - 6 * t) ** 2 + (y - 12) ** 2 + (z - 12) ** 2) / 20.0).astype(np.float32) for t in range(3)]
    loaders = [NumpyLoader(s, brick=16, value_range=(0.0, 1.0)) for s in steps]
    with Viewer(loaders[0], size=(64, 64), tf="viridis", series=loaders, rate=50.0, visible=False, frame_time=None) as v:
        v.key("H")
        _converge(v)
        first = v.read_screen()
        v.key("K")
        assert v.session.step == 1 and not v.playback.playing
        _converge(v)
        second = v.read_screen()
        cam, coi = v.camera(), v.controls.center_of_interest
        v.key("H")
        v.step(force=True)
        assert any(line.startswith("t 1/2 paused") for line in v._hud_text)
        v.key("SPACE")
        seen = {v.session.step}
        for _ in range(400):  # bounded: 3 steps at <= 50 steps/s, each drawn before the next
            v.step()
            seen.add(v.session.step)
            if len(seen) == 3:
                break
            time.sleep(0.005)
        assert seen == {0, 1, 2}
        v.key("SPACE")
        assert not v.playback.playing
    assert np.abs(first.astype(int) - second).max() > 30  # the blob moved
    ctx = create_context()
    try:
        with RenderSession(loaders[1], ctx, tf="viridis", params=RenderParams(jitter=True)) as s:
            ref = s.render(cam, coi, wait=True)
    finally:
        ctx.release()
    diff = np.abs(second.astype(np.float64) - _over_black(ref))
    assert diff.max() <= 3.0, diff.max()


def test_view_cli_plays_a_t_axis_and_refuses_a_store_without_one(xdisplay, tmp_path, capsys):
    import zarr

    from clipvol.tools.cli import main

    data = np.random.default_rng(0).random((3, 16, 16, 16)).astype(np.float32)
    g = zarr.open_group(str(tmp_path / "ts.zarr"), mode="w")
    g.create_array("0", shape=data.shape, chunks=(1, 16, 16, 16), dtype="float32")[...] = data
    axes = [{"name": "t", "type": "time"}] + [{"name": a, "type": "space"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1, 1]}]}]}]}})
    assert main(["view", str(tmp_path / "ts.zarr"), "--play", "--size", "48x48", "--max-frames", "4"]) == 0
    capsys.readouterr()
    assert main(["view", "procedural:fractal?size=32", "--brick", "16", "--play", "--max-frames", "2"]) == 2
    assert "--play" in capsys.readouterr().err


def test_window_on_a_mirrored_nifti_is_the_patient_not_its_mirror(xdisplay, tmp_path):
    """An LAS NIfTI (array axes a mirror of the patient) opens seen from the front, head up, the
    patient's left on screen right: the marker at the left-anterior-superior corner sits top right."""
    pytest.importorskip("nibabel")
    from world_volumes import write_copy

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.viewer.window import Viewer

    brick_volume(write_copy(tmp_path, "las"), tmp_path / "las.zarr", brick=8, progress=False)
    with Viewer(str(tmp_path / "las.zarr"), size=(96, 96), tf="grey") as viewer:
        viewer.key("H")
        _converge(viewer)
        assert viewer._orientation() == {"right": "L", "left": "R", "top": "S", "bottom": "I"}
        lum = viewer._frame[..., 0].astype(np.float64)
        rows, cols = np.nonzero(lum > 0.8 * lum.max())
        h, w = lum.shape
        assert rows.mean() < h / 2 and cols.mean() > w / 2
