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
    for n in range(91, 140):
        if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists():
            return n
    pytest.skip("no free X display number in :91..:139")


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
        v.key("L")  # gradient lighting: the lit shader variant draws, opacity unchanged
        v.step()
        assert v.session.action.params.shading and v.session.action.defines()["SHADING"]
        lit = v.read_screen()
        assert np.abs(lit.astype(int) - unlit)[..., :3].max() > 10
        v.key("L")
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
