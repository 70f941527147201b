"""Sort-last rendering on Dask: brick groups drawn in worker processes, composited in order.

:class:`DistributedRenderer` cuts the volume into ``n`` convex groups with a kd split
(:func:`clipvol.scene.decompose.kd_split`), and for every frame asks ``n`` Dask tasks to draw one
group each: a task runs in a worker process that holds its own EGL context, clip-texture and
render action over the same store (opened once per process and kept for later frames), and
draws the whole frame's selection clipped to its group's box (the render action's region of
interest), so samples on the constant-distance lattice fall into exactly one group. Each task
returns its float32 target before the background (premultiplied colour; for MIP the raw
maximum). The client composites the partial images in the groups' back-to-front order with the
``(1, 1 - alpha)`` operator (MIP: per-pixel maximum), puts the background under them and
converts to straight RGBA uint8 exactly as the single-process action does. The image equals the
single-process render within 1 LSB per channel (the float32 blending happens per group, and the
front group's opacity cannot stop the rays of the groups behind it early).

This is the database decomposition of Bhaniramka and Demange (2002) §3.3, with Dask instead of
multiple graphics pipes. Workers must be processes (``processes`` or a ``tcp://`` cluster):
every worker needs an EGL context of its own.

References
----------
Bhaniramka, P. and Demange, Y. (2002). OpenGL Volumizer: a toolkit for high quality volume
rendering of large data sets. Proc. IEEE/ACM Symposium on Volume Visualization and Graphics.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import MissingExtraError, ParameterError
from ..scene.decompose import back_to_front, kd_split
from ..scene.geometry import Shape
from ..scene.params import RenderParams

__all__ = ["DistributedRenderer", "SortLastStats", "release_worker_state", "render_path_sort_last"]

# -- worker side --------------------------------------------------------------------------------
_WORKER: dict[Any, Any] = {}


def _worker_action(source, source_kwargs: dict, memory_budget, params: RenderParams):
    """This process's (context, clip-texture, action) for ``source``, made once and kept."""
    key = (str(source), tuple(sorted(source_kwargs.items())), str(memory_budget))
    state = _WORKER.get(key)
    if state is None:
        from ..paging.cliptexture import ClipTexture
        from ..paging.open import open_store
        from ..render import create_context
        from ..render.action import ClipRenderAction

        loader = open_store(source, **source_kwargs)
        ctx = create_context()
        clip = ClipTexture(loader, memory_budget)
        action = ClipRenderAction(ctx, clip, params)
        state = _WORKER[key] = (ctx, clip, action)
    return state


def release_worker_state() -> None:
    """Close this process's actions, clip-textures and contexts (the ``inline`` scheduler's)."""
    while _WORKER:
        _key, (ctx, clip, action) = _WORKER.popitem()
        action.close()
        clip.close()
        ctx.release()


def _render_group(source, source_kwargs, memory_budget, params: RenderParams, camera, tf, box, timeout):
    """Draw one group: returns ``(raw float32 (h, w, 4), the TextureFormat, seconds, converged,
    failed bricks)``; a group whose bricks did not all arrive within ``timeout`` says so, and the
    failed ones are listed (:mod:`clipvol.render.failures`)."""
    t0 = time.perf_counter()
    _ctx, clip, action = _worker_action(source, source_kwargs, memory_budget, params)
    shape = params.shape
    lo, hi = np.asarray(box[0]), np.asarray(box[1])
    if shape is not None and shape.box is not None:
        lo, hi = np.maximum(lo, shape.box[0]), np.minimum(hi, shape.box[1])
    if np.any(hi < lo):  # the region of interest misses this group: nothing to draw
        w, h = camera.size
        from ..render.modes import mode_of

        raw = np.zeros((int(h), int(w), 4), dtype=np.float32)
        raw[...] = mode_of(params.mode).clear  # where no ray wrote (MIP: below any texel)
        return raw, action.cache.format, time.perf_counter() - t0, True, ()
    group_shape = Shape(box=(tuple(lo), tuple(hi)), planes=shape.planes if shape is not None else ())
    action.set_params(replace(params, shape=group_shape, background=(0.0, 0.0, 0.0, 0.0), early_termination=True))
    from ..scene.cut import outside_bricks

    if clip.set_outside(outside_bricks(clip.pyramid, group_shape)):  # only this group's bricks are read
        action.use_clip_texture(clip)  # bricks filled for another group's cut may be on the GPU: empty it
    vlo, vhi = clip.pyramid.volume_box()
    clip.set_center(np.clip((lo + hi) / 2.0, vlo, vhi))
    action.render(camera, tf, wait=True, timeout=timeout)
    st = action.last_frame_stats
    return (np.array(action.last_raw), action.cache.format, time.perf_counter() - t0, bool(st.converged),
            tuple(st.failed_bricks))


