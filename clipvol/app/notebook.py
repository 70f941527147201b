"""``clipvol.show(...)``: an interactive view in a Jupyter notebook, rendered server-side offscreen.

The notebook's kernel runs the same clip render action as ``clipvol view`` on an offscreen EGL
context (no GPU, no display needed) and sends each frame to the browser as a PNG; the browser
half is a few lines of JavaScript in an anywidget (Manzt et al., *anywidget*, 2024), a small
pure-Python widget layer on ipywidgets, chosen over jupyter_rfb because it needs no compiled
front-end extension. It is an optional extra: ``pip install 'clipvol[notebook]'``.

In the view: drag to orbit, wheel to zoom, menus for the transfer-function preset and
composite / MIP; the HUD line under the image gives the frame time, bricks drawn per level, the
resident memory and, for a patient-frame store (NIfTI, DICOM), the anatomical label of each
image edge. The same view is scriptable: ``v.set_view(azimuth=90)``, ``v.tf = "magma"``,
``v.snapshot()`` returns the last frame as an RGBA array.

Each frame waits for its bricks (``wait=True``, bounded by ``timeout``), so what is shown is
drawn at the levels the LOD selection wants; a very large store stays interactive because only
the bricks of the view are read (the clip-texture's budget bounds the memory).
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

_ESM = r"""
function render({ model, el }) {
  const root = document.createElement("div");
  root.style.display = "inline-block";
  const img = document.createElement("img");
  img.draggable = false;
  img.style.cursor = "grab";
  img.style.touchAction = "none";
  img.style.background = "#000";
  const bar = document.createElement("div");
  const tfSel = document.createElement("select");
  for (const n of model.get("tf_names")) {
    const o = document.createElement("option"); o.value = n; o.textContent = n; tfSel.appendChild(o);
  }
  const modeSel = document.createElement("select");
  for (const n of ["composite", "mip"]) {
    const o = document.createElement("option"); o.value = n; o.textContent = n; modeSel.appendChild(o);
  }
  const hud = document.createElement("pre");
  hud.style.margin = "2px 0"; hud.style.fontSize = "11px";
  bar.append("tf ", tfSel, " mode ", modeSel);
  root.append(img, bar, hud);
  el.appendChild(root);
  const sync = () => {
    img.src = model.get("image");
    hud.textContent = model.get("hud");
    tfSel.value = model.get("tf");
    modeSel.value = model.get("mode");
  };
  sync();
  model.on("change:image", sync);
  model.on("change:hud", sync);
  model.on("change:tf", sync);
  model.on("change:mode", sync);
  tfSel.onchange = () => { model.set("tf", tfSel.value); model.save_changes(); };
  modeSel.onchange = () => { model.set("mode", modeSel.value); model.save_changes(); };
  let drag = null;
  img.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY, az: model.get("azimuth"), el: model.get("elevation") };
    img.setPointerCapture(e.pointerId); img.style.cursor = "grabbing";
  });
  img.addEventListener("pointermove", (e) => {
    if (!drag) return;
    model.set("azimuth", drag.az - (e.clientX - drag.x) * 0.5);
    model.set("elevation", Math.max(-89, Math.min(89, drag.el + (e.clientY - drag.y) * 0.5)));
    model.save_changes();
  });
  const end = () => { drag = null; img.style.cursor = "grab"; };
  img.addEventListener("pointerup", end);
  img.addEventListener("pointercancel", end);
  img.addEventListener("wheel", (e) => {
    e.preventDefault();
    model.set("zoom", Math.max(0.2, Math.min(20, model.get("zoom") * Math.exp(-e.deltaY * 0.001))));
    model.save_changes();
  }, { passive: false });
}
export default { render };
"""


@lru_cache(maxsize=1)
def _widget_class():
    try:
        import anywidget
        import traitlets
    except ImportError:
        raise MissingExtraError("clipvol.show needs anywidget (Jupyter widgets): pip install 'clipvol[notebook]'") from None

    class VolumeWidget(anywidget.AnyWidget):
        """The browser half: an image, two menus and a HUD line (state synchronised by traitlets)."""

        _esm = _ESM
        image = traitlets.Unicode("").tag(sync=True)
        hud = traitlets.Unicode("").tag(sync=True)
        azimuth = traitlets.Float(0.0).tag(sync=True)
        elevation = traitlets.Float(20.0).tag(sync=True)
        zoom = traitlets.Float(1.0).tag(sync=True)
        tf = traitlets.Unicode("viridis").tag(sync=True)
        mode = traitlets.Unicode("composite").tag(sync=True)
        tf_names = traitlets.List(traitlets.Unicode()).tag(sync=True)

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
                 store=None) -> None:
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
        self._ctx = create_context()
        try:
            self.session = RenderSession(loader, self._ctx, memory_budget=memory_budget, texture_budget=texture_budget,
                                         threads=threads, params=RenderParams(mode=mode, lod_threshold=lod_threshold), tf=tf)
        except BaseException:
            self._ctx.release()
            raise
        self.frame = getattr(self.session.loader, "frame", None)
        self.last_image: np.ndarray | None = None
        self.last_frame_s = 0.0
        cls = _widget_class()
        self.widget = cls(tf_names=list(TransferFunction.names()), tf=tf, mode=mode)
        self.widget.observe(self._changed, names=["azimuth", "elevation", "zoom", "tf", "mode"])
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

    # -- frames --------------------------------------------------------------------------------
    def _changed(self, change) -> None:
        name = change["name"]
        if name in ("tf", "mode"):
            from ..scene.transfer import TransferFunction

            try:
                if name == "tf" and change["new"] not in TransferFunction.names():
                    raise ParameterError(f"tf: expected one of {', '.join(TransferFunction.names())}, got {change['new']!r}")
                self.session.update(**{name: change["new"]})
            except ParameterError as e:
                self.widget.hud = f"error: {e}"
                return
        self.render()

    def render(self) -> np.ndarray:
        """Render the current view (waiting for its bricks up to ``timeout``) and send it to the browser."""
        cam, coi = self.camera()
        img, dt = self.session.timed_render(cam, coi, wait=True, timeout=self.timeout)
        from .annotate import present

        img = present(img, cam, self.frame, labels=self.labels)  # head-up, un-mirrored, R/L A/P S/I letters
        self.last_image = img
        self.last_frame_s = dt
        self.widget.image = _png_data_url(img)
        self.widget.hud = self.hud_text(cam)
        return img

    def hud_text(self, cam=None) -> str:
        """The HUD line: frame time, bricks per level, resident memory, edge labels."""
        fs = self.session.frame_stats
        ts = self.session.texture_stats
        parts = [f"{self.last_frame_s * 1e3:.0f} ms"]
        drawn = getattr(fs, "bricks_drawn", None) or {}
        items = drawn.items() if isinstance(drawn, dict) else enumerate(drawn)
        per = " ".join(f"L{k}:{int(v)}" for k, v in items if v)
        parts.append(f"bricks {per or '-'}")
        parts.append(f"resident {getattr(ts, 'resident_bytes', 0) / 1e6:.1f} MB")
        if not getattr(fs, "converged", True):
            parts.append("refining")
        if self.frame is not None and cam is not None:
            from ..scene.orientation import view_labels
            from ..scene.views import screen_axes

            lab = view_labels(self.frame.affine, *screen_axes(cam, self.frame), self.frame.frame)
            parts.append(f"left {lab['left']} right {lab['right']} top {lab['top']}")
        return "  ".join(parts)

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
