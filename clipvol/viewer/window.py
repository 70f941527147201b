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

The window can be driven programmatically (``Viewer.step()``, ``Viewer.read_screen()``), which
is how ``tests/test_view_window.py`` checks it under Xvfb.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..app.session import RenderSession
from ..errors import ClipvolError, ParameterError
from ..render.context import create_context
from ..scene.params import RenderParams
from .controls import MOVE_KEYS, OrbitControls, ViewState
from .hud import hud_lines, render_text

__all__ = ["Viewer", "WindowError"]

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


def _anatomical_rig(loader) -> dict:
    """For a patient-frame store: orbit head-up, first seen from the front (else the default rig)."""
    frame = getattr(loader, "frame", None)
    if frame is None or frame.frame != "RAS":
        return {}
    from clipvol.scene.orientation import anatomical_axes

    up, front = anatomical_axes(frame.affine)
    return {"up": up, "front": front, "azimuth": 0.0, "elevation": 0.0}


def _quad(ctx, x0: float, y0: float, x1: float, y1: float):
    """A textured quad in NDC; texture row 0 (image top) at ``y1``."""
    data = np.array([
        x0, y0, 0.0, 1.0, x1, y0, 1.0, 1.0, x0, y1, 0.0, 0.0,
        x1, y1, 1.0, 0.0,
    ], dtype=np.float32)
    return ctx.buffer(data.tobytes())


