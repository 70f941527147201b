"""What every clipvol window shares: a GLFW window with a GL 3.3 core context, a quad that shows
an image, and the read-back, numbering and closing around them.

The volume viewer (:mod:`clipvol.viewer.window`) and the point viewer
(:mod:`clipvol.viewer.point_window`) differ in their session, keys and HUD, not in how a window is
opened, drawn into or closed; this module holds that common part once. Opening unbinds a current
EGL context first (:class:`_EglUnbound`): with Mesa, a GLX ``MakeCurrent`` fails while one is bound.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..errors import ClipvolError, ParameterError
from ..render.context import create_context
from .controls import MOVE_KEYS

__all__ = ["GlWindow", "WindowError"]

_QUAD_VS = """
#version 330
in vec2 in_pos;
in vec2 in_uv;
out vec2 v_uv;
void main() { v_uv = in_uv; gl_Position = vec4(in_pos, 0.0, 1.0); }
"""

_QUAD_FS = """
#version 330
uniform sampler2D u_tex;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = texture(u_tex, v_uv); }
"""



class WindowError(ClipvolError, RuntimeError):
    """No window could be opened (no display, GLFW missing, no GL 3.3 context)."""


class _EglUnbound:
    """Unbind the thread's current EGL context while the window's GLX context is in use.

    With Mesa, a GLX ``MakeCurrent`` fails with ``BadAccess`` (and Xlib exits the process) while
    an EGL context - such as a standalone offscreen context made earlier in the same process - is
    current on the thread. The window therefore unbinds it first and makes it current again when
    it closes, so offscreen rendering with that context goes on working afterwards.
    """

    _EGL_DRAW, _EGL_READ = 0x3059, 0x305A

    def __init__(self) -> None:
        self._egl = None
        self._saved = None
        try:
            import ctypes
            import ctypes.util

            name = ctypes.util.find_library("EGL") or "libEGL.so.1"
            egl = ctypes.CDLL(name)
        except OSError:
            return
        try:
            vp = ctypes.c_void_p
            egl.eglGetCurrentContext.restype = vp
            egl.eglGetCurrentDisplay.restype = vp
            egl.eglGetCurrentSurface.restype = vp
            egl.eglGetCurrentSurface.argtypes = [ctypes.c_int32]
            egl.eglMakeCurrent.argtypes = [vp, vp, vp, vp]
            egl.eglMakeCurrent.restype = ctypes.c_uint32
            cur = egl.eglGetCurrentContext()
            if cur:
                dpy = egl.eglGetCurrentDisplay()
                saved = (dpy, egl.eglGetCurrentSurface(self._EGL_DRAW), egl.eglGetCurrentSurface(self._EGL_READ), cur)
                if egl.eglMakeCurrent(dpy, None, None, None):
                    self._egl, self._saved = egl, saved
        except AttributeError:  # pragma: no cover - an EGL without these entry points
            return

    def restore(self) -> None:
        if self._egl is not None and self._saved is not None:
            self._egl.eglMakeCurrent(*self._saved)
            self._saved = None


def _quad(ctx, x0: float, y0: float, x1: float, y1: float):
    """A textured quad in NDC; texture row 0 (image top) at ``y1``."""
    data = np.array([
        x0, y0, 0.0, 1.0, x1, y0, 1.0, 1.0, x0, y1, 0.0, 0.0,
        x1, y1, 1.0, 0.0,
    ], dtype=np.float32)
    return ctx.buffer(data.tobytes())


class GlWindow:
    """The window part of a viewer. A subclass calls :meth:`_open` from its ``__init__`` (with a
    function making its session from the GL context), has ``controls`` (an
    :class:`~clipvol.viewer.controls.OrbitControls`), ``screenshot_dir`` and ``_dirty``, and defines
    ``close()`` (which ends with :meth:`_close_window`)."""

    session = None
    window = None
    _glfw_up = False
    _egl = None

    def _init_view_state(self, screenshot_dir, background) -> None:
        """The input, frame and HUD state every viewer starts with (before :meth:`_install_callbacks`)."""
        self.screenshot_dir = Path(screenshot_dir)
        self.background = tuple(float(v) for v in background)
        self.held: set[str] = set()  # movement keys held down
        self._drag = None  # (button, x, y, ...) while a mouse button is held
        self._dirty = True
        self._frame = None
        self._hud_tex = None
        self._hud_text = None
        self._hud_time = 0.0
        self._fps = 0.0
        self._t_last = time.perf_counter()
        self.frames_rendered = 0
        self._version = None
        self._view = None
        self.last_screenshot: Path | None = None

    def _open(self, size, *, visible: bool, title: str, no_display: str, make_session) -> None:
        """Open the window and its context, then ``self.session = make_session(ctx)``; on any
        failure close what was opened (``self.close()``) and raise. ``no_display`` ends the error
        shown without a display (what to use instead)."""
        try:
            import glfw
        except ImportError as e:  # pragma: no cover - glfw is a dependency
            raise WindowError(f"clipvol view needs the glfw package (pip install glfw), got ImportError: {e}") from e
        w, h = (int(v) for v in size)
        if w < 1 or h < 1:
            raise ParameterError(f"size: expected a window size >= 1x1, got {size!r}")
        self._glfw = glfw
        self._glfw_up = False
        self.session = None
        self.window = None
        self._egl = _EglUnbound()
        reporting = getattr(glfw, "ERROR_REPORTING", None)
        glfw.ERROR_REPORTING = "raise"  # turn GLFW's warnings into one clear error below
        try:
            ok = glfw.init()
        except glfw.GLFWError as e:
            ok, why = False, str(e)
        else:
            why = "glfw.init() returned False"
        finally:
            glfw.ERROR_REPORTING = reporting if reporting is not None else "warn"
        if not ok:
            self._egl.restore()
            raise WindowError(f"expected a display for the viewer window, got: {why} ({no_display})")
        self._glfw_up = True
        try:
            glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 3)
            glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 3)
            glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
            glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
            glfw.window_hint(glfw.VISIBLE, bool(visible))
            glfw.window_hint(glfw.DOUBLEBUFFER, True)
            self.window = glfw.create_window(w, h, title, None, None)
            if not self.window:
                raise WindowError("expected a window with an OpenGL 3.3 core context, but glfw.create_window failed")
            glfw.make_context_current(self.window)
            glfw.swap_interval(1 if visible else 0)
            self.ctx = create_context(standalone=False, backend=None)
            self.session = make_session(self.ctx)
            self._setup_gl()
        except BaseException:
            self.close()
            raise

    # -- GL objects -------------------------------------------------------------------------------
    def _setup_gl(self) -> None:
        import moderngl

        ctx = self.ctx
        self._prog = ctx.program(vertex_shader=_QUAD_VS, fragment_shader=_QUAD_FS)
        self._prog["u_tex"].value = 0
        self._full_vbo = _quad(ctx, -1.0, -1.0, 1.0, 1.0)
        self._full_vao = ctx.vertex_array(self._prog, [(self._full_vbo, "2f 2f", "in_pos", "in_uv")])
        self._hud_vbo = None
        self._hud_vao = None
        self._frame_tex = None
        self._mgl = moderngl

    def _texture(self, old, img: np.ndarray, smooth: bool = False):
        """``img`` (``(h, w, 4)`` uint8) in ``old`` (re-made when the size changed)."""
        h, w = img.shape[:2]
        if old is None or old.size != (w, h):
            if old is not None:
                old.release()
            old = self.ctx.texture((w, h), 4)
            old.repeat_x = old.repeat_y = False
        f = self._mgl.LINEAR if smooth else self._mgl.NEAREST
        old.filter = (f, f)
        old.write(np.ascontiguousarray(img, dtype=np.uint8).tobytes())
        return old

    def _install_callbacks(self) -> None:
        glfw = self._glfw
        win = self.window
        glfw.set_key_callback(win, self._on_key)
        glfw.set_char_callback(win, self._on_char)
        glfw.set_mouse_button_callback(win, self._on_button)
        glfw.set_cursor_pos_callback(win, self._on_cursor)
        glfw.set_scroll_callback(win, self._on_scroll)
        glfw.set_framebuffer_size_callback(win, lambda *_: self._mark())

    def _mark(self) -> None:
        self._dirty = True

    # -- input shared by the viewers ----------------------------------------------------------------
    def _hold(self, name: str, action) -> bool:
        """A movement key (``MOVE_KEYS``) held or let go: True when ``name`` is one (it was handled)."""
        if name not in MOVE_KEYS:
            return False
        if action == self._glfw.PRESS:
            self.held.add(name)
        elif action == self._glfw.RELEASE:
            self.held.discard(name)
        return True

    def _drag_delta(self, win, x, y, x0, y0) -> tuple[float, float]:
        """A cursor move from ``(x0, y0)`` to ``(x, y)`` (screen coordinates) in framebuffer pixels."""
        sx = self.framebuffer_size[0] / max(self._glfw.get_window_size(win)[0], 1)
        return (x - x0) * sx, (y - y0) * sx

    def _orbit_or_pan(self, button, dx: float, dy: float) -> None:
        """The left button orbits the camera, the others pan it."""
        if button == self._glfw.MOUSE_BUTTON_LEFT:
            self.controls.orbit(dx, dy)
        else:
            self.controls.pan(dx, dy, self.framebuffer_size)
        self._dirty = True

    # -- one loop iteration (a viewer's ``step``: begin, maybe a new frame, end) --------------------
    def _apply_view_keys(self) -> None:
        """The state's reset (view back to the start) and quit (close the window) requests."""
        st = self.state
        if st.reset:
            self.controls.reset()
            st.reset = False
        if st.quit:
            self._glfw.set_window_should_close(self.window, True)

    def _begin_step(self, poll: bool) -> float:
        """Take input (``poll``), move the camera by the keys held since the last step; returns now."""
        if poll:
            self._glfw.poll_events()
        now = time.perf_counter()
        dt, self._t_last = now - self._t_last, now
        if self.held and self.controls.move_keys(self.held, min(dt, 0.1), speed=0.5 * self.controls.distance):
            self._dirty = True
        return now

    def _frame_done(self, seconds: float) -> None:
        """Count a new frame that took ``seconds`` into the smoothed frame rate the HUD shows."""
        rate = 1.0 / max(seconds, 1e-4)
        self._fps = 0.8 * self._fps + 0.2 * rate if self._fps else rate
        self.frames_rendered += 1

    def _end_step(self) -> None:
        """Draw the last frame and HUD, take an asked-for screenshot, swap."""
        self._draw()
        if self.state.screenshot:
            self.state.screenshot = False
            self.screenshot()
        self._glfw.swap_buffers(self.window)

    # -- drawing ----------------------------------------------------------------------------------
    def _draw(self) -> None:
        """The last frame over the background, then the HUD (``self._draw_hud``) when it is on."""
        ctx = self.ctx
        mgl = self._mgl
        w, h = self.framebuffer_size
        ctx.screen.use()
        ctx.viewport = (0, 0, w, h)
        ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)
        r, g, b = self.background
        ctx.clear(r, g, b, 1.0)
        ctx.enable(mgl.BLEND)
        ctx.blend_equation = mgl.FUNC_ADD
        ctx.blend_func = mgl.SRC_ALPHA, mgl.ONE_MINUS_SRC_ALPHA
        if self._frame_tex is not None:
            self._frame_tex.use(location=0)
            self._full_vao.render(mgl.TRIANGLE_STRIP)
        if self.state.hud:
            self._draw_hud(w, h)
        ctx.disable(mgl.BLEND)

    def _place_hud(self, img: np.ndarray, w: int, h: int) -> None:
        """Show ``img`` (the HUD, RGBA) at the window's top left, pixel for pixel, from now on."""
        self._hud_tex = self._texture(self._hud_tex, img)
        ih, iw = img.shape[:2]
        x1 = -1.0 + 2.0 * min(iw, w) / w
        y0 = 1.0 - 2.0 * min(ih, h) / h
        if self._hud_vbo is not None:
            self._hud_vao.release()
            self._hud_vbo.release()
        self._hud_vbo = _quad(self.ctx, -1.0, y0, x1, 1.0)
        self._hud_vao = self.ctx.vertex_array(self._prog, [(self._hud_vbo, "2f 2f", "in_pos", "in_uv")])

    def _hud_due(self) -> bool:
        """Whether the HUD's text is to be made again (it changed, or a quarter second passed)."""
        return self._hud_text is None or time.perf_counter() - self._hud_time > 0.25

    def _render_hud(self) -> None:
        self._hud_tex.use(location=0)
        self._hud_vao.render(self._mgl.TRIANGLE_STRIP)

    # -- the view ---------------------------------------------------------------------------------
    @property
    def framebuffer_size(self) -> tuple[int, int]:
        w, h = self._glfw.get_framebuffer_size(self.window)
        return max(int(w), 1), max(int(h), 1)

    def camera(self):
        """The camera of the current view at the framebuffer's size."""
        return self.controls.camera(self.framebuffer_size)

    def should_close(self) -> bool:
        return bool(self._glfw.window_should_close(self.window))

    def read_screen(self) -> np.ndarray:
        """What the window shows, as ``(h, w, 3)`` uint8, row 0 at top.

        The last frame (and HUD) is drawn again into the back buffer and read from there: after a
        buffer swap the back buffer's content is undefined.
        """
        w, h = self.framebuffer_size
        self._draw()
        self.ctx.finish()
        data = self.ctx.screen.read(viewport=(0, 0, w, h), components=3, alignment=1)
        # moderngl selects GL_COLOR_ATTACHMENT0 as read buffer, which the default framebuffer does
        # not have: GL flags INVALID_OPERATION but reads the back buffer. Consume that flag so the
        # render action's own error check is not blamed for it.
        _ = self.ctx.error
        return np.frombuffer(data, dtype=np.uint8).reshape(h, w, 3)[::-1].copy()

    def run(self, max_frames: int | None = None) -> int:
        """The event loop (``self.step()``) until the window closes (Esc) or ``max_frames`` loop
        iterations; returns 0."""
        glfw = self._glfw
        n = 0
        while not self.should_close():
            t0 = time.perf_counter()
            self.step()
            n += 1
            if max_frames is not None and n >= max_frames:
                break
            fs = self.session.frame_stats
            refining = fs is not None and not fs.converged
            busy = self._dirty or bool(self.held) or self._drag is not None
            # pace: ~30 fps while refining (loader threads need the interpreter too), idle otherwise
            budget = 1.0 / 30.0 if (refining or busy) else 0.05
            left = budget - (time.perf_counter() - t0)
            if left > 0:
                glfw.wait_events_timeout(left)
        return 0

    def _numbered(self, stem: str, suffix: str) -> Path:
        """The first free ``screenshot_dir/stem-NNNN.suffix``."""
        self.screenshot_dir.mkdir(parents=True, exist_ok=True)
        k = 0
        while (self.screenshot_dir / f"{stem}-{k:04d}{suffix}").exists():
            k += 1
        return self.screenshot_dir / f"{stem}-{k:04d}{suffix}"

    def _note_saved(self, path: Path) -> Path:
        """After saving ``path`` (a screenshot, a table, a camera): say so in the HUD; returns it."""
        self.state.message = f"saved {path}"
        self._hud_text = None
        return path

    def _close_window(self) -> None:
        """Destroy the window, end GLFW, make the EGL context current again (the end of ``close``)."""
        glfw = self._glfw
        if self.window is not None:
            glfw.destroy_window(self.window)
            self.window = None
        if self._glfw_up:
            glfw.terminate()
            self._glfw_up = False
        if self._egl is not None:
            self._egl.restore()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