# -- client side --------------------------------------------------------------------------------
@dataclass(frozen=True)
class SortLastStats:
    """Times of the last frame: per group (in its worker), the wait for all, the compositing."""

    group_seconds: tuple[float, ...]
    frame_seconds: float
    composite_seconds: float
    order: tuple[int, ...]
    #: every group drew its bricks at their own level (False: some were still loading at the timeout)
    converged: bool = True
    #: the groups' failed bricks (:class:`~clipvol.render.failures.FailedBrick`), each once
    failed_bricks: tuple = ()

    @property
    def unreplaced(self) -> tuple:
        """The failed bricks no verified ancestor stands in for: regions missing from the image."""
        return tuple(f for f in self.failed_bricks if not f.replaced)


def sort_last_modes() -> tuple[str, ...]:
    """The modes whose groups' partial images combine here (``DrawMode.sort_last``: composite "over",
    MIP max; :mod:`clipvol.render.modes`)."""
    from ..render.modes import modes_with

    return modes_with("sort_last")


def _sort_last_mode(params: RenderParams) -> RenderParams:
    """Refuse a mode whose per-group partial images this compositor does not combine."""
    if params.mode not in sort_last_modes():
        raise ParameterError(f"mode: expected one of {', '.join(sort_last_modes())} for sort-last rendering "
                             f"(--workers), got {params.mode!r}")
    return params


