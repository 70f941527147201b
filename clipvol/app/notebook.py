"""``clipvol.show(...)``: an interactive view in a Jupyter notebook, rendered server-side offscreen.

The notebook's kernel runs the same clip render action as ``clipvol view`` on an offscreen EGL
context (no GPU, no display needed) and sends each frame to the browser as a PNG; the browser
half is a few lines of JavaScript in an anywidget (Manzt et al., *anywidget*, 2024), a small
pure-Python widget layer on ipywidgets, chosen over jupyter_rfb because it needs no compiled
front-end extension. It is an optional extra: ``pip install 'clipvol[notebook]'``.

In the view: drag to orbit, wheel to zoom, menus for the transfer-function preset and
composite / MIP, click to probe the first visible sample under the cursor (its value, level and
world position, :mod:`clipvol.scene.probe`), Shift+click to put a ruler end there; the HUD line under the image gives the frame time, bricks drawn per level, the
resident memory and, for a patient-frame store (NIfTI, DICOM), the anatomical label of each
image edge. The same view is scriptable: ``v.set_view(azimuth=90)``, ``v.tf = "magma"``,
``v.snapshot()`` returns the last frame as an RGBA array, ``v.probe(x, y)`` picks at a pixel,
``v.measure((x0, y0), (x1, y1))`` gives the distance of two picks in the store's unit, and
``clipvol.show(..., crop=..., crop_voxels=..., clip_planes=[...])`` or ``v.set_cut(...)`` cuts the
volume open (:mod:`clipvol.scene.cut`: world units of the store, or level-0 voxels).

Each frame waits for its bricks (``wait=True``, bounded by ``timeout``), so what is shown is
drawn at the levels the LOD selection wants; a very large store stays interactive because only
the bricks of the view are read (the clip-texture's budget bounds the memory). An error in the
kernel (a brick that failed with nothing to stand in for it, a render that raised, a wrong preset
name) shows as a red line under the image, with the image dimmed, until a frame is drawn whole.
The browser sends one camera change at a time (the kernel's ``handled`` count is its answer), so
pointer moves made during a slow frame merge into one instead of queueing a frame each.
"""

from __future__ import annotations

import base64
import io
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MissingExtraError, ParameterError

__all__ = ["VolumeView"]



@lru_cache(maxsize=1)
def _widget_class():
    try:
        import anywidget
        import traitlets
    except ImportError:
        raise MissingExtraError("clipvol.show needs anywidget (Jupyter widgets): pip install 'clipvol[notebook]'") from None
    from .live_view import view_esm

    class VolumeWidget(anywidget.AnyWidget):
        """The browser half: an image, two menus and a HUD line (state synchronised by traitlets)."""

        _esm = view_esm()  # web/view.js, the same module `clipvol serve`'s page runs
        image = traitlets.Unicode("").tag(sync=True)
        hud = traitlets.Unicode("").tag(sync=True)
        azimuth = traitlets.Float(0.0).tag(sync=True)
        elevation = traitlets.Float(20.0).tag(sync=True)
        zoom = traitlets.Float(1.0).tag(sync=True)
        tf = traitlets.Unicode("viridis").tag(sync=True)
        mode = traitlets.Unicode("composite").tag(sync=True)
        error = traitlets.Unicode("").tag(sync=True)
        handled = traitlets.Int(0).tag(sync=True)  # changes the kernel is done with: the browser's ack
        tf_names = traitlets.List(traitlets.Unicode()).tag(sync=True)
        mode_names = traitlets.List(traitlets.Unicode()).tag(sync=True)  # the registered modes (render/modes)
        #: a click in the image: [x, y, shift (a ruler end), counter] in image pixels
        pick = traitlets.List(traitlets.Float(), default_value=[0.0, 0.0, 0.0, 0.0]).tag(sync=True)

    return VolumeWidget


def _png_data_url(img: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img), "RGBA").save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


