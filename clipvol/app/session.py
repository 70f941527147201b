"""One data source on screen: a loader, its clip-texture and a clip render action, as one object.

The window, the offscreen path renderer (``clipvol view --offscreen``), the report and the demo
all do the same per frame: move the centre of interest, render without waiting (or converged),
read the statistics. :class:`RenderSession` holds the three parts, applies setting changes (a
change of LOD threshold, mode or selection rebuilds only the render action; the clip-texture and
its resident bricks are kept), and closes everything in the right order (render action, then
loader threads).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace

import numpy as np

from ..errors import ParameterError

__all__ = ["RenderSettings", "RenderSession", "open_loader"]

#: action attributes the render action reads per frame (changed in place by RenderSession.update)
_LIVE = ("lod_threshold", "mode", "selection", "level", "texels_per_frame", "max_texels_drawn", "step")


def open_loader(source, **kwargs):
    """A loader for ``source``: a store path, ``procedural:...`` URL, ``.npy`` path, or a loader."""
    if hasattr(source, "read_brick") and hasattr(source, "pyramid"):
        return source
    from ..paging.open import open_store

    return open_store(source, **kwargs)


@dataclass(frozen=True, slots=True)
class RenderSettings:
    """What the render action is asked to do (everything the viewer's keys can change)."""

    lod_threshold: float = 1.0
    selection: str = "multiresolution"
    level: int | None = None
    mode: str = "composite"
    tf: object = "viridis"  # a preset name or a TransferFunction
    step: float = 0.5
    texels_per_frame: int | None = None
    max_texels_drawn: int | None = None

    def __post_init__(self) -> None:
        for name in ("lod_threshold", "step"):
            try:
                object.__setattr__(self, name, float(getattr(self, name)))
            except (TypeError, ValueError):
                raise ParameterError(f"{name}: expected a number, got {getattr(self, name)!r}") from None
        for name in ("texels_per_frame", "max_texels_drawn"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1):
                raise ParameterError(f"{name}: expected None or an integer >= 1, got {v!r}")
        if not (np.isfinite(self.lod_threshold) and self.lod_threshold > 0):
            raise ParameterError(f"lod_threshold: expected a finite value > 0 pixels, got {self.lod_threshold!r}")
        if self.selection not in ("multiresolution", "roaming", "fixed"):
            raise ParameterError(f"selection: expected multiresolution, roaming or fixed, got {self.selection!r}")
        if self.mode not in ("composite", "mip"):
            raise ParameterError(f"mode: expected composite or mip, got {self.mode!r}")
        if self.selection == "fixed" and self.level is None:
            object.__setattr__(self, "level", 0)
        if self.level is not None and int(self.level) < 0:
            raise ParameterError(f"level: expected a level >= 0, got {self.level!r}")
        if not isinstance(self.tf, str) and not hasattr(self.tf, "table"):
            raise ParameterError(f"tf: expected a preset name or a TransferFunction, got {self.tf!r}")
        if not (np.isfinite(self.step) and self.step > 0):
            raise ParameterError(f"step: expected a finite value > 0, got {self.step!r}")

    def action_kwargs(self) -> dict:
        return dict(
            lod_threshold=self.lod_threshold,
            mode=self.mode,
            selection=self.selection,
            level=self.level if self.selection == "fixed" else None,
            texels_per_frame=self.texels_per_frame,
            max_texels_drawn=self.max_texels_drawn,
            step=self.step,
        )


class RenderSession:
    """A loader + :class:`~clipvol.paging.cliptexture.ClipTexture` + :class:`~clipvol.render.action.ClipRenderAction`.

    Parameters
    ----------
    source : loader, path or URL
        The data (anything :func:`clipvol.paging.open.open_store` opens, or a loader).
    ctx : moderngl.Context
        The GL context to draw with (offscreen EGL or a window's).
    memory_budget, texture_budget : int or str
        Budgets of the clip-texture (main memory) and of the GPU brick cache.
    threads : int, optional
        Loader threads (default: number of cores).
    settings : RenderSettings, optional
        Initial render settings.
    background : tuple
        RGBA background of the frames (0..1).
    """

    def __init__(self, source, ctx, *, memory_budget="256MB", texture_budget="256MB", threads=None,
                 settings: RenderSettings | None = None, background=(0.0, 0.0, 0.0, 0.0)) -> None:
        from ..paging.cliptexture import ClipTexture

        self.loader = open_loader(source)
        self.pyramid = self.loader.pyramid
        self.ctx = ctx
        self.texture_budget = texture_budget
        self.background = tuple(background)
        self.settings = settings or RenderSettings()
        self.clip_texture = ClipTexture(self.loader, memory_budget, threads)
        self.action = None
        self._tf = None
        self._tf_name = None
        self._center = None
        try:
            self._build_action()
        except BaseException:
            self.clip_texture.close()
            raise

    # -- settings -----------------------------------------------------------------------------
    def _build_action(self) -> None:
        from ..render.action import ClipRenderAction

        if self.action is not None:
            self.action.close()
            self.action = None
        self.action = ClipRenderAction(
            self.ctx, self.clip_texture, texture_budget=self.texture_budget, background=self.background,
            **self.settings.action_kwargs(),
        )

    def update(self, **changes) -> bool:
        """Change settings (``lod_threshold=2``, ``mode='mip'``, ...); returns whether anything changed.

        A change of the transfer function needs nothing rebuilt; the others are applied to the live
        render action (it reads them per frame), so its GPU cache and the clip-texture's resident
        bricks are kept. Settings are validated first (:class:`RenderSettings`).
        """
        names = {f.name for f in fields(RenderSettings)}
        bad = set(changes) - names
        if bad:
            raise ParameterError(f"update: unknown setting(s) {', '.join(sorted(bad))}; expected {', '.join(sorted(names))}")
        new = replace(self.settings, **changes)
        if new.level is not None and new.level >= self.pyramid.num_levels:
            raise ParameterError(f"level: expected 0..{self.pyramid.num_levels - 1}, got {new.level}")
        if new == self.settings:
            return False
        old, self.settings = self.settings, new
        if replace(old, tf=new.tf) == new:
            return True
        # the action reads these per frame: change them in place and keep its GPU cache
        a = self.action
        kw = new.action_kwargs()
        for n in _LIVE:
            setattr(a, n, kw[n])
        if a.texels_per_frame is not None:  # at least one brick per frame, as the action's constructor does
            a.texels_per_frame = max(int(a.texels_per_frame), int(np.prod(self.pyramid.brick_shape)))
        return True

    @property
    def transfer_function(self):
        """The :class:`~clipvol.scene.transfer.TransferFunction` of the current ``tf`` preset."""
        tf = self.settings.tf
        if not isinstance(tf, str):
            return tf
        if self._tf_name != tf:
            from ..scene.transfer import TransferFunction

            if tf == "auto":  # a window on the data's foreground, from its histogram
                from ..scene.auto_tf import auto_transfer_function

                self._tf = auto_transfer_function(self.loader)
            else:
                self._tf = TransferFunction.preset(tf)
            self._tf_name = tf
        return self._tf

    # -- per frame ----------------------------------------------------------------------------
    def set_center(self, xyz) -> None:
        """Move the clip-texture's centre of interest (clamped into the volume box) if it moved."""
        lo, hi = self.pyramid.volume_box()
        c = np.clip(np.asarray(xyz, dtype=np.float64), lo, hi)
        if self._center is None or not np.array_equal(c, self._center):
            self.clip_texture.set_center(c)
            self._center = c

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

    def close(self) -> None:
        """Release the render action's GL resources, then stop the loader threads."""
        try:
            if self.action is not None:
                self.action.close()
                self.action = None
        finally:
            self.clip_texture.close()

    def __enter__(self) -> "RenderSession":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
