"""The one thread that draws for ``clipvol serve``: it owns the EGL context and every store's session.

Why one thread: a GL context is current on one thread, and a CPU renderer (Mesa llvmpipe) already
uses every core for one frame, so frames of several browsers drawn at once would only slow each
other. The asyncio loop (:mod:`clipvol.app.serve.server`) never draws: it hands this worker a
view's newest state (:meth:`RenderWorker.request`) and the worker keeps only the newest per view
(a drag of a hundred pointer moves during one slow frame is one frame, not a hundred). Views take
turns, oldest request first.

**Adaptive quality** (as the desktop viewer, :mod:`clipvol.app.adaptive`): while a view's camera
moves, its frames are drawn smaller and with a longer sample step, chosen to hold the target frame
time, without waiting for bricks, and sent compactly (JPEG by default); once the camera has rested
for ``settle_s`` (or twice the time the page takes to answer a frame with its next move, when
that is longer: a busy or distant browser) the full-size frame is drawn waiting for its bricks (bounded by ``timeout``) and
sent losslessly (PNG) with its camera (:func:`clipvol.scene.bookmarks.camera_to_json`), so the
page shows exactly what ``clipvol render`` writes for that camera. A change that is not a camera
move (transfer function, mode, cut, slice) draws the full frame at once. A new view's first
picture is a small one of the coarse levels (:data:`PREVIEW`, its few bricks waited for), so the
page shows the data well before the converged frame's bricks are all read.

**Sharing.** All views of one store draw through one :class:`~clipvol.app.session.RenderSession`:
one clip-texture, one memory budget, one GPU cache. Before each frame the session takes the view's
transfer function, mode and cut (:meth:`RenderSession.update` keeps the resident bricks and the GPU
cache), so each browser has its own camera and settings over the same bricks.
"""

from __future__ import annotations

import io
import itertools
import logging
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ...errors import ClipvolError, ParameterError
from ..adaptive import Quality

__all__ = ["RenderWorker", "encode"]

log = logging.getLogger("clipvol.serve")

#: frame encodings for moving frames (pillow's format names); the converged frame is always PNG
FORMATS = {"jpeg": ("JPEG", "image/jpeg"), "webp": ("WEBP", "image/webp"), "png": ("PNG", "image/png")}