class VolumeView:
    """A live view of a store or array in a notebook (what :func:`clipvol.show` returns for a volume).

    The object displays as its widget (``_repr_mimebundle_``); changing :attr:`widget`'s traits
    (from the browser or from Python) renders a new frame. Call :meth:`close` to stop the loader
    threads and release the GL context.
    """

    def __init__(self, source, *, size=(384, 384), tf: str | None = None, mode: str = "composite",
                 memory_budget="256MB", texture_budget="256MB", threads: int | None = None,
                 lod_threshold: float = 1.0, timeout: float = 30.0, brick: int = 32, labels: bool = True,
                 store=None, crop=None, crop_voxels=None, clip_planes=(), iso_value: float | None = None) -> None:
        from ..render.context import create_context
        from ..scene.transfer import TransferFunction
        from ..scene.params import RenderParams
        from .session import RenderSession

        w, h = (int(v) for v in size)
        if not (16 <= w <= 2048 and 16 <= h <= 2048):
            raise ParameterError(f"size: expected (width, height) between 16 and 2048 pixels, got {size!r}")
        if tf is not None and tf not in TransferFunction.names():
            raise ParameterError(f"tf: expected one of {', '.join(TransferFunction.names())}, got {tf!r}")
        self.size = (w, h)
        self.timeout = float(timeout)
        self.labels = bool(labels)
        loader = _as_loader(source, brick, store)
        if tf is None:  # grey for a scan in a patient frame (CT, MRI), viridis otherwise
            from ..scene.views import is_anatomical

            tf = "grey" if is_anatomical(getattr(loader, "frame", None)) else "viridis"
        from ..scene.cut import cut_shape
        from ..scene.probe import Prober, Ruler

        shape = cut_shape(loader.pyramid, getattr(loader, "frame", None), crop=crop, crop_voxels=crop_voxels,
                          clip_planes=clip_planes)
        self._ctx = create_context()
        try:
            params = RenderParams(mode=mode, iso_value=iso_value, lod_threshold=lod_threshold, shape=shape)
            self.session = RenderSession(loader, self._ctx, memory_budget=memory_budget, texture_budget=texture_budget,
                                         threads=threads, params=params, tf=tf)
        except BaseException:
            self._ctx.release()
            raise
        self.frame = getattr(self.session.loader, "frame", None)
        self.unit = getattr(self.session.loader, "unit", None) or ""
        self.prober = Prober(self.session.loader)
        self.ruler = Ruler()
        self.last_probe = None
        self.last_image: np.ndarray | None = None
        self.last_frame_s = 0.0
        cls = _widget_class()
        from ..render.modes import DRAW_MODES

        self.widget = cls(tf_names=list(TransferFunction.names()), mode_names=list(DRAW_MODES), tf=tf, mode=mode)
        self.widget.observe(self._changed, names=["azimuth", "elevation", "zoom", "tf", "mode"])
        self.widget.observe(self._picked, names=["pick"])
        self.render()

    # -- camera --------------------------------------------------------------------------------
    def camera(self):
        """The current camera: a turntable view about the data's up (patient head-up for RAS stores)."""
        from ..scene.orientation import anatomical_axes
        from ..scene.paths import UP, fit_distance, turntable

        from ..scene.views import mirrored

        up, front = (UP, (0.0, 0.0, -1.0))
        if self.frame is not None and self.frame.frame == "RAS":
            up, front = anatomical_axes(self.frame.affine)
        wdg = self.widget
        d = fit_distance(self.session.pyramid, 30.0, self.size) / max(float(wdg.zoom), 1e-3)
        cam, coi = next(turntable(self.session.pyramid, 1, size=self.size, up=tuple(up), front=tuple(front),
                                  elevation=float(np.clip(wdg.elevation, -89, 89)), distance=d, azimuth=float(wdg.azimuth),
                                  mirror=mirrored(self.frame)))
        return cam, coi

    def set_view(self, *, azimuth: float | None = None, elevation: float | None = None, zoom: float | None = None) -> np.ndarray:
        """Turn / tilt / zoom the view (degrees, degrees, factor) and return the new frame."""
        with self.widget.hold_trait_notifications():
            if azimuth is not None:
                self.widget.azimuth = float(azimuth)
            if elevation is not None:
                self.widget.elevation = float(elevation)
            if zoom is not None:
                if not (np.isfinite(zoom) and zoom > 0):
                    raise ParameterError(f"zoom: expected a factor > 0, got {zoom!r}")
                self.widget.zoom = float(zoom)
        return self.last_image

    @property
    def tf(self) -> str:
        return self.widget.tf

    @tf.setter
    def tf(self, name: str) -> None:
        self.widget.tf = name

    @property
    def mode(self) -> str:
        return self.widget.mode

    @mode.setter
    def mode(self, name: str) -> None:
        self.widget.mode = name

    # -- cut, probe and measure -------------------------------------------------------------------
    def set_cut(self, *, crop=None, crop_voxels=None, clip_planes=()) -> np.ndarray:
        """Cut the volume open (a crop box in world units or level-0 voxels, up to six clip planes
        ``(x, y, z, nx, ny, nz)`` keeping the side the normal points to; nothing: the whole volume)
        and return the new frame. See :func:`clipvol.scene.cut.cut_shape`."""
        from ..scene.cut import cut_shape

        shape = cut_shape(self.session.pyramid, self.frame, crop=crop, crop_voxels=crop_voxels,
                          clip_planes=clip_planes)
        self.session.update(shape=shape)
        return self.render()

    def probe(self, x: float, y: float, *, threshold: float | None = None, level: int = 0):
        """The first visible sample under pixel ``(x, y)`` of the image shown (column, row from the
        top-left), or None where the ray sees nothing: a :class:`clipvol.scene.probe.Probe` with the
        value, level, voxel and world position. Also shown on the HUD line."""
        from .live_view import probe_pixel

        cam, _ = self.camera()
        p = probe_pixel(self.session, self.prober, cam, self.frame, x, y, threshold=threshold, level=level)
        self.last_probe = p
        self.widget.hud = self.hud_text(cam)
        return p

    def measure(self, a, b, **kwargs) -> float | None:
        """Distance in the store's world unit between the first visible samples under pixels ``a``
        and ``b`` (each ``(x, y)``), or None when either sees nothing; kept as :attr:`ruler`."""
        pa = self.probe(*a, **kwargs)
        pb = self.probe(*b, **kwargs)
        if pa is None or pb is None:
            return None
        self.ruler.clear()
        self.ruler.add(pa.world)
        self.ruler.add(pb.world)
        self.widget.hud = self.hud_text(self.camera()[0])
        return self.ruler.length

    def _picked(self, change) -> None:
        x, y, shift, _ = (list(change["new"]) + [0.0] * 4)[:4]
        try:
            p = self.probe(x, y)
        except ParameterError as e:
            self.widget.hud = f"error: {e}"
            return
        if shift and p is not None:
            self.ruler.add(p.world)
            self.widget.hud = self.hud_text(self.camera()[0])

    # -- frames --------------------------------------------------------------------------------
    def _changed(self, change) -> None:
        """Render after a change from the browser or from Python; any error shows in the view.

        A change from the browser arrives as a comm message, and an exception the kernel's comm
        handler catches only reaches the kernel's log: the view would keep its last frame as if
        the new one were drawn. So the error's line goes to the widget's ``error`` trait (shown
        in red under the image, the stale frame dimmed) before it is raised on to the caller. A
        wrong preset or mode name is only shown, not raised, the same from Python as from the
        browser.
        """
        from ..render.failures import _cause as one_line  # first line; a foreign error keeps its type's name

        name = change["name"]
        try:
            if name in ("tf", "mode"):
                from ..scene.transfer import TransferFunction

                if name == "tf" and change["new"] not in TransferFunction.names():
                    raise ParameterError(f"tf: expected one of {', '.join(TransferFunction.names())}, got {change['new']!r}")
                self.session.update(**{name: change["new"]})
            self.render()
        except ParameterError as e:
            self.widget.error = one_line(e)
        except Exception as e:
            self.widget.error = one_line(e)
            raise
        finally:
            self.widget.handled += 1  # after the frame or the error: the browser may send its next change

    def render(self) -> np.ndarray:
        """Render the current view (waiting for its bricks up to ``timeout``) and send it to the browser."""
        cam, coi = self.camera()
        img, dt = self.session.timed_render(cam, coi, wait=True, timeout=self.timeout)
        from .live_view import finish_frame

        img, error = finish_frame(self.session, img, cam, self.frame, labels=self.labels)  # hatched, head-up, lettered
        self.last_image = img
        self.last_frame_s = dt
        with self.widget.hold_sync():  # one message: the frame, its HUD and its error arrive together
            self.widget.image = _png_data_url(img)
            self.widget.hud = self.hud_text(cam)
            self.widget.error = error
        return img

    def hud_text(self, cam=None) -> str:
        """The HUD line: frame time, bricks per level, resident memory, edge labels (:func:`clipvol.app.live_view.hud_text`)."""
        from .live_view import hud_text

        return hud_text(self.session, self.last_frame_s, cam, self.frame, probe=self.last_probe, ruler=self.ruler,
                        unit=self.unit)

    def snapshot(self) -> np.ndarray:
        """The last frame, ``(h, w, 4)`` uint8 RGBA."""
        return self.last_image.copy()

    def _repr_mimebundle_(self, **kwargs) -> Any:
        return self.widget._repr_mimebundle_(**kwargs)

    def close(self) -> None:
        """Stop the loader threads, release GL resources and close the widget."""
        try:
            self.session.close()
        finally:
            self._ctx.release()
            self.widget.close()

    def __enter__(self) -> "VolumeView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _as_loader(source, brick: int, store=None):
    if isinstance(source, np.ndarray):
        from ..loaders.numpy_array import NumpyLoader

        if source.ndim != 3:
            raise ParameterError(f"source: expected a 3-D array (z, y, x), got shape {source.shape}")
        return NumpyLoader(source, brick=brick)
    from .session import open_loader

    if isinstance(source, (str, Path)):  # a NIfTI / DICOM / HDF5 / MRC input: bricked once, as `clipvol view` does
        from .autobrick import bricked_source

        source = bricked_source(str(source), store)
    return open_loader(source)