class Viewer:
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
        Where P writes ``clipvol-NNNN.png``.
    visible : bool
        Show the window (tests may render into a hidden one).
    title : str
        Window title.
    background : (r, g, b)
        Colour behind the volume, 0..1.
    """

    def __init__(self, source, *, size=(960, 640), memory_budget="256MB", texture_budget="256MB", threads=None,
                 params: RenderParams | None = None, tf="viridis", screenshot_dir=".", visible: bool = True,
                 title: str = "clipvol", background=(0.0, 0.0, 0.0)) -> None:
        try:
            import glfw
        except ImportError as e:  # pragma: no cover - glfw is a dependency
            raise WindowError(f"clipvol view needs the glfw package (pip install glfw), got ImportError: {e}") from e
        w, h = (int(v) for v in size)
        if w < 1 or h < 1:
            raise ParameterError(f"size: expected a window size >= 1x1, got {size!r}")
        self._glfw = glfw
        self._glfw_up = False
        self.session: RenderSession | None = None
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
            raise WindowError(f"expected a display for the viewer window, got: {why} (set DISPLAY, or use --offscreen)")
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
            self.session = RenderSession(source, self.ctx, memory_budget=memory_budget, texture_budget=texture_budget,
                                         threads=threads, tf=tf,
                                         params=params if params is not None else RenderParams(jitter=True))
            self._setup_gl()
        except BaseException:
            self.close()
            raise
        pyr = self.session.pyramid
        s, tf = self.session.params, self.session.tf
        presets = ("grey", "viridis", "magma", "inferno", "plasma", "bone")
        # a transfer function given as an object (not a preset name) joins the cycle as "custom"
        self._custom_tf = None if isinstance(tf, str) else tf
        if self._custom_tf is not None:
            presets = ("custom",) + presets
        self.state = ViewState(
            num_levels=pyr.num_levels, tf_presets=presets, mode=s.selection, level=s.level or 0,
            lod_threshold=s.lod_threshold, render_mode=s.mode, shading=s.shading,
            tf_index=presets.index(tf) if isinstance(tf, str) and tf in presets else (0 if self._custom_tf is not None else 1),
        )
        self.controls = OrbitControls.for_pyramid(pyr, size=self.framebuffer_size, **_anatomical_rig(self.session.loader))
        self.screenshot_dir = Path(screenshot_dir)
        self.background = tuple(float(v) for v in background)
        self.held: set[str] = set()
        self._drag: tuple[int, float, float] | None = None
        self._dirty = True
        self._frame = None
        self._frame_camera = None
        self._hud_tex = None
        self._hud_text = None
        self._hud_time = 0.0
        self._fps = 0.0
        self._t_last = time.perf_counter()
        self.frames_rendered = 0
        self._version = None
        self._view = None
        self.last_screenshot: Path | None = None
        self._install_callbacks()

    # -- GL objects ---------------------------------------------------------------------------
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

    def _texture(self, old, img: np.ndarray):
        h, w = img.shape[:2]
        if old is None or old.size != (w, h):
            if old is not None:
                old.release()
            old = self.ctx.texture((w, h), 4)
            old.filter = (self._mgl.NEAREST, self._mgl.NEAREST)
            old.repeat_x = old.repeat_y = False
        old.write(np.ascontiguousarray(img, dtype=np.uint8).tobytes())
        return old

    # -- input --------------------------------------------------------------------------------
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

    def _on_key(self, win, key, scancode, action, mods) -> None:
        glfw = self._glfw
        name = None
        if glfw.KEY_A <= key <= glfw.KEY_Z:
            name = chr(ord("A") + key - glfw.KEY_A)
        elif key == glfw.KEY_ESCAPE:
            name = "ESCAPE"
        elif key == glfw.KEY_KP_ADD:
            name = "+"
        elif key == glfw.KEY_KP_SUBTRACT:
            name = "-"
        if name is None:
            return
        if name in MOVE_KEYS:
            if action == glfw.PRESS:
                self.held.add(name)
            elif action == glfw.RELEASE:
                self.held.discard(name)
            return
        if action == glfw.PRESS:
            self.key(name)

    def _on_char(self, win, codepoint) -> None:
        ch = chr(codepoint)
        if ch in "+-=_[]":
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
        # cursor positions are in screen coordinates; pan in framebuffer pixels
        sx = self.framebuffer_size[0] / max(self._glfw.get_window_size(win)[0], 1)
        dx, dy = (x - x0) * sx, (y - y0) * sx
        if button == self._glfw.MOUSE_BUTTON_LEFT:
            self.controls.orbit(dx, dy)
        else:
            self.controls.pan(dx, dy, self.framebuffer_size)
        self._dirty = True

    def _on_scroll(self, win, xoff, yoff) -> None:
        self.controls.zoom(yoff)
        self._dirty = True

    def key(self, name: str) -> None:
        """Apply one key as if pressed (``'M'``, ``'+'``, ``'P'``, ...)."""
        if self.state.handle_key(name):
            self._apply_state()

    def _apply_state(self) -> None:
        st = self.state
        if st.reset:
            self.controls.reset()
            st.reset = False
        if st.quit:
            self._glfw.set_window_should_close(self.window, True)
        self.session.update(
            lod_threshold=st.lod_threshold, policy=st.mode, level=st.level if st.mode == "fixed" else None,
            mode=st.render_mode, shading=st.shading, tf=self._custom_tf if st.tf_name == "custom" else st.tf_name,
        )
        self._hud_text = None
        self._dirty = True

    # -- frame --------------------------------------------------------------------------------
    @property
    def framebuffer_size(self) -> tuple[int, int]:
        w, h = self._glfw.get_framebuffer_size(self.window)
        return max(int(w), 1), max(int(h), 1)

    def camera(self):
        """The camera of the current view at the framebuffer's size."""
        return self.controls.camera(self.framebuffer_size)

    def should_close(self) -> bool:
        return bool(self._glfw.window_should_close(self.window))

    def step(self, *, force: bool = False, poll: bool = True) -> bool:
        """One loop iteration: input, a new frame if anything changed, draw, swap. Returns whether it rendered."""
        glfw = self._glfw
        if poll:
            glfw.poll_events()
        now = time.perf_counter()
        dt, self._t_last = now - self._t_last, now
        if self.held and self.controls.move_keys(self.held, min(dt, 0.1), speed=0.5 * self.controls.distance):
            self._dirty = True
        sess = self.session
        fs = sess.frame_stats
        # not converged and the last frame still uploaded something: the next frame shows more.
        # (Bricks that arrive in RAM bump residency_version; a failed brick ends the refinement.)
        refining = fs is None or (not fs.converged and fs.bytes_uploaded > 0)
        version = sess.clip_texture.residency_version
        rendered = False
        view = (tuple(self.controls.eye), tuple(self.controls.target), self.framebuffer_size)
        if force or self._dirty or refining or version != self._version or view != self._view:
            self._version, self._view = version, view
            self._dirty = False
            cam = self.camera()
            t0 = time.perf_counter()
            img = sess.render(cam, self.controls.center_of_interest, wait=False)
            if self.state.outlines:
                from ..app.overlay import draw_outlines

                img = draw_outlines(img, cam, sess.last_items())
            self._frame = img
            self._frame_camera = cam
            self._frame_tex = self._texture(self._frame_tex, img)
            ft = time.perf_counter() - t0
            self._fps = 0.8 * self._fps + 0.2 / max(ft, 1e-4) if self._fps else 1.0 / max(ft, 1e-4)
            self.frames_rendered += 1
            rendered = True
        self._draw()
        if self.state.screenshot:
            self.state.screenshot = False
            self.screenshot()
        glfw.swap_buffers(self.window)
        return rendered

    def _draw(self) -> None:
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

    def _orientation(self) -> dict[str, str] | None:
        """The view edges' anatomical (or world-axis) labels when the store records its affine."""
        frame = getattr(getattr(self.session, "loader", None), "frame", None)
        if frame is None:
            return None
        from clipvol.scene.orientation import view_labels

        cam = self.camera()
        return view_labels(frame.affine, cam.right, cam.up, frame.frame)

    def _draw_hud(self, w: int, h: int) -> None:
        now = time.perf_counter()
        if self._hud_text is None or now - self._hud_time > 0.25:
            st = self.state
            settings = {
                "mode": st.mode + (f" L{st.level}" if st.mode == "fixed" else ""),
                "lod": f"{st.lod_threshold:g}px",
                "render": st.render_mode + (" lit" if st.shading and st.render_mode == "composite" else ""),
                "tf": st.tf_name,
            }
            lines = hud_lines(fps=self._fps, frame_stats=self.session.frame_stats,
                              texture_stats=self.session.texture_stats, settings=settings, message=st.message,
                              orientation=self._orientation())
            self._hud_text = lines
            self._hud_time = now
            img = render_text(lines)
            self._hud_tex = self._texture(self._hud_tex, img)
            ih, iw = img.shape[:2]
            x1 = -1.0 + 2.0 * min(iw, w) / w
            y0 = 1.0 - 2.0 * min(ih, h) / h
            if self._hud_vbo is not None:
                self._hud_vao.release()
                self._hud_vbo.release()
            self._hud_vbo = _quad(self.ctx, -1.0, y0, x1, 1.0)
            self._hud_vao = self.ctx.vertex_array(self._prog, [(self._hud_vbo, "2f 2f", "in_pos", "in_uv")])
        self._hud_tex.use(location=0)
        self._hud_vao.render(self._mgl.TRIANGLE_STRIP)

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

    def screenshot(self, path=None) -> Path:
        """Save what the window shows (redrawn into the back buffer) as a PNG; returns its path."""
        from PIL import Image

        if path is None:
            self.screenshot_dir.mkdir(parents=True, exist_ok=True)
            k = 0
            while (self.screenshot_dir / f"clipvol-{k:04d}.png").exists():
                k += 1
            path = self.screenshot_dir / f"clipvol-{k:04d}.png"
        path = Path(path)
        Image.fromarray(self.read_screen(), "RGB").save(path)
        self.last_screenshot = path
        self.state.message = f"saved {path}"
        self._hud_text = None
        return path

    def run(self, max_frames: int | None = None) -> int:
        """The event loop until the window closes (Esc) or ``max_frames`` loop iterations; returns 0."""
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

    def close(self) -> None:
        """Stop the loader threads, release GL objects, destroy the window."""
        try:
            if self.session is not None:
                self.session.close()
                self.session = None
        finally:
            glfw = self._glfw
            if self.window is not None:
                glfw.destroy_window(self.window)
                self.window = None
            if self._glfw_up:
                glfw.terminate()
                self._glfw_up = False
            self._egl.restore()

    def __enter__(self) -> "Viewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