def encode(img: np.ndarray, fmt: str, quality: int = 80) -> bytes:
    """``img`` (``(h, w, 4)`` uint8 straight-alpha RGBA) as ``fmt`` bytes; JPEG has no alpha, so it
    gets the image over black, as the page shows it."""
    from PIL import Image

    name, _ = FORMATS[fmt]
    buf = io.BytesIO()
    if name == "JPEG":
        a = img[..., 3:4].astype(np.uint16)
        rgb = ((img[..., :3].astype(np.uint16) * a + 127) // 255).astype(np.uint8)
        Image.fromarray(np.ascontiguousarray(rgb), "RGB").save(buf, format="JPEG", quality=quality)
    elif name == "WEBP":
        Image.fromarray(np.ascontiguousarray(img), "RGBA").save(buf, format="WEBP", quality=quality)
    else:
        Image.fromarray(np.ascontiguousarray(img), "RGBA").save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


#: the first frame of a new view: a third of each side, twice the step (coarse levels, few bricks)
PREVIEW = Quality(1.0 / 3.0, 2.0, False)


@dataclass
class _Slot:
    """One view, as the worker keeps it."""

    store: int
    size: tuple[int, int]
    state: object  # a ViewState copy: the newest asked for
    kinds: set = field(default_factory=set)  # what changed since the last frame ("camera", "look")
    picks: list = field(default_factory=list)
    asked: float = 0.0  # when the oldest undrawn request came
    full_due: float | None = None  # when the converged frame is due (the camera rests)
    adaptive: object = None
    cam: object = None  # the full-size camera of the last frame
    shown_size: tuple[int, int] = (1, 1)  # the pixel size of the last frame sent
    probe: object = None
    ruler: object = None
    values: np.ndarray | None = None  # a slice's values (probe without a ray)
    frames: int = 0
    seconds: float = 0.0  # the last frame's time (the HUD of a probe)
    sent_at: float | None = None  # when the last moving frame was handed over
    gap: float = 0.0  # how long the page takes to answer a moving frame with its next move (smoothed)


class _Store:
    """A store's session, its transfer functions and its slice action (made on the worker thread)."""

    def __init__(self, loader, ctx, memory_budget, texture_budget, threads, name: str) -> None:
        from ..session import RenderSession
        from ...scene.params import RenderParams

        self.name = name
        self.session = RenderSession(loader, ctx, memory_budget=memory_budget, threads=threads,
                                     params=RenderParams(texture_budget=texture_budget), tf="grey")
        self.loader = self.session.loader
        self.frame = getattr(self.loader, "frame", None)
        self.unit = getattr(self.loader, "unit", None) or ""
        self.base_step = self.session.params.step
        self._auto = None
        self._tfs: dict = {}
        self._slices = None
        from ...scene.probe import Prober

        self.prober = Prober(self.loader)

    def transfer_function(self, name: str, window):
        """The view's transfer function: a preset (or ``auto``, from the histogram) over ``window``
        (default: the preset's own, the data's value range)."""
        key = (name, None if window is None else tuple(float(v) for v in window))
        tf = self._tfs.get(key)
        if tf is None:  # one object per setting: the session sees no change while a view's tf stays
            if len(self._tfs) >= 64:
                self._tfs.clear()
            tf = self._tfs[key] = self._make_tf(name, key[1])
        return tf

    def _make_tf(self, name: str, window):
        from ...scene.transfer import TransferFunction

        if name == "auto":
            if self._auto is None:
                from ...scene.auto_tf import auto_transfer_function

                self._auto = auto_transfer_function(self.loader)
            return self._auto if window is None else self._auto.with_value_range(tuple(window))
        return TransferFunction.preset(name, value_range=tuple(window) if window else None)

    def slices(self):
        if self._slices is None:
            from ...render.slice_action import SliceAction
            from ...scene.params import RenderParams

            s = self.session
            self._slices = SliceAction(s.ctx, s.clip_texture, RenderParams(texture_budget=s.params.texture_budget),
                                       cache=s.action.cache)
            self._slices.follow_plane = False  # the volume views' cube windows stay: they share the clip-texture
        return self._slices

    def close(self) -> None:
        try:
            if self._slices is not None:
                self._slices.close()
        finally:
            self.session.close()


class RenderWorker:
    """The render thread of a server.

    Parameters
    ----------
    loaders : sequence of loaders
        One per store (opened by the caller, on any thread).
    names : sequence of str
        Their names (shown in the page).
    deliver : callable
        ``deliver(view_id, message: dict, data: bytes | None)``, called on this thread with each
        frame (``message["method"] == "frame"``, ``data`` the encoded image) or state change
        (``"update"``, no data); the server passes it on to the view's connection.
    memory_budget, texture_budget, threads, timeout
        The clip-texture's main-memory budget (per store), the GPU budget, the loader threads, and
        how long a converged frame waits for its bricks.
    target_s, settle_s : float
        The frame time held while a camera moves; how long it rests before the converged frame
        (longer than the desktop viewer's 0.2 s: a browser's next move comes over the network).
    moving_format : str
        ``jpeg`` (default), ``webp`` or ``png`` for the frames drawn while the camera moves.
    """

    def __init__(self, loaders, names, deliver: Callable | None = None, *, memory_budget="512MB", texture_budget="256MB",
                 threads: int | None = None, timeout: float = 30.0, target_s: float = 0.1, settle_s: float = 0.35,
                 moving_format: str = "jpeg") -> None:
        if moving_format not in FORMATS:
            raise ParameterError(f"--format: expected one of {', '.join(FORMATS)}, got {moving_format!r}")
        self._loaders = list(loaders)
        self.names = list(names)
        self.deliver = deliver
        self._budgets = (memory_budget, texture_budget, threads)
        self.timeout = float(timeout)
        self.target_s = float(target_s)
        self.settle_s = float(settle_s)
        self.moving_format = moving_format
        self._cond = threading.Condition()
        self._slots: dict[int, _Slot] = {}
        self._stop = False
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.stores: list[_Store] = []
        self._thread = threading.Thread(target=self._run, name="clipvol-serve-render", daemon=True)

    # -- life -------------------------------------------------------------------------------------
    def start(self) -> "RenderWorker":
        """Start the thread and wait until its context and sessions exist (their errors raise here)."""
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._thread.join()
            raise self._error
        return self

    def close(self) -> None:
        """Stop drawing, release every session and the context (joins the thread)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join()

    # -- the loop's side --------------------------------------------------------------------------
    def open_view(self, view_id: int, store: int, size, state) -> None:
        """A new view of store ``store``: its first (converged) frame is drawn as soon as it is its turn."""
        with self._cond:
            self._slots[view_id] = _Slot(store, tuple(size), state, {"look"}, asked=time.monotonic())
            self._cond.notify_all()

    def request(self, view_id: int, state, kinds, pick=None) -> None:
        """The view's newest state (a copy) and what changed; replaces any request not yet drawn."""
        with self._cond:
            s = self._slots.get(view_id)
            if s is None:
                return
            if not s.kinds and not s.picks:
                s.asked = time.monotonic()
            if "camera" in kinds and s.sent_at is not None:  # the page answers a moving frame with its next move
                s.gap = 0.7 * s.gap + 0.3 * (time.monotonic() - s.sent_at)
                s.sent_at = None
            s.state = state
            s.kinds |= set(kinds)
            if pick is not None and len(s.picks) < 4:
                s.picks.append(pick)
            self._cond.notify_all()

    def close_view(self, view_id: int) -> None:
        with self._cond:
            self._slots.pop(view_id, None)

    # -- the thread -------------------------------------------------------------------------------
    def _run(self) -> None:
        from ...render.context import create_context

        ctx = None
        try:
            ctx = create_context()
            mem, tex, threads = self._budgets
            for loader, name in zip(self._loaders, self.names):
                self.stores.append(_Store(loader, ctx, mem, tex, threads, name))
        except BaseException as e:  # noqa: BLE001 - handed to start()'s caller
            self._error = e
            self._release(ctx)
            self._ready.set()
            return
        for st in self.stores:  # compile the shaders and ask for the coarse bricks before any page opens
            try:
                from .state import orbit_camera

                st.session.render(orbit_camera(st.session.pyramid, "iso", (16, 16)), wait=False)
            except Exception:  # noqa: BLE001 - a page's own frame reports what is wrong
                log.debug("warm-up frame of %s failed", st.name, exc_info=True)
        self._ready.set()
        try:
            while True:
                job = self._next_job()
                if job is None:
                    return
                self._do(*job)
        finally:
            self._release(ctx)

    def _release(self, ctx) -> None:
        for st in self.stores:
            try:
                st.close()
            except Exception:  # noqa: BLE001 - closing the rest matters more
                log.exception("closing store %s", st.name)
        self.stores = []
        if ctx is not None:
            ctx.release()

    def _next_job(self):
        """Wait for the next thing to draw: the oldest request, else a converged frame that is due."""
        with self._cond:
            while not self._stop:
                now = time.monotonic()
                waiting = [(s.asked, vid) for vid, s in self._slots.items() if s.kinds or s.picks]
                if waiting:
                    _, vid = min(waiting)
                    s = self._slots[vid]
                    kinds, picks, s.kinds, s.picks = s.kinds, s.picks, set(), []
                    return vid, s, s.state, kinds, picks, False
                due = [(s.full_due, vid) for vid, s in self._slots.items() if s.full_due is not None]
                if due:
                    t, vid = min(due)
                    if t <= now:
                        s = self._slots[vid]
                        s.full_due = None
                        return vid, s, s.state, set(), [], True
                    self._cond.wait(t - now)
                else:
                    self._cond.wait()
            return None

    def _do(self, vid: int, slot: _Slot, state, kinds: set, picks: list, settled: bool) -> None:
        from ..adaptive import AdaptiveQuality
        from ...render.failures import _cause as one_line

        if slot.adaptive is None:
            slot.adaptive = AdaptiveQuality(self.target_s, settle_s=self.settle_s)
            from ...scene.probe import Ruler

            slot.ruler = Ruler()
        try:
            if slot.frames == 0 and not state.slice and not settled:
                # the page's first picture: a small frame of the coarse levels, its few bricks waited
                # for (far fewer than the full frame's), then the converged frame at once
                self._frame(vid, slot, state, PREVIEW, wait=True)
                with self._cond:
                    slot.full_due = time.monotonic()
            elif kinds or settled:
                now = time.monotonic()
                moving = kinds == {"camera"} and slot.frames > 0 and not state.slice
                if not moving:
                    slot.adaptive.invalidate()
                q = slot.adaptive.next(moving, now) if moving else None
                self._frame(vid, slot, state, q)
                if moving:  # the converged frame once the camera rests: no next move within the settle
                    # time, or within twice the page's usual answer (a busy browser or a far one)
                    with self._cond:
                        slot.sent_at = time.monotonic()
                        slot.full_due = slot.sent_at + max(self.settle_s, 2.0 * slot.gap)
            for x, y, shift in picks:
                self._pick(vid, slot, state, x, y, shift)
        except ClipvolError as e:
            self.deliver(vid, {"method": "update", "state": {"error": one_line(e), "handled": state.handled}}, None)
        except Exception as e:  # noqa: BLE001 - one view's failure must not stop the server
            log.exception("view %s: frame failed", vid)
            self.deliver(vid, {"method": "update", "state": {"error": one_line(e), "handled": state.handled}}, None)

    def _look(self, store: _Store, state, step_factor: float = 1.0) -> None:
        """Give the store's session this view's transfer function, mode, cut and sample step."""
        tf = store.transfer_function(state.tf, state.window)
        iso = state.iso_value if state.mode == "iso" else None
        store.session.update(tf=tf, mode=state.mode, iso_value=iso, shape=state.cut(store.session.pyramid, store.frame),
                             step=store.base_step * step_factor)

    def _frame(self, vid: int, slot: _Slot, state, q, *, wait: bool | None = None) -> None:
        """Draw one frame of the view (``q``: an interactive quality, None: the converged frame) and
        deliver it; ``wait`` for its bricks (default: for the converged frame only)."""
        from ...scene.bookmarks import camera_to_json
        from ..live_view import finish_frame, hud_text

        store = self.stores[slot.store]
        sess = store.session
        full = q is None or q.full
        t0 = time.perf_counter()
        if state.slice:
            img, cam, error = self._slice(store, slot, state, wait=True)
            extra = (f"{state.slice} slice",)
        else:
            size = slot.size if full else q.size(slot.size)
            self._look(store, state, 1.0 if full else q.step_factor)
            cam = state.camera(sess.pyramid, size, store.frame)
            wait = full if wait is None else wait
            img = sess.render(cam, cam.center, wait=wait, timeout=self.timeout if wait else None)
            img, error = finish_frame(sess, img, cam, store.frame, labels=True)
            slot.values = None
            if full:
                extra = ("converged" if getattr(sess.frame_stats, "converged", True) else "not converged",)
            else:
                extra = (f"moving: {100 * q.scale:.0f} % size, step x{q.step_factor:.1f}",)
        dt = time.perf_counter() - t0
        fmt = "png" if full else self.moving_format
        data = encode(img, fmt)
        spent = time.perf_counter() - t0  # what the frame costs the page's frame rate: drawn and encoded
        if q is PREVIEW:
            pass  # its time includes reading bricks: no measure of a moving frame's cost
        elif not full:
            slot.adaptive.done(q, spent)
        elif q is None:
            from ..adaptive import FULL

            slot.adaptive.done(FULL, spent)
        fs = sess.frame_stats if not state.slice else None
        failed = len(getattr(fs, "failed_bricks", ()) or ())
        slot.cam = cam if full else state.camera(sess.pyramid, slot.size, store.frame)
        slot.shown_size = (img.shape[1], img.shape[0])
        slot.frames += 1
        slot.seconds = dt
        converged = bool(full and getattr(fs, "converged", True))
        hud = hud_text(sess, dt, cam, store.frame, probe=slot.probe, ruler=slot.ruler, unit=store.unit,
                       extra=(*extra, f"failed {failed}"))
        msg = {"method": "frame", "format": FORMATS[fmt][1], "full": full, "converged": converged,
               "width": slot.size[0], "height": slot.size[1], "seconds": dt, "hud": hud, "error": error,
               "handled": state.handled, "camera": camera_to_json(slot.cam) if not state.slice else None}
        self.deliver(vid, msg, data)
        if full and not state.slice and not converged and not error:  # bricks still coming: draw again soon
            with self._cond:
                slot.full_due = time.monotonic() + self.settle_s

    def _slice(self, store: _Store, slot: _Slot, state, *, wait: bool):
        """A slice of the view's plane, fitted into the view (its values kept for a probe)."""
        from ...scene.plane import Plane
        from ...scene.views import anatomical_plane, is_anatomical
        from ..slice_session import leave_out_cut

        pyr = store.session.pyramid
        if is_anatomical(store.frame):
            plane = anatomical_plane(pyr, store.frame, state.slice, state.slice_index)
        else:
            plane = Plane.axis(pyr, state.slice, state.slice_index)
        lo, hi = pyr.volume_box()
        umin, umax, vmin, vmax = plane.footprint(lo, hi)
        w, h = slot.size
        px = max(2 * max(abs(umin), abs(umax)) / w, 2 * max(abs(vmin), abs(vmax)) / h, 1e-12)
        action = store.slices()
        action.set_params(replace(action.params, focus=tuple(float(v) for v in plane.origin)))
        store.session.set_center(plane.origin)
        tf = store.transfer_function(state.tf, state.window)
        rgba, values = action.render(plane, slot.size, px, transfer_function=tf, wait=wait, timeout=self.timeout,
                                     return_values=True)
        # the view's crop box and clip plane cut its slices as they cut its volume
        rgba, values = leave_out_cut(rgba, values, state.cut(pyr, store.frame), plane, px)
        slot.values = values
        error = ""
        holes = tuple(getattr(action.last_stats, "unreplaced", ()))
        if holes:
            from ...render.failures import describe_failed, hatch_failed

            rgba = hatch_failed(rgba, action.last_camera, pyr, holes, plane=plane)
            error = f"{len(holes)} brick(s) failed and nothing stands in for them (striped red): {describe_failed(holes)}"
        if store.frame is not None and store.frame.frame == "RAS":
            from ...scene.orientation import view_labels
            from ..annotate import label_edges

            rgba = label_edges(rgba, view_labels(store.frame.affine, plane.right, plane.up, store.frame.frame))
        return rgba, action.last_camera, error

    def _pick(self, vid: int, slot: _Slot, state, x: float, y: float, shift: bool) -> None:
        """A click at ``(x, y)`` of the image shown: the probe (Shift: a ruler end) on the HUD."""
        from ..live_view import hud_text, probe_pixel

        store = self.stores[slot.store]
        if slot.cam is None:
            return
        sx, sy = slot.size[0] / max(slot.shown_size[0], 1), slot.size[1] / max(slot.shown_size[1], 1)
        x, y = float(x) * sx, float(y) * sy
        if state.slice:
            v = slot.values
            i, j = int(min(max(y, 0), v.shape[0] - 1)), int(min(max(x, 0), v.shape[1] - 1))
            text = f"value {v[i, j]:.6g} at pixel ({j}, {i}) of the {state.slice} slice"
            self.deliver(vid, {"method": "update", "state": {"hud": text, "handled": state.handled}}, None)
            return
        self._look(store, state)
        p = probe_pixel(store.session, store.prober, slot.cam, store.frame, x, y)
        slot.probe = p
        if shift and p is not None:
            slot.ruler.add(p.world)
        hud = hud_text(store.session, slot.seconds, slot.cam, store.frame, probe=p, ruler=slot.ruler, unit=store.unit)
        if p is None:
            hud += "\nprobe: the ray meets nothing visible there"
        self.deliver(vid, {"method": "update", "state": {"hud": hud, "handled": state.handled}}, None)


_ids = itertools.count(1)


def new_view_id() -> int:
    """A process-unique view number."""
    return next(_ids)

