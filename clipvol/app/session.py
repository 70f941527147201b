"""One data source on screen: a loader, its clip-texture and a clip render action, as one object.

The window, the offscreen path renderer (``clipvol view --offscreen``), the report and the demo
all do the same per frame: move the centre of interest, render without waiting (or converged),
read the statistics. :class:`RenderSession` holds the three parts, applies parameter changes (a
new frozen :class:`~clipvol.scene.params.RenderParams` handed to the render action: its GPU cache
and the clip-texture's resident bricks are kept), and closes everything in the right order (render
action, then loader threads). It imports no window toolkit: the report, the CLI, a notebook and
the viewer all stand on it.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import ParameterError
from ..paging.cliptexture import ClipTexture
from ..paging.open import open_store
from ..render.action import ClipRenderAction
from ..scene.params import RenderParams
from ..scene.transfer import TransferFunction

__all__ = ["ActionSession", "RenderSession", "open_loader", "make_overlays"]


def open_loader(source, **kwargs):
    """A loader for ``source``: a store path, ``procedural:...`` URL, ``.npy`` path, or a loader."""
    if hasattr(source, "read_brick") and hasattr(source, "pyramid"):
        return source
    return open_store(source, **kwargs)


def make_overlays(specs) -> tuple:
    """:class:`~clipvol.scene.overlay.Overlay` objects from ``specs``: each an ``Overlay``, a source
    (store path, URL or loader; transfer function ``diverging``) or a ``(source, tf)`` pair."""
    from ..scene.overlay import Overlay

    out = []
    for spec in specs or ():
        if isinstance(spec, Overlay):
            out.append(spec)
            continue
        source, tf = (spec if isinstance(spec, tuple) and len(spec) == 2 else (spec, "diverging"))
        name = source if isinstance(source, str) else ""
        out.append(Overlay(open_loader(source), tf, name=str(name)))
    return tuple(out)


def resolve_tf(tf, loader):
    """The :class:`~clipvol.scene.transfer.TransferFunction` of ``tf``: itself, the preset of that
    name, or for ``"auto"`` a window on ``loader``'s foreground from its histogram."""
    if not isinstance(tf, str):
        return tf
    if tf == "auto":
        from ..scene.auto_tf import auto_transfer_function

        return auto_transfer_function(loader)
    return TransferFunction.preset(tf)


def _check_tf(tf):
    if not isinstance(tf, str) and not hasattr(tf, "table"):
        raise ParameterError(f"tf: expected a preset name or a TransferFunction, got {tf!r}")
    return tf


