"""One frame written to a PNG: what ``clipvol render`` does once its flags are objects.

The frame goes through :class:`~clipvol.app.session.RenderSession` (or, with ``workers``, through
:class:`~clipvol.app.sortlast.DistributedRenderer`), like the viewer's, the notebook's and the
report's. Why the command's promises live here and not in the command: a one-shot frame promises
an image that is what was asked, so a frame some of whose bricks failed, or one the memory,
texture or time budget could not complete, is refused (exit 3, :mod:`clipvol.app.partial`) unless
``allow_partial``; the whole command keeps one deadline (:class:`~clipvol.app.deadline.CommandDeadline`);
the image gets its patient-frame edge letters (:func:`clipvol.app.annotate.present`); and the
frame's statistics (bricks per level, uploads, texture bytes, bytes read, time per stage) are told
in lines on ``log``. Any front end that writes a still gets the same behaviour by calling
:func:`render_to_png`. A point store's frame goes through its own session
(:class:`~clipvol.app.point_session.PointSession`) in :func:`render_points_to_png`.
"""

from __future__ import annotations

import sys
from typing import Callable

import numpy as np

from ..errors import ParameterError
from .deadline import CommandDeadline

__all__ = ["render_to_png", "render_sort_last_to_png", "render_points_to_png"]


def _stderr(line: str) -> None:
    print(line, file=sys.stderr)


def _save_png(image: np.ndarray, camera, frame, out, labels: bool) -> None:
    from PIL import Image

    from .annotate import present

    Image.fromarray(present(image, camera, frame, labels=labels), "RGBA").save(out)


def render_to_png(loader, out, camera, params, tf, *, memory_budget, threads=None, wait: bool = True,
                  timeout: float | None = None, deadline: CommandDeadline | None = None, allow_partial: bool = False,
                  labels: bool = True, log: Callable[[str], None] = _stderr, command: str = "render"):
    """Render one frame of ``loader`` seen by ``camera`` and write it to the PNG ``out``.

    Parameters
    ----------
    loader
        The volume's loader (a channel set, a loader with hidden labels, ...): its ``frame``, if any,
        puts the R/L, A/P, S/I letters at the image's edges.
    out : path
        The PNG written (nothing is written when the frame is refused).
    camera : Camera
        The view; its target, clamped into the volume, is the clip-texture's first centre of interest.
    params : RenderParams
        Checked against the loader's pyramid.
    tf : TransferFunction
    memory_budget, threads
        The clip-texture's budget and loader threads.
    wait : bool
        Converge: wait until every brick the view wants is drawn at its own level (``False``: one
        pass over what is resident).
    timeout : float, optional
        Seconds; without ``wait`` the frame's own wait, with it the bound of ``deadline``.
    deadline : CommandDeadline, optional
        The whole command's deadline, taken when it started (default: from now, ``timeout``).
    allow_partial : bool
        Write a frame with failed bricks (hatched) or one not complete at the level asked, with a
        warning, instead of refusing it.
    labels : bool
        The patient-frame edge letters.
    log : callable
        Where the statistics lines go (default: stderr).

    Returns
    -------
    FrameStats
        The frame's statistics.

    Raises
    ------
    FrameIncompleteError
        The frame is refused (exit 3 on the command line); nothing is written.
    """
    from ..render import create_context
    from ..render.failures import hatch_failed
    from .partial import settle_failed, settle_unconverged
    from .session import RenderSession

    if deadline is None:
        deadline = CommandDeadline(timeout if wait else None)
    pyr = loader.pyramid
    lo, hi = pyr.volume_box()
    centre = np.clip(np.asarray(camera.center, dtype=np.float64), lo, hi)
    ctx = create_context()
    try:
        with deadline.closing(command) as register, \
                RenderSession(loader, ctx, memory_budget=memory_budget, threads=threads, params=params, tf=tf,
                              center=centre) as session:
            register(session.clip_texture)
            action, clip = session.action, session.clip_texture
            image = session.render(camera, wait=wait, timeout=deadline.left() if wait else timeout)
            st = action.last_frame_stats
            overlay_levels = action.overlays.levels()
            unread = clip.stats.empty_skipped
            if not st.failed_bricks:  # failed bricks are settled below, with their causes
                settle_unconverged(command, out, converged=st.converged, waited=wait,
                                   selection=action.last_selection, clip=clip, timeout=timeout,
                                   brick_gpu_bytes=action.cache.brick_texels * action.cache.format.itemsize,
                                   texture_budget=params.texture_budget, allow=allow_partial)
            policy = action.last_policy
        late = clip.take_reads()  # what the loader threads read after the frame, until they stopped
    finally:
        ctx.release()
    image = settle_failed(command, out, st.failed_bricks, image,
                          lambda im: hatch_failed(im, camera, pyr, st.failed_bricks), allow_partial, strict=True)
    _save_png(image, camera, getattr(loader, "frame", None), out, labels)
    _log_frame(log, out, camera, params, tf, st, unread, late, policy, overlay_levels)
    return st


