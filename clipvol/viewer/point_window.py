"""The window of ``clipvol view POINTS.zarr``: splats of a point store around a :class:`PointSession`.

The volume viewer's loop (:mod:`clipvol.viewer.window`) with points for bricks: each iteration
polls input (mouse and WASD/QE through :class:`~clipvol.viewer.controls.OrbitControls`, keys through
:class:`~clipvol.viewer.point_keys.PointViewState`) and, when the camera, a setting, the window
size or the clip-texture's residency changed (a node arrived), or the last frame had not
converged, draws a frame *without waiting* for I/O: resident ancestors stand in for nodes still
loading and the picture refines as they arrive. ``[`` / ``]`` make the tolerance finer / coarser
(Meredith & Ma 2001: the largest splat, a fraction of the screen), the HUD shows fps, points and
nodes drawn and the tolerance. It shares the window set-up (GLFW, the EGL unbinding, the
full-window quad) with the volume viewer.

Driven programmatically (``PointViewer.step()``, ``key()``, ``read_screen()``) by
``tests/viewer/test_point_viewer.py`` under Xvfb.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..app.point_session import PointSession
from .controls import OrbitControls
from .hud import point_hud_lines, render_text
from .point_keys import PointViewState
from .gl_window import GlWindow

__all__ = ["PointViewer"]


class _Frame:
    """What :meth:`OrbitControls.for_pyramid` reads of a pyramid: the box and a length scale."""

    def __init__(self, lo, hi, spacing: float) -> None:
        self._box = (np.asarray(lo, np.float64), np.asarray(hi, np.float64))
        self.spacing = (spacing,) * 3

    def volume_box(self):
        return self._box


class PointViewer(GlWindow):
    """A GLFW window showing a point store as splats under a screen-space tolerance.

    Parameters
    ----------
    source : path or PointStoreLoader
        A store written by ``clipvol brick-points``.
    size : (int, int)
        Window size.
    tolerance : float or str
        The starting tolerance (``0.05``, ``"5%"``, ``"12px"``).
    memory_budget : int or str
        Clip-texture budget.
    threads : int, optional
        Loader threads.
    mode : {"composite", "mip"}
    tf : str or TransferFunction
        The starting transfer function (a preset name heads the ``T`` cycle).
    screenshot_dir : str or Path
        Where ``P`` writes ``clipvol-points-NNNN.png``.
    visible : bool
        Show the window (tests render into a hidden one).
    title : str
    background : (r, g, b)
    """

    def __init__(self, source, *, size=(960, 640), tolerance=0.05, memory_budget="256MB", threads=None,
                 mode: str = "composite", tf="viridis", screenshot_dir=".", visible: bool = True,
                 title: str = "clipvol points", background=(0.0, 0.0, 0.0), shading: bool = False) -> None:
        self._open(size, visible=visible, title=title, no_display="set DISPLAY, or use clipvol render",
                   make_session=lambda ctx: PointSession(source, ctx, memory_budget=memory_budget, threads=threads,
                                                         tolerance=tolerance, mode=mode, tf=tf, shading=shading))
        from ..scene.transfer import TransferFunction

        first = tf if isinstance(tf, str) else (self.session.tf.name or "custom")
        presets = (first,) + tuple(n for n in TransferFunction.names() if n != first)
        self._first_tf = self.session.tf
        self.state = PointViewState.starting_at(tolerance, self.framebuffer_size, tf_presets=presets, render_mode=mode,
                                                shading=bool(shading))
        self.session.update(tolerance=self.state.tolerance)
        lo, hi = self.session.volume_box()
        meta = self.session.loader.meta
        self.controls = OrbitControls.for_pyramid(_Frame(lo, hi, meta.point_spacing or meta.edge * 1e-3),
                                                  size=self.framebuffer_size)
        self._init_view_state(screenshot_dir, background)  # _drag: (button, x, y)
        self._install_callbacks()

    # -- input ----------------------------------------------------------------------------------
    def _on_key(self, win, key, scancode, action, mods) -> None:
        glfw = self._glfw
        if glfw.KEY_A <= key <= glfw.KEY_Z:
            name = chr(ord("A") + key - glfw.KEY_A)
        elif key == glfw.KEY_ESCAPE:
            name = "ESCAPE"
        else:
            return  # printable keys such as [ ] arrive through _on_char (keyboard layouts differ)
        if self._hold(name, action):
            return
        if action == glfw.PRESS:
            self.key(name)

    def _on_char(self, win, codepoint) -> None:
        ch = chr(codepoint)
        if ch in "[]":
            self.key(ch)

    def _on_button(self, win, button, action, mods) -> None:
        glfw = self._glfw
        if action == glfw.PRESS:
            x, y = glfw.get_cursor_pos(win)
            self._drag = (button, x, y)
        elif action == glfw.RELEASE:
            self._drag = None

    def _on_cursor(self, win, x, y) -> None:
        if self._drag is None:
            return
        button, x0, y0 = self._drag
        self._drag = (button, x, y)
        self._orbit_or_pan(button, *self._drag_delta(win, x, y, x0, y0))

    def _on_scroll(self, win, xoff, yoff) -> None:
        self.controls.zoom(yoff)
        self._dirty = True

    def key(self, name: str) -> None:
        """Apply one key as if pressed (``'['``, ``']'``, ``'I'``, ``'T'``, ``'H'``, ``'P'``, ``'R'``, ``'ESCAPE'``)."""
        if self.state.handle_key(name):
            self._apply_state()

    def _apply_state(self) -> None:
        st = self.state
        self._apply_view_keys()
        from ..scene.transfer import TransferFunction

        name = st.tf_name
        window = self.session.tf.window(self.session.value_range)
        if name == st.tf_presets[0]:
            tf = self._first_tf.with_value_range(window)
        else:
            tf = TransferFunction.preset(name, value_range=window)
        self.session.update(tolerance=st.tolerance, mode=st.render_mode, tf=tf, shading=st.shading)
        self._hud_text = None
        self._dirty = True

    # -- frame ----------------------------------------------------------------------------------
    def step(self, *, force: bool = False, poll: bool = True) -> bool:
        """One loop iteration: input, a new frame if anything changed, draw, swap. Returns whether it rendered."""
        self._begin_step(poll)
        sess = self.session
        version = sess.clip_texture.residency_version
        view = (tuple(self.controls.eye), tuple(self.controls.target), self.framebuffer_size)
        rendered = False
        if force or self._dirty or version != self._version or view != self._view:
            self._version, self._view = version, view
            self._dirty = False
            cam = self.camera()
            t0 = time.perf_counter()
            img = sess.render(cam, self.controls.center_of_interest, wait=False)
            self._frame = img
            self._frame_tex = self._texture(self._frame_tex, img)
            self._frame_done(time.perf_counter() - t0)
            rendered = True
        self._end_step()
        return rendered

    def hud_lines(self) -> list[str]:
        """The HUD's text for the current state."""
        st = self.state
        return point_hud_lines(fps=self._fps, frame_stats=self.session.frame_stats if self.frames_rendered else None,
                               tolerance=st.tolerance, size=self.framebuffer_size,
                               settings={"render": st.render_mode + (" lit" if st.shading and st.render_mode == "composite" else ""),
                                         "tf": st.tf_name},
                               texture_stats=self.session.clip_texture.stats, message=st.message)

    def _draw_hud(self, w: int, h: int) -> None:
        if self._hud_due():
            lines = self.hud_lines()
            self._hud_text, self._hud_time = lines, time.perf_counter()
            img = render_text(lines)
            self._place_hud(img, w, h)
        self._render_hud()

    def screenshot(self, path=None) -> Path:
        """Save what the window shows (with the HUD) as a PNG; returns its path."""
        from PIL import Image

        path = Path(path) if path is not None else self._numbered("clipvol-points", ".png")
        Image.fromarray(self.read_screen(), "RGB").save(path)
        self.last_screenshot = path
        return self._note_saved(path)

    def close(self) -> None:
        """Stop the loader threads, release GL objects, destroy the window."""
        try:
            if self.session is not None:
                self.session.close()
                self.session = None
        finally:
            self._close_window()