class DistributedRenderer:
    """Render frames of ``source`` with ``workers`` Dask worker processes, composited sort-last.

    Parameters
    ----------
    source : str
        A store path or URL, as :func:`clipvol.paging.open.open_store` takes (each worker opens it).
    workers : int
        Number of groups (and of worker processes for ``scheduler="processes"``).
    params : RenderParams, optional
        Render parameters (every group uses them, clipped to its box).
    scheduler : str
        ``"processes"`` (a local cluster of ``workers`` processes), a ``tcp://`` scheduler address,
        or ``"inline"`` (the groups drawn one after the other in this process, without Dask: for
        checking the decomposition and measuring the compositing alone).
    client : distributed.Client, optional
        Use this client (its workers must be processes).
    memory_budget : int or str
        Each worker's clip-texture budget.
    source_kwargs : dict, optional
        Passed to ``open_store`` in the workers (``cache=...`` for a remote store).
    """

    def __init__(self, source, workers: int = 2, params: RenderParams | None = None, *, scheduler: str = "processes",
                 client=None, memory_budget="256MB", source_kwargs: dict | None = None, timeout: float = 120.0) -> None:
        from ..paging.open import open_store

        self.source = str(source)
        self.source_kwargs = dict(source_kwargs or {})
        self.params = _sort_last_mode(params or RenderParams())
        self.memory_budget = memory_budget
        self.timeout = float(timeout)
        self.pyramid = open_store(self.source, **self.source_kwargs).pyramid
        self.params.check_for(self.pyramid)
        self.tree = kd_split(self.pyramid, workers)
        self.groups = {leaf.group: (leaf.lo, leaf.hi) for leaf in self.tree.leaves()}
        self._cluster = None
        self._own_client = client is None
        self._inline = client is None and scheduler == "inline"
        if self._inline:
            client = None
        elif client is None:
            try:
                from distributed import Client, LocalCluster
            except ImportError:
                raise MissingExtraError("--workers: sort-last rendering on Dask needs the dask extra: "
                                        "pip install 'clipvol[dask]'") from None
            if scheduler == "processes":
                self._cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                             host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                             worker_dashboard_address="127.0.0.1:0")
                client = Client(self._cluster)
            elif "://" in scheduler:
                try:
                    client = Client(scheduler, timeout="10s")
                except (OSError, TimeoutError) as e:
                    raise ParameterError(f"--scheduler: cannot reach the Dask scheduler at {scheduler} ({type(e).__name__})") from None
            else:
                raise ParameterError(f"--scheduler: expected processes, inline or tcp://HOST:PORT for rendering, "
                                     f"got {scheduler!r}")
        self.client = client
        self.last_stats: SortLastStats | None = None

    def render(self, camera, tf) -> np.ndarray:
        """One converged frame: ``(h, w, 4)`` straight RGBA uint8, as :meth:`ClipRenderAction.render`."""
        from ..render.paths.setup import premultiplied_to_uint8
        from ..render.modes import mode_of

        t0 = time.perf_counter()
        order = back_to_front(self.tree, camera)
        args = (self.source, self.source_kwargs, self.memory_budget, self.params, camera, tf)
        if self._inline:
            results = {g: _render_group(*args, self.groups[g], self.timeout) for g in self.groups}
        else:
            futs = {g: self.client.submit(_render_group, *args, self.groups[g], self.timeout, pure=False) for g in self.groups}
            results = dict(zip(futs, self.client.gather(list(futs.values()))))
        t1 = time.perf_counter()
        p = self.params
        prem = mode_of(p.mode).sort_last_image([results[g][0] for g in order], results[order[0]][1], tf,
                                               self.pyramid.value_range)
        alpha = prem[..., 3]
        r, g_, b, ba = p.background
        prem = prem + (1.0 - alpha[..., None]) * np.array([r * ba, g_ * ba, b * ba, ba])
        image = premultiplied_to_uint8(prem)
        t2 = time.perf_counter()
        failed = {(f.level, f.index): f for g in sorted(results) for f in results[g][4]}
        self.last_stats = SortLastStats(tuple(results[g][2] for g in sorted(results)), t2 - t0, t2 - t1, tuple(order),
                                        all(results[g][3] for g in results), tuple(failed.values()))
        return image

    def set_params(self, params: RenderParams) -> None:
        """Render the next frames with ``params`` (the workers pick them up with the next task)."""
        self.params = _sort_last_mode(params).check_for(self.pyramid)

    def close(self) -> None:
        if self._inline:
            release_worker_state()
        if self._own_client and self.client is not None:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()
        self.client = self._cluster = None

    def __enter__(self) -> "DistributedRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def render_path_sort_last(source, out, *, workers: int = 2, scheduler: str = "processes", path: str = "orbit",
                          frames: int = 36, size=(256, 256), params: RenderParams | None = None, tf="viridis",
                          memory_budget="256MB", source_kwargs: dict | None = None, timeout: float = 120.0,
                          progress=None, on_failed=None, path_kwargs: dict | None = None, frame=None,
                          labels: bool = True) -> list[dict]:
    """An offscreen flythrough drawn sort-last: PNG frames ``frame_0000.png``... and ``frames.csv``
    (frame time, each group's time in its worker, compositing time, visibility order) in ``out``.

    Every frame is converged (each worker waits for its group's bricks). ``on_failed`` is
    :func:`clipvol.app.flythrough.render_path`'s (a frame with failed bricks). ``path_kwargs`` go to
    :func:`clipvol.scene.paths.make_path` (:func:`clipvol.scene.views.patient_path` gives a
    patient-frame store's: head up, from the front); ``frame`` is the store's world frame, through
    which every frame is presented as any offscreen frame is (:func:`clipvol.app.annotate.present`:
    un-mirrored, and lettered unless ``labels`` is False). Returns the CSV rows.
    """
    import csv
    from pathlib import Path

    from ..scene.paths import make_path
    from ..scene.transfer import TransferFunction
    from .annotate import present
    from .flythrough import save_png

    out = Path(out)
    if out.suffix.lower() == ".gif" or (out.exists() and not out.is_dir()):
        raise ParameterError(f"out: expected a directory for sort-last frames, got {out}")
    out.mkdir(parents=True, exist_ok=True)
    tfn = TransferFunction.preset(tf) if isinstance(tf, str) else tf
    rows: list[dict] = []
    with DistributedRenderer(source, workers, params, scheduler=scheduler, memory_budget=memory_budget,
                             source_kwargs=source_kwargs, timeout=timeout) as dr, \
            open(out / "frames.csv", "w", newline="") as fh:
        cols = ["frame", "frame_s", "composite_s", "converged", "order"] + [f"group{g}_s" for g in range(workers)]
        writer = csv.DictWriter(fh, fieldnames=cols)
        writer.writeheader()
        for k, (cam, _coi) in enumerate(make_path(path, dr.pyramid, frames, size=size, **(path_kwargs or {}))):
            img = dr.render(cam, tfn)
            st = dr.last_stats
            if on_failed is not None and st.failed_bricks:
                img = on_failed(k, cam, img, st.failed_bricks)
            save_png(present(img, cam, frame, labels=labels), out / f"frame_{k:04d}.png")
            row = {"frame": k, "frame_s": round(st.frame_seconds, 6), "composite_s": round(st.composite_seconds, 6),
                   "converged": st.converged,
                   "order": " ".join(map(str, st.order)),
                   **{f"group{g}_s": round(t, 6) for g, t in enumerate(st.group_seconds)}}
            writer.writerow(row)
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows
