"""One volume cut by planes: a loader, its clip-texture and a slice action, as one object.

The cutting-plane counterpart of :class:`clipvol.app.session.RenderSession` (LaMar, Duchaineau,
Hamann & Joy, "Multiresolution techniques for interactive texture-based rendering of arbitrarily
oriented cutting planes", 2000). ``clipvol slice`` draws one plane through it; a front end that
shows planes only (no ray cast beside them) draws many. The viewer's slice panels and the server
instead put a :class:`~clipvol.render.slice_action.SliceAction` on the volume session's own
clip-texture, because they show both.

Why a session of its own rather than a ray-cast session with a slice action on its side: a ray-cast
session makes a render action and its GPU brick cache, which a slice never draws with, and starts
its loader threads around the volume's centre; a plane asks for a thin slab only, so this session's
clip-texture starts with an empty region (``Region.empty``) and reads nothing until the first plane
hands it its slab.
"""

from __future__ import annotations

import numpy as np

from ..paging.cliptexture import ClipTexture
from ..paging.region import Region
from ..render.slice_action import SliceAction
from ..scene.params import RenderParams
from .session import ActionSession, open_loader

__all__ = ["SliceSession", "leave_out_cut"]


def leave_out_cut(rgba: np.ndarray, values: np.ndarray | None, shape, plane, pixel_size: float):
    """``rgba`` and ``values`` of a slice with the pixels outside a cut (crop box, clip planes) left
    out: transparent in the image, NaN in the values. ``shape`` None: returned as they are.

    A slice reads and draws its plane whole; the cut is applied to its pixels afterwards (a plane
    is cheap to draw, and one rule then serves ``clipvol slice``, the server and the viewer).
    """
    if shape is None:
        return rgba, values
    h, w = rgba.shape[:2]
    outside = ~shape.contains(plane.pixel_points((w, h), pixel_size))
    rgba = rgba.copy()
    rgba[outside] = 0
    if values is not None:
        values = values.copy()
        values[outside] = np.nan
    return rgba, values


class SliceSession(ActionSession):
    """A loader + :class:`~clipvol.paging.cliptexture.ClipTexture` + :class:`~clipvol.render.slice_action.SliceAction`.

    Parameters
    ----------
    source : loader, path or URL
        The volume (anything :func:`clipvol.app.session.open_loader` opens, or a loader).
    ctx : moderngl.Context
        The GL context to draw with.
    params : RenderParams
        The slice's parameters (``policy="plane"``, ``focus`` a point of interest, ``shape`` a cut,
        ``level``, ``texture_budget``).
    memory_budget : int or str
        Budget of the clip-texture (main memory).
    threads : int, optional
        Loader threads (default: number of cores).
    center : 3 floats, optional
        The clip-texture's centre of interest (render frame): the point of interest or a point of
        the first plane.
    """

    def __init__(self, source, ctx, params: RenderParams, *, memory_budget="256MB", threads=None,
                 center=None) -> None:
        from ..scene.cut import outside_bricks

        self.loader = open_loader(source)
        self.pyramid = self.loader.pyramid
        self.params = params
        self.ctx = ctx
        self.clip_texture = ClipTexture(self.loader, memory_budget, threads, center=center,
                                        region=Region.empty(self.pyramid.num_levels),
                                        outside=outside_bricks(self.pyramid, params.shape))
        try:
            self.action = SliceAction(ctx, self.clip_texture, params)
        except BaseException:
            self.clip_texture.close()
            raise

    def render(self, plane, size=None, pixel_size: float | None = None, *, transfer_function=None, window=None,
               wait: bool = False, timeout: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Draw ``plane``: ``(rgba, values)``, ``(h, w, 4)`` uint8 and ``(h, w)`` float32 (NaN
        outside the volume); see :meth:`SliceAction.render <clipvol.render.slice_action.SliceAction.render>`."""
        return self.action.render(plane, size, pixel_size, transfer_function=transfer_function, window=window,
                                  wait=wait, timeout=timeout, return_values=True)

    @property
    def stats(self):
        """The last slice's :class:`~clipvol.render.slice_action.SliceStats`."""
        return self.action.last_stats
