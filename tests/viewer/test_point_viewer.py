"""``clipvol view POINTS.zarr``: the tolerance keys, the HUD, and the window against an offscreen render.

The key table and the controller are tested without a window; the window itself (under Xvfb)
must show what :class:`clipvol.app.point_session.PointSession` renders offscreen for the same
camera, and ``]`` must draw fewer points.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.viewer.hud import point_hud_lines
from clipvol.viewer.point_keys import TOLERANCE_LADDER, PointViewState
from test_view_window import xdisplay  # noqa: F401  (the Xvfb fixture, shared)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    from clipvol.bricking.point_sources import ClusteredPointSource
    from clipvol.bricking.point_store import build_point_store

    path = tmp_path_factory.mktemp("pv") / "pts.zarr"
    build_point_store(ClusteredPointSource(20000, seed=3), path, max_points=512, progress=False)
    return path


def test_brackets_walk_the_tolerance_ladder_and_stop_at_its_ends():
    st = PointViewState(tolerance=0.05)
    seen = []
    for _ in range(len(TOLERANCE_LADDER) + 2):
        assert st.handle_key("[")
        seen.append(st.tolerance)
    assert seen[: TOLERANCE_LADDER.index(0.05)] == list(TOLERANCE_LADDER[: TOLERANCE_LADDER.index(0.05)][::-1])
    assert st.tolerance == TOLERANCE_LADDER[0]  # clamped
    up = []
    for _ in range(len(TOLERANCE_LADDER) + 2):
        st.handle_key("]")
        up.append(st.tolerance)
    assert up == sorted(up) and up[-1] == TOLERANCE_LADDER[-1]
    assert "%" in st.message
    # from a value off the ladder, the next rung each way
    st = PointViewState(tolerance=0.03)
    st.handle_key("]")
    assert st.tolerance == 0.05
    st = PointViewState(tolerance=0.03)
    st.handle_key("[")
    assert st.tolerance == 0.02


def test_other_keys_and_validation():
    st = PointViewState.starting_at("12px", (600, 400))
    assert st.tolerance == pytest.approx(0.02) and st.tolerance_px((600, 400)) == pytest.approx(12)
    assert st.handle_key("i") and st.render_mode == "mip"
    assert st.handle_key("I") and st.render_mode == "composite"
    names = [st.tf_name]
    for _ in range(len(st.tf_presets)):
        st.handle_key("T")
        names.append(st.tf_name)
    assert names[0] == names[-1] and len(set(names)) == len(st.tf_presets)
    assert not st.shading and st.handle_key("n") and st.shading and "lighting on" in st.message
    assert st.hud and st.handle_key("H") and not st.hud
    for k in ("P", "R", "ESCAPE"):
        assert st.handle_key(k)
    assert st.screenshot and st.reset and st.quit
    assert not st.handle_key("M") and not st.handle_key("Z")
    with pytest.raises(ParameterError, match="tolerance"):
        PointViewState(tolerance=0.0)
    with pytest.raises(ParameterError, match="tolerance"):
        PointViewState.starting_at("abc", (10, 10))


def test_hud_lines_name_points_nodes_tolerance_and_fps():
    from clipvol.render.splat import SplatFrameStats

    fs = SplatFrameStats(nodes_drawn=12, points_drawn=3456, nodes_per_depth={1: 4, 2: 8}, missing=3, converged=False)
    lines = point_hud_lines(fps=12.5, frame_stats=fs, tolerance=0.05, size=(400, 300), message="hello")
    text = "\n".join(lines)
    assert "12.5 fps" in text
    assert "points 3,456" in text and "nodes 12" in text and "d1:4 d2:8" in text
    assert "tolerance 5 % of the screen = 20.0 px" in text
    assert "3 nodes loading" in text and lines[-1] == "hello"


def test_the_key_ladder_drives_the_session_and_points_fall_as_tolerance_grows(gl, store):
    """The controller's logic headless: each ``]`` applied to a session draws no more points than before."""
    from clipvol.app.point_session import PointSession
    from clipvol.scene.camera import Camera

    with PointSession(store, gl, threads=2, tolerance=TOLERANCE_LADDER[0]) as s:
        lo, hi = s.volume_box()
        c = (lo + hi) / 2
        cam = Camera.perspective(tuple(c + np.array([0.8, 0.6, 1.5]) * (hi - lo)), tuple(c), fov_y=35, size=(96, 96))
        st = PointViewState(tolerance=TOLERANCE_LADDER[0])
        points, nodes = [], []
        for _ in range(len(TOLERANCE_LADDER)):
            s.update(tolerance=st.tolerance)
            s.render(cam, c, wait=True, timeout=60)
            assert s.frame_stats.converged
            points.append(s.frame_stats.points_drawn)
            nodes.append(s.frame_stats.nodes_drawn)
            st.handle_key("]")
        # the total number of drawn nodes at depth >= d shrinks too; points is the paper's measure
        assert all(a >= b for a, b in zip(points, points[1:])), points
        assert points[0] > 4 * points[-1], points
        with pytest.raises(ParameterError, match="tolerance"):
            s.update(tolerance="-3px")


