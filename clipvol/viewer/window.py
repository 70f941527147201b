"""The interactive window of ``clipvol view``: GLFW + moderngl around a :class:`RenderSession`.

Why GLFW: it is small and mature, has wheels for every platform, and hands moderngl a GL core-profile
context with no toolkit baggage (Qt or wx would bring an event loop and hundreds of MB); the
offscreen paths never import it.

Each loop iteration polls input (:mod:`clipvol.viewer.controls` maps it to a camera and settings),
and, when something changed - the camera, a setting, the window size, or the clip-texture's
``residency_version`` (a brick arrived) - or the last frame had not converged, renders a frame
*without waiting* for I/O (``wait=False``): what is resident is drawn, coarser levels stand in for
what is still loading, and the image refines frame by frame as bricks arrive. The frame (an RGBA
array from the render action) goes into a texture drawn as a full-window quad, the brick outlines
(B) are drawn onto it first, and the HUD (H; text rasterised with pillow) is blended over it. While
the image is still refining the loop is paced to ~30 frames per second, so the loader threads get
their share of the interpreter.

**Interactive on a CPU.** While the camera moves (a drag, the wheel, WASD/QE) frames are drawn at
a reduced image size and a longer sample step chosen by :class:`clipvol.app.adaptive.AdaptiveQuality`
to hold a target frame time (default 1/15 s), from one whole coarse level (a cut the frame loop
draws again while the view turns), and scaled up on screen; once the camera has been
still for 0.2 s one full-quality frame is drawn and refined as bricks arrive. The HUD says which.

**Transfer function.** The HUD shows the data's histogram with the opacity curve and the window
over it. Left/Right (or a left drag on the histogram) move the window, Up/Down (or a right drag)
widen/narrow it, T cycles colour maps over the same
window, Shift+S (or Ctrl+S) saves it as JSON (``--tf FILE.json`` reads it back), C saves the camera
(``--camera FILE.json``), P saves a screenshot with the HUD and Shift+P one without, all into the
screenshot folder.

The window can be driven programmatically (``Viewer.step()``, ``Viewer.read_screen()``), which
is how ``tests/test_view_window.py`` checks it under Xvfb.

Why one module of this size: it is the one place GLFW events meet the session; what a key does is
:mod:`.controls`, the cut keys :mod:`.cut_keys`, the HUD :mod:`.hud`.
"""

from __future__ import annotations

import time
from pathlib import Path


from ..app.adaptive import DRAG_FRAME_S, FULL, AdaptiveQuality, frame_params
from ..app.session import RenderSession
from ..errors import ClipvolError, ParameterError
from ..render.modes import DRAW_MODES
from ..render.paths.setup import max_step
from ..scene.params import RenderParams
from .controls import OrbitControls, ViewState
from .gl_window import GlWindow, WindowError
from .hud import hud_lines, render_text

__all__ = ["Viewer", "WindowError"]

def _anatomical_rig(loader) -> dict:
    """For a patient-frame store: orbit head-up, first seen from the front (else the default rig)."""
    frame = getattr(loader, "frame", None)
    if frame is None or frame.frame != "RAS":
        return {}
    from clipvol.scene.orientation import anatomical_axes

    up, front = anatomical_axes(frame.affine)
    return {"up": up, "front": front, "azimuth": 0.0, "elevation": 0.0}