class ActionSession:
    """What every session of one render action over one clip-texture shares: closing both in the
    right order (the action's GL resources first, then the loader threads), also as a context
    manager. Subclasses set ``action`` and ``clip_texture``."""

    action = None
    clip_texture = None

    def close(self) -> None:
        """Release the action's GL resources, then stop the loader threads."""
        try:
            if self.action is not None:
                self.action.close()
                self.action = None
        finally:
            if self.clip_texture is not None:
                self.clip_texture.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class RenderSession(ActionSession):
    """A loader + :class:`~clipvol.paging.cliptexture.ClipTexture` + :class:`~clipvol.render.action.ClipRenderAction`.

    Parameters
    ----------
    source : loader, path or URL
        The data (anything :func:`clipvol.paging.open.open_store` opens, or a loader).
    ctx : moderngl.Context
        The GL context to draw with (offscreen EGL or a window's).
    memory_budget : int or str
        Budget of the clip-texture (main memory).
    threads : int, optional
        Loader threads (default: number of cores).
    params : RenderParams, optional
        Initial render parameters (policy, mode, step, budgets, background).
    tf : str or TransferFunction
        The transfer function: a preset name or an object.
    texture_budget, background : optional
        Shorthands for the same fields of ``params``.
    overlays : sequence, optional
        Co-registered volumes drawn over the source in the same ray cast (see :func:`make_overlays`
        and :mod:`clipvol.scene.overlay`): ``[("zmap.zarr", "diverging")]``.
    center : 3 floats, optional
        The clip-texture's first centre of interest (render frame; default the volume's centre). A
        one-shot frame gives its camera's target, so the loader threads start reading where the
        frame looks rather than around the middle.
    """

    def __init__(self, source, ctx, *, memory_budget="256MB", threads=None, params: RenderParams | None = None,
                 tf="viridis", texture_budget=None, background=None, overlays=None, center=None) -> None:
        over = {k: v for k, v in (("texture_budget", texture_budget), ("background", background)) if v is not None}
        if overlays is not None:
            over["overlays"] = make_overlays(overlays)
        self.params = RenderParams.from_kwargs(params, **over)
        self.tf = _check_tf(tf)
        self.loader = open_loader(source)
        self.pyramid = self.loader.pyramid
        self.params.check_for(self.pyramid)
        self.ctx = ctx
        from ..scene.cut import outside_bricks

        # bricks outside a crop box / clip planes are culled by the selection and never read either
        self.clip_texture = ClipTexture(self.loader, memory_budget, threads, center=center,
                                        outside=outside_bricks(self.pyramid, self.params.shape))
        self._tf = None
        self._tf_name = None
        self._center = None
        try:
            self.action = ClipRenderAction(ctx, self.clip_texture, self.params)
        except BaseException:
            self.clip_texture.close()
            raise

    # -- parameters -----------------------------------------------------------------------------
    def update(self, tf=None, **changes) -> bool:
        """Change render parameters (``lod_threshold=2``, ``mode='mip'``, ``policy='fixed'``) and/or
        the transfer function (``tf=``); returns whether anything changed.

        The new :class:`RenderParams` is built (and so validated) first; the render action takes it
        for the next frame and keeps its GPU cache, and the clip-texture keeps its bricks.
        """
        if "overlays" in changes:
            changes["overlays"] = make_overlays(changes["overlays"])
        new = RenderParams.from_kwargs(self.params, **changes).check_for(self.pyramid)
        changed = False
        if tf is not None and (tf is not self.tf and tf != self.tf):
            self.tf = _check_tf(tf)
            changed = True
        if new != self.params:
            if new.shape != self.params.shape:
                from ..scene.cut import outside_bricks

                if self._set_outside(outside_bricks(self.pyramid, new.shape)):
                    self.action.use_clip_texture(self.clip_texture)  # the GPU may hold their fill: empty it
            self.params = new
            self.action.set_params(new)
            changed = True
        return changed

    @property
    def transfer_function(self):
        """The :class:`~clipvol.scene.transfer.TransferFunction` of the current ``tf``."""
        tf = self.tf
        if not isinstance(tf, str):
            return tf
        if self._tf_name != tf:
            self._tf = resolve_tf(tf, self.loader)
            self._tf_name = tf
        return self._tf

    # -- per frame ----------------------------------------------------------------------------
    def set_center(self, xyz) -> None:
        """Move the clip-texture's centre of interest (clamped into the volume box) if it moved."""
        lo, hi = self.pyramid.volume_box()
        c = np.clip(np.asarray(xyz, dtype=np.float64), lo, hi)
        if self._center is None or not np.array_equal(c, self._center):
            self._move_center(c)
            self._center = c

    def _set_outside(self, outside) -> int:
        """Where a new cut's unread bricks go: the clip-texture (a series: every step it holds)."""
        return self.clip_texture.set_outside(outside)

    def _move_center(self, c: np.ndarray) -> None:
        """Where a new centre of interest goes: the clip-texture (a series: every step it holds)."""
        self.clip_texture.set_center(c)

    def render(self, camera, center=None, *, wait: bool = False, timeout: float | None = None) -> np.ndarray:
        """Render one frame (``(h, w, 4)`` uint8, row 0 at top); ``center`` moves the centre of interest first."""
        if center is not None:
            self.set_center(center)
        return self.action.render(camera, self.transfer_function, wait=wait, timeout=timeout)

    def timed_render(self, camera, center=None, *, wait: bool = False, timeout: float | None = None) -> tuple[np.ndarray, float]:
        """:meth:`render` and its wall time in seconds."""
        t0 = time.perf_counter()
        img = self.render(camera, center, wait=wait, timeout=timeout)
        return img, time.perf_counter() - t0

    @property
    def frame_stats(self):
        """The render action's ``last_frame_stats``."""
        return self.action.last_frame_stats if self.action is not None else None

    @property
    def texture_stats(self):
        """The clip-texture's ``stats`` snapshot."""
        return self.clip_texture.stats

    def last_items(self) -> list:
        """The draw items of the last frame (for brick outlines); empty before the first frame."""
        sel = getattr(self.action, "last_selection", None)
        return list(sel.items) if sel is not None else []