def _converge(v, limit=300):
    for _ in range(limit):
        v.step()
        fs = v.session.frame_stats
        if v.frames_rendered and fs.converged and v.session.clip_texture.stats.queued == 0:
            break
        time.sleep(0.01)
    v.step(force=True)
    assert v.session.frame_stats.converged


def test_point_window_matches_offscreen_and_keys_change_the_tolerance(xdisplay, store, tmp_path):
    from clipvol.app.point_session import PointSession
    from clipvol.render.context import create_context
    from clipvol.viewer.point_window import PointViewer

    ctx = create_context()
    try:
        with PointViewer(store, size=(96, 80), tolerance="4px", screenshot_dir=tmp_path, visible=False) as v:
            v.key("H")  # HUD off: the screen shows the frame only
            _converge(v)
            screen = v.read_screen()
            cam, coi = v.camera(), v.controls.center_of_interest
            tol = v.state.tolerance
            fine = v.session.frame_stats.points_drawn
            v.key("]")
            v.key("]")
            assert v.state.tolerance > tol and v.session.tolerance == v.state.tolerance
            _converge(v)
            assert v.session.frame_stats.points_drawn < fine
            unlit = v.read_screen()
            v.key("N")  # lighting from the points' gradients
            assert v.session.action.shading
            v.step(force=True)
            assert np.abs(v.read_screen().astype(int) - unlit).max() > 10
            v.key("N")
            v.key("H")
            v.step(force=True)
            assert any("points" in line for line in v._hud_text) and any("tolerance" in line for line in v._hud_text)
            with_hud = v.read_screen()
            v.key("P")
            v.step()
            assert v.last_screenshot is not None and v.last_screenshot.is_file()
            v.key("ESCAPE")
            assert v.should_close()
        with PointSession(store, ctx, tolerance=tol) as s:
            ref = s.render(cam, coi, wait=True, timeout=60)
    finally:
        ctx.release()
    over_black = ref[..., :3].astype(np.float64) * ref[..., 3:4] / 255.0
    diff = np.abs(screen.astype(np.float64) - over_black)
    assert screen.max() > 50 and (screen.sum(axis=-1) > 0).mean() > 0.05  # not blank
    assert diff.max() <= 3.0, diff.max()
    assert np.abs(with_hud[:20, :40].astype(int) - screen[:20, :40]).max() > 0


def test_view_cli_opens_a_point_store(xdisplay, store):
    from clipvol.tools.cli import main

    assert main(["view", str(store), "--size", "64x48", "--tolerance", "5%", "--max-frames", "3"]) == 0
    assert main(["view", str(store), "--offscreen"]) == 2