class Viewer(GlWindow):
    """A GLFW window showing ``source`` with the multiresolution clip renderer.

    Parameters
    ----------
    source : loader, path or URL
        The data (see :func:`clipvol.paging.open.open_store`).
    size : (int, int)
        Window size in screen coordinates.
    memory_budget, texture_budget : int or str
        Clip-texture and GPU cache budgets.
    threads : int, optional
        Loader threads.
    params : RenderParams, optional
        Initial render parameters (policy, LOD threshold, mode, step).
    tf : str or TransferFunction
        Initial transfer function.
    screenshot_dir : str or Path
        Where P writes ``clipvol-NNNN.png`` (Shift+P: ``clipvol-NNNN-nohud.png``), Shift+S
        ``tf-NNNN.json`` and C ``camera-NNNN.json`` (created when first needed).
    frame_time : float
        Target frame time in seconds while the camera moves (default 1/15: 15 fps; 0 or None:
        always full quality).
    camera : Camera, optional
        The first view (e.g. from :func:`clipvol.scene.bookmarks.load_camera`).
    visible : bool
        Show the window (tests may render into a hidden one).
    title : str
        Window title.
    background : (r, g, b)
        Colour behind the volume, 0..1.
    series : sequence of Loader, optional
        A time series (one loader per step, ``source`` is then only its name): the viewer plays,
        pauses and steps it (Space, J / K, { / }; :mod:`clipvol.viewer.playback`), the next step
        prefetched under the same memory budget (:class:`clipvol.app.timeseries.SeriesSession`).
    rate : float
        Playing rate of a series, steps per second (a ceiling).
    """

    def __init__(self, source, *, size=(960, 640), memory_budget="256MB", texture_budget="256MB", threads=None,
                 params: RenderParams | None = None, tf="viridis", screenshot_dir=".", visible: bool = True,
                 title: str = "clipvol", background=(0.0, 0.0, 0.0), frame_time: float | None = DRAG_FRAME_S,
                 camera=None, series=None, rate: float = 4.0) -> None:
        params = params if params is not None else RenderParams(jitter=True)

        def make_session(ctx):
            if series is not None:  # a time series: play / pause / step (viewer/playback.py)
                from ..app.timeseries import SeriesSession

                return SeriesSession(series, ctx, memory_budget=memory_budget, texture_budget=texture_budget,
                                     threads=threads, tf=tf, params=params)
            return RenderSession(source, ctx, memory_budget=memory_budget, texture_budget=texture_budget,
                                 threads=threads, tf=tf, params=params)

        self._open(size, visible=visible, title=title, no_display="set DISPLAY, or use --offscreen",
                   make_session=make_session)
        pyr = self.session.pyramid
        s, tf0 = self.session.params, self.session.tf
        from ..scene.transfer import TransferFunction

        presets = tuple(n for n in TransferFunction.names())
        # the starting transfer function (a preset name or an object, e.g. the automatic one)
        # heads the cycle under its own label; T cycles colour maps over the current window
        self._first_tf = self.session.transfer_function
        first = self._first_tf.name or "custom"
        if isinstance(tf0, str) and tf0 in presets:
            first = tf0
        self._first_label = first
        presets = (first,) + tuple(n for n in presets if n != first)
        self.tf = self._first_tf
        self.state = ViewState(
            num_levels=pyr.num_levels, tf_presets=presets, mode=s.policy, level=s.level or 0,
            lod_threshold=s.lod_threshold, render_mode=s.mode, shading=s.shading, tf_index=0,
            # I: every registered mode whose fields are set (the iso-surface when clipvol view --iso-value)
            render_modes=tuple(name for name, m in DRAW_MODES.items()
                               if all(getattr(s, f) is not None for f in m.requires)),
        )
        self.controls = OrbitControls.for_pyramid(pyr, size=self.framebuffer_size, **_anatomical_rig(self.session.loader))
        if camera is not None:
            self.controls.set_camera(camera)
        self.adaptive = AdaptiveQuality(float(frame_time)) if frame_time else None
        self._base_step = float(s.step)
        self._max_error = getattr(s, "max_error", None)  # --max-error: the image policy's error budget
        self._quality = FULL
        self._hist = None
        self._strip_rect = None
        self._init_view_state(screenshot_dir, background)  # _drag: (button, x, y, distance moved)
        self._frame_camera = None
        self.slices = None  # slice mode (key L): clipvol.viewer.slice_layout, built on first use
        self.playback = None  # a time series' play / pause / step (viewer/playback.py)
        if series is not None:
            from .playback import Playback

            self.playback = Playback(len(self.session.player), rate=rate)
        from .cut_keys import CutKeys

        self.cut = CutKeys(self.session)  # crop box / clip planes (F X Z V O), probe under the cursor, ruler (U)
        self._hover = None  # the cursor (framebuffer pixels) to probe at, once the view is still
        self._install_callbacks()

    # -- input --------------------------------------------------------------------------------
    def _on_key(self, win, key, scancode, action, mods) -> None:
        glfw = self._glfw
        if glfw.KEY_A <= key <= glfw.KEY_Z:
            name = chr(ord("A") + key - glfw.KEY_A)
        else:  # the other keys the viewer knows by name (printable ones arrive through _on_char)
            name = {glfw.KEY_ESCAPE: "ESCAPE", glfw.KEY_KP_ADD: "+", glfw.KEY_KP_SUBTRACT: "-",
                    glfw.KEY_LEFT: "LEFT", glfw.KEY_RIGHT: "RIGHT", glfw.KEY_UP: "UP", glfw.KEY_DOWN: "DOWN",
                    glfw.KEY_SPACE: "SPACE"}.get(key)
        if name is None:
            return
        if action in (glfw.PRESS, glfw.REPEAT) and name in ("LEFT", "RIGHT", "UP", "DOWN"):
            self.key(name)
            return
        if action == glfw.PRESS and (mods & (glfw.MOD_SHIFT | glfw.MOD_CONTROL)) and name in ("S", "P"):
            self.key("shift+" + name)
            return
        if self._hold(name, action):
            return
        if action == glfw.PRESS:
            self.key(name)

    def _show_step(self, step: int) -> None:
        """Show time step ``step`` of the series (the prefetched one when it is the next)."""
        if self.session.step != step:
            self.session.go_to(step)
            self._dirty = True
            self._hud_text = None

    def toggle_slices(self) -> None:
        """Slice mode on / off: three orthogonal slices beside the 3D view (:mod:`.slice_layout`)."""
        if self.slices is None:
            from .slice_layout import SliceLayout

            self.slices = SliceLayout(self.session)
        self.slices.active = not self.slices.active
        self._hud_text = None
        self._dirty = True

    def _on_char(self, win, codepoint) -> None:
        ch = chr(codepoint)
        if ch in "+-=_[]<>,.{}":
            self.key(ch)

    def _on_button(self, win, button, action, mods) -> None:
        glfw = self._glfw
        if action == glfw.PRESS:
            x, y = glfw.get_cursor_pos(win)
            self._drag = (button, x, y, 0.0)  # (button, x, y, distance moved so far)
            r = self._strip_rect if self.state.hud else None
            sx = self.framebuffer_size[0] / max(glfw.get_window_size(win)[0], 1)
            if r is not None and r[0] <= x * sx < r[2] and r[1] <= y * sx < r[3]:
                self._drag = (("strip", button), x, y, 0.0)  # a drag on the histogram edits the window
        elif action == glfw.RELEASE:
            if self.slices is not None and self.slices.active and self._drag is not None and self._drag[3] < 3 \
                    and not isinstance(self._drag[0], tuple):
                self.slices.click(*self._slice_panel(win))  # a click, not a drag: set the point of interest
                self._dirty = True
            self._drag = None

    def _on_cursor(self, win, x, y) -> None:
        if self._drag is None:
            sx = self.framebuffer_size[0] / max(self._glfw.get_window_size(win)[0], 1)
            self._hover = (x * sx, y * sx)  # probed in step() when the view is still
            return
        button, x0, y0, moved = self._drag
        self._drag = (button, x, y, moved + abs(x - x0) + abs(y - y0))
        dx, dy = self._drag_delta(win, x, y, x0, y0)
        if isinstance(button, tuple):
            self.drag_window(dx, widen=button[1] != self._glfw.MOUSE_BUTTON_LEFT)
            return
        if self.slices is not None and self.slices.active and self._slice_panel(win)[0] != "3d":
            self.slices.tilt(self._slice_panel(win)[0], dx, dy)
            self._dirty = True
        else:
            from clipvol.scene.views import mirrored

            # the image of a mirrored store is flipped (clipvol.scene.views): so is the drag
            self._orbit_or_pan(button, -dx if mirrored(self._frame_of_store()) else dx, dy)

    def _on_scroll(self, win, xoff, yoff) -> None:
        if self.slices is not None and self.slices.active and self._slice_panel(win)[0] != "3d":
            self.slices.step_plane(self._slice_panel(win)[0], yoff)
        else:
            self.controls.zoom(yoff)
        self._dirty = True

    def _slice_panel(self, win) -> tuple[str, float, float]:
        """The slice-mode panel under the cursor and the cursor in its framebuffer pixels."""
        x, y = self._glfw.get_cursor_pos(win)
        sx = self.framebuffer_size[0] / max(self._glfw.get_window_size(win)[0], 1)
        return self.slices.panel_at(x * sx, y * sx, self.framebuffer_size)

    def key(self, name: str) -> None:
        """Apply one key as if pressed (``'M'``, ``'+'``, ``'P'``, ``'shift+P'``, ``'shift+S'``,
        ``'C'``, ``'L'`` for slice mode, ``'LEFT'``/``'RIGHT'``/``'UP'``/``'DOWN'``, ...)."""
        if name == "L":
            self.toggle_slices()
        elif name in ("LEFT", "RIGHT", "UP", "DOWN"):
            self.nudge_window(name)
        elif name == "shift+S":
            self.save_transfer_function()
        elif name == "shift+P":
            self.screenshot(hud=False)
        elif name.upper() == "C" and len(name) == 1:
            self.save_camera()
        elif len(name) == 1 and name.upper() in self.cut.KEYS and \
                self.cut.handle_key(name, self.controls.center_of_interest, self.controls.forward):
            self.apply_cut()
        elif self.playback is not None and self.playback.handle_key(name):
            self.state.message = self.playback.message
            self._show_step(self.playback.step)
        elif self.state.handle_key(name):
            self._apply_state()

    # -- cut, probe -----------------------------------------------------------------------------
    def apply_cut(self) -> None:
        """Draw the cut the keys set (:class:`clipvol.viewer.cut_keys.CutKeys`) from the next frame on."""
        self.state.message = self.cut.message
        shape = self.cut.shape()
        if shape != self.session.params.shape:
            self.session.update(shape=shape)
        self._hud_text = None
        self._dirty = True

    def probe_at(self, x: float, y: float):
        """Probe the first visible sample under framebuffer pixel ``(x, y)`` of the last frame (HUD
        line); returns the :class:`~clipvol.scene.probe.Probe` or None."""
        cam = self._frame_camera
        if cam is None or (self.slices is not None and self.slices.active):
            return None
        fw, fh = self.framebuffer_size
        cx, cy = x * cam.size[0] / fw, y * cam.size[1] / fh
        from clipvol.scene.views import mirrored

        if mirrored(self._frame_of_store()):  # the frame shown is flipped left-right
            cx = cam.size[0] - cx
        if not (0 <= cx <= cam.size[0] and 0 <= cy <= cam.size[1]):
            return None
        st = self.state
        p = self.cut.probe_pixel(cam, cx, cy, self.tf, step=self._base_step,
                                 max_level=None if st.mode != "fixed" else st.level)
        self._hud_text = None
        return p

    # -- transfer function, bookmarks ---------------------------------------------------------
    def _set_tf(self, tf, message: str | None = None) -> None:
        self.tf = tf
        self.session.update(tf=tf)
        if self.adaptive is not None:
            self.adaptive.invalidate()
        if message:
            self.state.message = message
        self._hud_text = None
        self._dirty = True

    def nudge_window(self, direction: str) -> tuple[float, float]:
        """Move (LEFT/RIGHT: 5 % of the data range) or widen/narrow (UP/DOWN: x1.25) the window."""
        lo, hi = self.tf.window(self.session.pyramid.value_range)
        dlo, dhi = self.session.pyramid.value_range
        span = (dhi - dlo) or 1.0
        c, w = (lo + hi) / 2.0, hi - lo
        if direction == "LEFT":
            c -= 0.05 * span
        elif direction == "RIGHT":
            c += 0.05 * span
        elif direction == "UP":
            w = w * 1.25 if w > 0 else 0.05 * span
        elif direction == "DOWN":
            w = w / 1.25
        else:
            raise ParameterError(f"direction: expected LEFT, RIGHT, UP or DOWN, got {direction!r}")
        win = (c - w / 2.0, c + w / 2.0)
        self._set_tf(self.tf.with_value_range(win), f"window {win[0]:.4g} .. {win[1]:.4g}")
        return win

    def drag_window(self, dx: float, widen: bool = False) -> tuple[float, float]:
        """A horizontal drag of ``dx`` pixels on the HUD's histogram: move the window with the
        cursor (left button), or widen it (right button: x2 per 100 pixels to the right)."""
        lo, hi = self.tf.window(self.session.pyramid.value_range)
        h = self._histogram()
        e0, e1 = (float(h.edges[0]), float(h.edges[-1])) if h is not None else self.session.pyramid.value_range
        r = self._strip_rect
        px = max((r[2] - r[0]) - 12, 1) if r is not None else 288  # the strip's plot width (padding 6)
        if widen:
            c, w = (lo + hi) / 2.0, (hi - lo) * 2.0 ** (float(dx) / 100.0)
            win = (c - w / 2.0, c + w / 2.0)
        else:
            d = float(dx) / px * ((e1 - e0) or 1.0)
            win = (lo + d, hi + d)
        self._set_tf(self.tf.with_value_range(win), f"window {win[0]:.4g} .. {win[1]:.4g}")
        return win

    def save_transfer_function(self, path=None) -> Path:
        """Save the current transfer function as JSON (Shift+S); returns its path."""
        return self._note_saved(self.tf.save(path if path is not None else self._numbered("tf", ".json")))

    def save_camera(self, path=None) -> Path:
        """Save the current camera as JSON (C); returns its path."""
        from ..scene.bookmarks import save_camera

        return self._note_saved(save_camera(self.camera(), path if path is not None else self._numbered("camera", ".json")))

    def _histogram(self):
        if self._hist is None:
            from ..scene.auto_tf import value_histogram

            try:
                self._hist = value_histogram(self.session.loader)
            except ClipvolError:  # a brick that cannot be read: no strip, the viewer goes on
                self._hist = False
        return self._hist or None

    def _apply_state(self) -> None:
        st = self.state
        self._apply_view_keys()
        name = st.tf_name
        label = self.tf.name or "custom"
        if name == self._first_label:
            tf = self._first_tf.with_value_range(self.tf.window(self.session.pyramid.value_range))
        elif label == name or label.startswith(name + " "):
            tf = self.tf
        else:
            from ..scene.transfer import TransferFunction

            tf = TransferFunction.preset(name, value_range=self.tf.window(self.session.pyramid.value_range))
        self.tf = tf
        if st.render_mode != "composite" and self.session.params.overlays:  # overlays are composited over the primary
            st.render_mode, st.message = "composite", \
                f"{st.render_mode.upper()}: not with overlays (they are composited over the volume)"
        self.session.update(
            lod_threshold=st.lod_threshold, policy=st.mode, level=st.level if st.mode == "fixed" else None,
            mode=st.render_mode, shading=st.shading, tf=tf,
            block_budget=st.block_budget, max_error=self._max_error if st.mode == "image" else None,
        )
        if self.adaptive is not None:
            self.adaptive.invalidate()
        self._hud_text = None
        self._dirty = True

    # -- frame --------------------------------------------------------------------------------
    def step(self, *, force: bool = False, poll: bool = True) -> bool:
        """One loop iteration: input, a new frame if anything changed, draw, swap. Returns whether it rendered."""
        now = self._begin_step(poll)
        if self.playback is not None:  # a time series playing: the next step once this one is drawn
            fs = self.session.frame_stats
            if self.playback.due(now, ready=fs is not None and fs.converged):
                self._show_step(self.playback.advance(now))
        sess = self.session
        fs = sess.frame_stats
        # not converged and the last frame still uploaded something: the next frame shows more.
        # (Bricks that arrive in RAM bump residency_version; a failed brick ends the refinement.)
        refining = fs is None or (not fs.converged and fs.bytes_uploaded > 0)
        version = sess.clip_texture.residency_version
        rendered = False
        view = (tuple(self.controls.eye), tuple(self.controls.target), self.framebuffer_size)
        moving = (self._view is not None and view != self._view) or self._drag is not None or bool(self.held)
        q, want = FULL, False
        if self.adaptive is not None and not force:  # a forced frame is a full-quality frame
            q = self.adaptive.next(moving, now)
            # None: the full frame is drawn and only bricks arrive: refine at full quality
            want = q is not None
            q = q or FULL
        if force or want or self._dirty or (refining and q.full) or version != self._version or view != self._view:
            self._version, self._view = version, view
            self._dirty = False
            cam = self.controls.camera(q.size(self.framebuffer_size))
            self._apply_quality(q, cam)
            t0 = time.perf_counter()
            if self.slices is not None and self.slices.active:
                img = self.slices.render(lambda size: self.controls.camera(size), self.framebuffer_size)
            else:
                try:
                    img = sess.render(cam, self.controls.center_of_interest, wait=False)
                except ClipvolError as e:  # e.g. image-based LOD on a store without summary tables
                    if self.state.mode != "image":
                        raise
                    self.state.mode, self.state.message = "projected-size", str(e)
                    self._apply_state()
                    img = sess.render(cam, self.controls.center_of_interest, wait=False)
            if not (self.slices is not None and self.slices.active):
                fs = sess.frame_stats  # a hole where bricks failed and nothing stands in: hatched, never blank
                if fs is not None and fs.unreplaced:
                    from ..render.failures import hatch_failed

                    img = hatch_failed(img, cam, sess.pyramid, fs.unreplaced)
            if self.state.outlines and not (self.slices is not None and self.slices.active):
                from ..app.overlay import draw_outlines

                img = draw_outlines(img, cam, sess.last_items())
            if not (self.slices is not None and self.slices.active):
                from ..app.annotate import present

                img = present(img, cam, self._frame_of_store(), labels=False)  # a mirrored store: un-mirrored
            self._frame = img
            self._frame_camera = cam
            self._frame_tex = self._texture(self._frame_tex, img, smooth=not q.full)
            ft = time.perf_counter() - t0
            if self.adaptive is not None:
                self.adaptive.done(q, ft)
            self._quality = q
            self._frame_done(ft)
            rendered = True
        if self._hover is not None and not moving and self._drag is None:
            self.probe_at(*self._hover)
            self._hover = None
        self._end_step()
        return rendered

    def _apply_quality(self, q, cam) -> None:
        """Set the session's parameters for a frame at quality ``q`` seen by ``cam``
        (:func:`~clipvol.app.adaptive.frame_params`): a moving view's coarser step (never past one
        brick edge, the longest step a frame may use) and one whole level; a full frame's are the
        user's own, so a still image is what it is without adaptive quality."""
        sess, st = self.session, self.state
        previous = sess.params.level if not self._quality.full else None  # the preview's level so far
        want = frame_params(q, sess.pyramid, cam, step=self._base_step, lod_threshold=st.lod_threshold,
                            policy=st.mode, level=st.level if st.mode == "fixed" else None,
                            max_step=max_step(sess.pyramid), previous=previous)
        want["max_error"] = self._max_error if want["policy"] == "image" else None
        changes = {k: v for k, v in want.items() if getattr(sess.params, k) != v}
        if changes:
            sess.update(**changes)

    def _image_lod_settings(self) -> dict:
        """HUD entries of image-based LOD: block budget and its estimated error (else none)."""
        if self.state.mode != "image":
            return {}
        est = getattr(getattr(self.session.action, "last_policy", None), "estimated_error", float("nan"))
        out = {"budget": f"{self.state.block_budget} blocks", "est.err": f"{100 * est:.1f} % px dE>=6"}
        if self._max_error is not None:
            out["max.err"] = f"{100 * self._max_error:g} %"
        return out

    def _frame_of_store(self):
        """The store's :class:`~clipvol.bricking.worldframe.WorldFrame`, or None."""
        return getattr(getattr(self.session, "loader", None), "frame", None)

    def _orientation(self) -> dict[str, str] | None:
        """The view edges' anatomical (or world-axis) labels when the store records its affine."""
        frame = self._frame_of_store()
        if frame is None:
            return None
        from clipvol.scene.orientation import view_labels
        from clipvol.scene.views import screen_axes

        cam = self.camera()
        return view_labels(frame.affine, *screen_axes(cam, frame), frame.frame)

    def _draw_hud(self, w: int, h: int) -> None:
        if self._hud_due():
            st = self.state
            settings = {
                "mode": st.mode + (f" L{st.level}" if st.mode == "fixed" else ""),
                "lod": f"{st.lod_threshold:g}px",
                **self._image_lod_settings(),
                "render": st.render_mode + (" lit" if st.shading and st.render_mode == "composite" else ""),
                "tf": self.tf.name or "custom",
            }
            q = self._quality
            fs = self.session.frame_stats
            if not q.full:
                quality = f"interactive: {100 * q.scale:.0f} % resolution, step x{q.step_factor:.1f}, " \
                          f"level {self.session.params.level}"
            elif fs is not None and not fs.converged:
                quality = "full quality, refining as bricks arrive"
            else:
                quality = "full quality"
            lines = hud_lines(fps=self._fps, frame_stats=fs,
                              texture_stats=self.session.texture_stats, settings=settings, message=st.message,
                              orientation=self._orientation())
            lines.insert(1, quality)
            if self.playback is not None:
                lines.insert(2, self.playback.hud_line(self.session.player.prefetch_state))
            if self.slices is not None and self.slices.active:
                lines = lines + self.slices.hud_lines()
            lines = lines + self.cut.hud_lines()
            self._hud_text = lines
            self._hud_time = time.perf_counter()
            from .hud import stack_images, tf_strip

            text = render_text(lines)
            hist = self._histogram()
            strip = None
            if hist is not None:
                strip = tf_strip(hist.counts, hist.edges, self.tf, self.session.pyramid.value_range,
                                 width=max(240, min(text.shape[1], 360)))
            img = stack_images([text, strip])
            self._strip_rect = None if strip is None else (0, text.shape[0], strip.shape[1], text.shape[0] + strip.shape[0])
            self._place_hud(img, w, h)
        self._render_hud()

    def screenshot(self, path=None, hud: bool = True) -> Path:
        """Save a PNG of the view; returns its path.

        ``hud=True``: what the window shows (redrawn into the back buffer), RGB. ``hud=False``:
        a full-quality frame of the current camera, RGBA with the transparent background kept,
        and no HUD.
        """
        from PIL import Image

        if path is None:
            path = self._numbered("clipvol", ".png")
            if not hud:
                path = path.with_name(path.stem + "-nohud.png")
        path = Path(path)
        if not path.parent.is_dir():
            raise ParameterError(f"{path}: expected an existing folder {str(path.parent)!r} for the screenshot")
        if hud:
            Image.fromarray(self.read_screen(), "RGB").save(path)
        else:
            sess = self.session
            cam = self.camera()
            self._apply_quality(FULL, cam)
            img = sess.render(cam, self.controls.center_of_interest, wait=True, timeout=60.0)
            if self.state.outlines:
                from ..app.overlay import draw_outlines

                img = draw_outlines(img, cam, sess.last_items())
            from ..app.annotate import present

            Image.fromarray(present(img, cam, self._frame_of_store(), labels=False), "RGBA").save(path)
        self.last_screenshot = path
        return self._note_saved(path)

    def close(self) -> None:
        """Stop the loader threads, release GL objects, destroy the window."""
        try:
            if getattr(self, "slices", None) is not None:
                self.slices.close()
                self.slices = None
            if self.session is not None:
                self.session.close()
                self.session = None
        finally:
            self._close_window()
