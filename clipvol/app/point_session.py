"""One point store on screen: its loader, clip-texture and splat render action, as one object.

The point-store counterpart of :class:`clipvol.app.session.RenderSession`: the viewer
(``clipvol view POINTS.zarr``) and the report (``clipvol report POINTS.zarr``) both move the
centre of interest, render splats at a tolerance (without waiting, or converged) and read the
frame statistics. :class:`PointSession` holds the three parts, applies setting changes (the
clip-texture's resident nodes are kept when the tolerance, mode or transfer function change) and
closes them in order (render action, then loader threads). It imports no window toolkit.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..paging.cliptexture import ClipTexture
from ..render.splat import SplatRenderAction
from ..scene.splat_select import tolerance_pixels
from ..scene.transfer import TransferFunction

__all__ = ["PointSession", "open_point_loader"]


def open_point_loader(source):
    """A :class:`clipvol.loaders.point_store.PointStoreLoader` for a path (or the loader itself)."""
    if hasattr(source, "nodes") and hasattr(source, "to_paging"):
        return source
    from clipvol.loaders.point_store import PointStoreLoader

    return PointStoreLoader(source)


class PointSession:
    """A point store's loader, clip-texture and :class:`~clipvol.render.splat.SplatRenderAction`.

    Parameters
    ----------
    source : path or PointStoreLoader
        A store written by ``clipvol brick-points``.
    ctx : moderngl.Context
        The GL context to draw with.
    memory_budget : int or str
        Clip-texture budget (main memory for node payloads).
    threads : int, optional
        Loader threads.
    tolerance : float or str
        Largest splat: a fraction of the screen's linear size, ``"5%"`` or ``"12px"``.
    mode : {"composite", "mip"}
    tf : str or TransferFunction, optional
        A preset name or a transfer function (default ``viridis`` over the value's range).
    value : int or str
        The value column drawn.
    background : 4 floats
        Straight RGBA behind the points.
    shading : bool
        Composite: lighting from each point's weighted least-squares gradient.
    light : 4 floats
        Ambient, diffuse, specular and shininess of that lighting.
    center : 3 floats, optional
        The first centre of interest (world ``(x, y, z)``, clamped into the root cube; default its
        centre): a one-shot frame gives its camera's target.
    """

    def __init__(self, source, ctx, *, memory_budget="256MB", threads=None, tolerance=0.05, mode: str = "composite",
                 tf=None, value=0, background=(0.0, 0.0, 0.0, 0.0), shading: bool = False,
                 light=(0.3, 0.7, 0.3, 20.0), center=None) -> None:
        self.loader = open_point_loader(source)
        tolerance_pixels(tolerance, (1000, 1000))  # a clear error before any thread starts
        lo, hi = self.loader.world_box()
        c = (lo + hi) / 2.0 if center is None else np.clip(np.asarray(center, np.float64), lo, hi)
        self.clip_texture = ClipTexture(self.loader, memory_budget, threads, center=self.loader.to_paging(c))
        try:
            self.action = SplatRenderAction(ctx, self.clip_texture, tolerance=tolerance, mode=mode, value=value,
                                             background=background, shading=shading, light=light)
        except BaseException:
            self.clip_texture.close()
            raise
        vr = self.loader.meta.value_ranges[self.action.value]
        if tf is None:
            tf = "viridis"
        self.tf = TransferFunction.preset(tf, value_range=vr) if isinstance(tf, str) else tf
        self._center = None

    # -- settings -------------------------------------------------------------------------------
    @property
    def tolerance(self):
        return self.action.tolerance

    @property
    def mode(self) -> str:
        return self.action.mode

    @property
    def value_range(self) -> tuple[float, float]:
        return tuple(self.loader.meta.value_ranges[self.action.value])

    def update(self, *, tolerance=None, mode: str | None = None, tf=None, shading: bool | None = None) -> None:
        """Change the tolerance, MIP/composite, the transfer function or lighting (resident nodes are kept)."""
        if tolerance is not None:
            tolerance_pixels(tolerance, (1000, 1000))
            self.action.tolerance = tolerance
        if mode is not None:
            from ..render.modes import modes_with

            if mode not in modes_with("splats"):
                raise ParameterError(f"mode: expected one of {', '.join(modes_with('splats'))}, got {mode!r}")
            self.action.mode = mode
        if shading is not None:
            self.action.shading = bool(shading)
        if tf is not None:
            self.tf = TransferFunction.preset(tf, value_range=self.value_range) if isinstance(tf, str) else tf

    def volume_box(self) -> tuple[np.ndarray, np.ndarray]:
        """World ``(lo, hi)`` of the octree's root cube (what cameras are framed on)."""
        return self.loader.world_box()

    # -- frames ---------------------------------------------------------------------------------
    def render(self, camera, center=None, *, wait: bool = False, timeout: float | None = None) -> np.ndarray:
        """One frame ``(h, w, 4)`` uint8 RGBA; ``center`` (world ``(x, y, z)``) moves the centre of interest."""
        if center is not None:
            lo, hi = self.loader.world_box()
            c = np.clip(np.asarray(center, np.float64), lo, hi)
            if self._center is None or not np.array_equal(c, self._center):
                self.clip_texture.set_center(self.loader.to_paging(c))
                self._center = c
        return self.action.render(camera, self.tf, wait=wait, timeout=timeout)

    @property
    def frame_stats(self):
        """The last frame's :class:`~clipvol.render.splat.SplatFrameStats`."""
        return self.action.last_frame_stats

    def close(self) -> None:
        """Release the GL objects, then stop the loader threads."""
        try:
            self.action.close()
        finally:
            self.clip_texture.close()

    def __enter__(self) -> "PointSession":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