def _log_frame(log, out, camera, params, tf, st, unread: int, late, policy, overlay_levels) -> None:
    """The statistics lines of :func:`render_to_png`."""
    from ..units import format_bytes

    levels = ", ".join(f"L{L}: {n}" for L, n in st.bricks_drawn.items()) or "none"
    log(f"wrote {out} ({camera.size[0]}x{camera.size[1]}, {params.mode}, {params.policy}, transfer function "
        f"{tf.name or 'custom'})")
    log(f"bricks drawn {sum(st.bricks_drawn.values())} ({levels}); texels drawn {st.texels_drawn:,}; "
        f"converged {st.converged} after {st.passes} pass(es)")
    if params.shape is not None:
        log(f"cut: {st.counts.get('culled_shape', 0)} bricks outside the crop box / clip planes not drawn; "
            f"{unread} bricks filled without reading (outside the cut, or empty)")
    read = "" if st.frame_bytes_read is None else (
        f"; read {format_bytes(st.frame_bytes_read)} from storage for the frame's bricks and "
        f"{format_bytes(st.prefetch_bytes_read + sum((late or {}).values()))} prefetched around them")
    log(f"uploaded {format_bytes(st.bytes_uploaded)} in {st.bricks_uploaded} bricks; textures "
        f"{format_bytes(st.texture_bytes)} of {format_bytes(st.texture_budget)}{read}")
    if params.policy == "image":
        est = getattr(policy, "estimated_error", float("nan"))
        budget = "" if params.max_error is None else f", error budget {100 * params.max_error:g} %"
        sampled = " (of the cut; adaptive image sampling adds an error of its own, not estimated)" \
            if params.refine_tolerance > 0 and params.mode == "composite" else ""
        log(f"image policy: block budget {params.block_budget or 'none'}{budget}, {st.bricks_distinct} bricks drawn, "
            f"estimated {100 * est:.1f} % of pixels dE>=6 against the converged picture{sampled}")
    if overlay_levels:
        log("overlays: " + "; ".join(f"{name} (level {L})" for name, L in overlay_levels.items()))
    log("time: " + ", ".join(f"{k} {v * 1000:.1f} ms" for k, v in st.times.items()))


def render_sort_last_to_png(source, out, camera, params, tf, *, workers: int, scheduler: str = "processes",
                            memory_budget, timeout: float | None = None, source_kwargs: dict | None = None,
                            frame=None, wait: bool = True, hidden_labels: bool = False,
                            allow_partial: bool = False, labels: bool = True,
                            log: Callable[[str], None] = _stderr, command: str = "render"):
    """:func:`render_to_png` drawn sort-last: ``workers`` spatially disjoint brick groups in Dask
    workers (:class:`~clipvol.app.sortlast.DistributedRenderer`), composited, then written.

    ``source`` is the store's path or URL (each worker opens it with ``source_kwargs``); ``frame``
    the store's patient frame for the edge letters. A frame with overlays, hidden labels or without
    ``wait`` is refused (each worker draws its part of the primary alone, and always converged).

    Returns
    -------
    SortLastStats
    """
    from ..render.failures import hatch_failed
    from .partial import settle_failed
    from .sortlast import DistributedRenderer

    if workers < 1:
        raise ParameterError(f"--workers: expected an integer >= 1, got {workers}")
    if not wait:
        raise ParameterError("--no-wait: sort-last frames are always converged; drop --no-wait or --workers")
    if params.overlays:
        raise ParameterError("--overlay: not available with --workers (each worker draws a part of the primary alone)")
    if hidden_labels:
        raise ParameterError("--hide-labels: not available with --workers (the workers draw the image alone)")
    with DistributedRenderer(source, workers, params, scheduler=scheduler, memory_budget=memory_budget,
                             timeout=timeout, source_kwargs=source_kwargs or {}) as dr:
        image = dr.render(camera, tf)
        st = dr.last_stats
    image = settle_failed(command, out, st.failed_bricks, image,
                          lambda im: hatch_failed(im, camera, dr.pyramid, st.failed_bricks), allow_partial,
                          strict=True)
    _save_png(image, camera, frame, out, labels)
    log(f"wrote {out} ({camera.size[0]}x{camera.size[1]}, {params.mode}, {params.policy}, sort-last over "
        f"{workers} workers)")
    log(f"converged {st.converged}")
    log("time: frame {:.1f} ms, groups {}, compositing {:.1f} ms".format(
        st.frame_seconds * 1000, ", ".join(f"{t * 1000:.1f} ms" for t in st.group_seconds),
        st.composite_seconds * 1000))
    return st


def render_points_to_png(loader, out, camera, tf, *, tolerance, mode: str = "composite",
                         background=(0.0, 0.0, 0.0, 0.0), shading: bool = False, light=(0.3, 0.7, 0.3, 20.0),
                         memory_budget, threads=None, wait: bool = True, timeout: float | None = None,
                         log: Callable[[str], None] = _stderr):
    """One frame of a point store (splats at ``tolerance``, Meredith & Ma 2001) seen by ``camera``,
    written to the PNG ``out``; the clip-texture's first centre of interest is the camera's target.

    Returns
    -------
    SplatFrameStats
    """
    from PIL import Image

    from ..render import create_context
    from .point_session import PointSession

    ctx = create_context()
    try:
        with PointSession(loader, ctx, memory_budget=memory_budget, threads=threads, tolerance=tolerance, mode=mode,
                          tf=tf, background=background, shading=shading, light=light,
                          center=camera.center) as session:
            image = session.render(camera, wait=wait, timeout=timeout)
            st = session.frame_stats
    finally:
        ctx.release()
    Image.fromarray(image, "RGBA").save(out)
    log(f"wrote {out} ({camera.size[0]}x{camera.size[1]}, splats, {mode}, tolerance {st.tolerance_px:.1f} px)")
    log(f"nodes drawn {st.nodes_drawn} ({', '.join(f'd{d}: {n}' for d, n in st.nodes_per_depth.items())}); "
        f"points drawn {st.points_drawn:,}; converged {st.converged}")
    log("time: " + ", ".join(f"{k} {v * 1000:.1f} ms" for k, v in st.times.items()))
    return st
