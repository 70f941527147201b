"""Time-varying volumes: play a series of time steps, prefetching the next under the same budget.

OpenGL Volumizer pages time-varying data through the same clip-texture machinery as space
(Bhaniramka & Demange 2002, section 3.4). A series here is a list of loaders of one brick geometry,
one per time step (``[open_store(path, t=k) for k in range(n)]`` for an OME-Zarr with a ``t``
axis). :class:`TimeSeriesPlayer` splits the memory budget between two clip-textures: the one being
drawn, and the next step's, which its loader threads fill around the same centre of interest
(coarse levels first, as any clip-texture) while the current step is on screen. Stepping swaps
them and starts prefetching the step after; with ``prefetch=False`` the whole budget goes to the
current step and each step loads from scratch (the baseline of ``tools/bench/bench_timeseries.py``).
The render action is kept across steps (its GPU cache is emptied: the data changed).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ParameterError
from ..paging.cliptexture import ClipTexture
from ..render.action import ClipRenderAction
from ..scene.params import RenderParams
from ..units import parse_bytes
from .session import RenderSession, _check_tf

__all__ = ["TimeSeriesPlayer", "SeriesSession", "series_loaders"]


def series_loaders(loader) -> list | None:
    """The loaders of every step of the time series ``loader`` reads one step of (a store or URL
    with a ``t`` axis: ``loader.axes``), or None when it has no ``t`` axis of more than one step.
    What a whole-series default needs (:func:`clipvol.scene.auto_tf.series_histogram`)."""
    axes = tuple(getattr(loader, "axes", ()) or ())
    if "t" not in axes:
        return None
    n = int(loader.lead_shape[axes.index("t")])
    where = getattr(loader, "set_root", None) or getattr(loader, "url", None) or getattr(loader, "path", None)
    if n < 2 or where is None:
        return None
    from ..paging.open import open_store

    others = {a: int(v) for a, v in zip(axes, getattr(loader, "_select", ()) or ()) if a != "t"}
    return [open_store(str(where), t=k, **others) for k in range(n)]


class TimeSeriesPlayer:
    """Render time step after time step of ``loaders`` with one render action.

    Parameters
    ----------
    loaders : sequence of Loader
        One per time step, all with the same levels, brick shape and dtype.
    ctx : moderngl.Context
    memory_budget : int or str
        Main memory for bricks, for the current step and the prefetched one together.
    params : RenderParams, optional
        Render parameters (texture budget included).
    prefetch : bool
        Fill the next step's clip-texture while the current one is drawn.
    threads : int, optional
        Loader threads per clip-texture.
    """

    def __init__(self, loaders: Sequence, ctx, *, memory_budget="256MB", params: RenderParams | None = None,
                 prefetch: bool = True, threads: int | None = None) -> None:
        self.loaders = list(loaders)
        if not self.loaders:
            raise ParameterError("loaders: expected at least one time step, got none")
        first = self.loaders[0].pyramid
        for k, ld in enumerate(self.loaders[1:], start=1):
            p = ld.pyramid
            if p.brick_shape != first.brick_shape or [lv.shape for lv in p.levels] != [lv.shape for lv in first.levels] \
                    or p.dtype != first.dtype:
                raise ParameterError(f"loaders[{k}]: expected the levels, brick shape and dtype of time step 0, got "
                                     f"levels {[lv.shape for lv in p.levels]} brick {p.brick_shape} {p.dtype}")
        self.prefetch = bool(prefetch) and len(self.loaders) > 1
        budget = parse_bytes(memory_budget, "memory_budget")
        self._part = budget // 2 if self.prefetch else budget
        self.memory_budget = budget
        self._threads = threads
        self.step = 0
        self._center = None
        from ..scene.cut import outside_bricks

        #: bricks every step's clip-texture leaves unread (the cut, see ClipTexture.set_outside)
        self.outside = outside_bricks(first, params.shape if params is not None else None)
        self.current = ClipTexture(self.loaders[0], self._part, threads, outside=self.outside)
        self.next: ClipTexture | None = None
        try:
            self.action = ClipRenderAction(ctx, self.current, params)
        except BaseException:
            self.current.close()
            raise
        self._start_prefetch()

    def __len__(self) -> int:
        return len(self.loaders)

    def _start_prefetch(self) -> None:
        if not self.prefetch:
            return
        k = (self.step + 1) % len(self.loaders)
        self.next = ClipTexture(self.loaders[k], self._part, self._threads,
                                center=self._center if self._center is not None else None, outside=self.outside)

    def set_center(self, xyz) -> None:
        """Move the centre of interest of the current and the prefetched step."""
        self._center = np.asarray(xyz, dtype=np.float64)
        for ct in (self.current, self.next):
            if ct is not None:
                ct.set_center(self._center)

    def go_to(self, step: int) -> None:
        """Show time step ``step`` from the next frame on (the prefetched one if it is next)."""
        step = int(step) % len(self.loaders)
        if step == self.step:
            return
        if self.next is not None and step == (self.step + 1) % len(self.loaders):
            old, self.current, self.next = self.current, self.next, None
        else:
            old = self.current
            if self.next is not None:
                self.next.close()
                self.next = None
            self.current = ClipTexture(self.loaders[step], self._part, self._threads, center=self._center,
                                       outside=self.outside)
        self.action.use_clip_texture(self.current)
        old.close()
        self.step = step
        self._start_prefetch()

    def advance(self) -> None:
        """Go to the next time step (wrapping around)."""
        self.go_to(self.step + 1)

    def render(self, camera, transfer_function, *, wait: bool = False, timeout: float | None = None) -> np.ndarray:
        """One frame of the current step (see :meth:`ClipRenderAction.render`)."""
        return self.action.render(camera, transfer_function, wait=wait, timeout=timeout)

    @property
    def resident_bytes(self) -> int:
        """Bricks held in main memory by the current and the prefetched step together."""
        return sum(ct.stats.resident_bytes for ct in (self.current, self.next) if ct is not None)

    @property
    def prefetch_state(self) -> str:
        """``"ready"``, ``"loading"`` or ``"off"``: the next step's clip-texture."""
        if self.next is None:
            return "off"
        return "ready" if self.next.stats.queued == 0 and self.next.stats.loading == 0 else "loading"

    def close(self) -> None:
        try:
            self.action.close()
        finally:
            for ct in (self.current, self.next):
                if ct is not None:
                    ct.close()

    def __enter__(self) -> "TimeSeriesPlayer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SeriesSession(RenderSession):
    """A :class:`~clipvol.app.session.RenderSession` over a time series: what the viewer holds to
    play one (:mod:`clipvol.viewer.playback`). Its ``clip_texture`` and ``action`` are those of the
    current step of one :class:`TimeSeriesPlayer` (the next step prefetched under the same budget);
    :meth:`go_to` changes the step. Parameters as :class:`RenderSession`, with ``loaders`` (one per
    time step) for ``source``; ``prefetch`` as :class:`TimeSeriesPlayer`.
    """

    def __init__(self, loaders, ctx, *, memory_budget="256MB", threads=None, params: RenderParams | None = None,
                 tf="viridis", texture_budget=None, background=None, prefetch: bool = True) -> None:
        over = {k: v for k, v in (("texture_budget", texture_budget), ("background", background)) if v is not None}
        self.params = RenderParams.from_kwargs(params, **over)
        self.tf = _check_tf(tf)
        self.player = TimeSeriesPlayer(loaders, ctx, memory_budget=memory_budget, params=self.params,
                                       prefetch=prefetch, threads=threads)
        self.loader = self.player.loaders[0]
        self.pyramid = self.loader.pyramid
        self.ctx = ctx
        self._tf = None
        self._tf_name = None
        self._center = None

    @property
    def clip_texture(self):
        return self.player.current

    @property
    def action(self):
        return self.player.action

    @property
    def step(self) -> int:
        """The time step shown."""
        return self.player.step

    def go_to(self, step: int) -> None:
        """Show time step ``step`` from the next frame on."""
        self.player.go_to(step)
        self.loader = self.player.loaders[self.player.step]
        if self._center is not None:
            self.player.set_center(self._center)

    def _move_center(self, c: np.ndarray) -> None:
        self.player.set_center(c)  # the current step's clip-texture and the prefetched one

    def _set_outside(self, outside) -> int:
        """The cut's unread bricks for every step: the current, the prefetched and those to come."""
        self.player.outside = outside
        if self.player.next is not None:
            self.player.next.set_outside(outside)
        return self.player.current.set_outside(outside)

    def close(self) -> None:
        self.player.close()

