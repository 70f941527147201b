"""One cutting plane of a volume written as files: what ``clipvol slice`` does once its flags are objects.

The plane goes through :class:`~clipvol.app.slice_session.SliceSession`. Why the command's promises
live here and not in the command: a slice promises outputs that are what was asked and complete,
so a slice some of whose bricks failed, or one the budgets could not complete, is refused (exit 3,
:mod:`clipvol.app.partial`) unless ``allow_partial``; pixels outside a cut (crop box, clip planes)
are transparent in the PNG and NaN in the values; each output is written to a temporary name and
renamed when complete (:func:`clipvol.app.outputs.write_atomic`); the PNG of a patient-frame store
gets its R/L, A/P, S/I edge letters; and the slice's statistics are told in lines on ``log``.
"""

from __future__ import annotations

import json
import sys
from typing import Callable

import numpy as np

from ..errors import ParameterError
from ..scene.slice_exact import DEFAULT_TOL
from .deadline import CommandDeadline
from .outputs import write_atomic

__all__ = ["slice_to_files"]


def _stderr(line: str) -> None:
    print(line, file=sys.stderr)


def slice_to_files(loader, plane, params, *, out=None, npy=None, stats=None, size=None, pixel_size=None,
                   tf=None, window=None, center=None, poi=None, memory_budget, threads=None, wait: bool = True,
                   timeout: float | None = None, deadline: CommandDeadline | None = None,
                   allow_partial: bool = False, labels: bool = True, log: Callable[[str], None] = _stderr,
                   command: str = "slice", exact_tol: float | None = DEFAULT_TOL):
    """Draw ``plane`` of ``loader`` and write the PNG ``out``, the float32 values ``npy`` and the
    statistics JSON ``stats`` (each None: not written; at least one is asked).

    Parameters
    ----------
    loader
        The volume's loader; its ``frame``, if any, names the image's edges (R/L, A/P, S/I).
    plane : Plane
        The cutting plane (render frame); refused when it misses the volume.
    params : RenderParams
        ``policy="plane"``; ``focus`` a point of interest (full resolution near it), ``level`` one
        level everywhere, ``shape`` a cut.
    size : (w, h), optional
        Pixels (default: the plane's cut through the volume).
    pixel_size : float, optional
        World units per pixel (default: the level-0 voxel).
    tf, window
        A transfer function colouring the values, or a grey window ``(centre, width)`` (default:
        the value range).
    center : 3 floats, optional
        The clip-texture's centre of interest (default: the plane's origin), clamped into the volume.
    poi : 3 floats, optional
        The point of interest as the user gave it (world frame), recorded in ``stats``.
    memory_budget, threads, wait, timeout, deadline, allow_partial, log
        As for :func:`clipvol.app.render_png.render_to_png`.
    labels : bool
        The edge letters on the PNG.
    exact_tol : float or None
        With a point of interest, on a store with summary tables: a coarser brick draws where every
        voxel beneath it stays within this CIELUV Delta E of level 0 under the slice's colours
        (:attr:`~clipvol.render.slice_action.SliceAction.exact_tol`); None: by distance alone.

    Returns
    -------
    SliceStats
        The slice's statistics.
    """
    from ..render import create_context
    from ..render.failures import hatch_failed
    from .partial import settle_failed, settle_unconverged
    from .slice_session import SliceSession

    named = out or npy or stats
    pyr = loader.pyramid
    frame = getattr(loader, "frame", None)  # the source's voxel-to-world affine (NIfTI, DICOM, ...)
    lo, hi = pyr.volume_box()
    if not plane.crosses(lo, hi)[0]:
        raise ParameterError(f"plane: expected a plane that meets the volume {tuple(lo.tolist())}..{tuple(hi.tolist())}, "
                             f"got origin {plane.origin} normal {plane.normal}")
    if params.level is not None and not (0 <= params.level < pyr.num_levels):
        raise ParameterError(f"--level: expected 0..{pyr.num_levels - 1} for this store, got {params.level}")
    edges = None
    if frame is not None:
        from ..scene.orientation import view_labels

        edges = view_labels(frame.affine, plane.right, plane.up, frame.frame)
    centre = np.clip(np.asarray(center if center is not None else plane.origin, dtype=np.float64), lo, hi)
    if deadline is None:
        deadline = CommandDeadline(timeout if wait else None)
    ctx = create_context()
    try:
        with deadline.closing(command) as register, \
                SliceSession(loader, ctx, params, memory_budget=memory_budget, threads=threads,
                             center=centre) as session:
            register(session.clip_texture)
            action, clip = session.action, session.clip_texture
            action.exact_tol = exact_tol
            rgba, values = session.render(plane, size, pixel_size, transfer_function=tf, window=window, wait=wait,
                                          timeout=deadline.left() if wait else timeout)
            st = action.last_stats
            if not st.failed_bricks:  # failed bricks are settled below, with their causes
                settle_unconverged(command, named, converged=st.converged, waited=wait,
                                   selection=action.last_selection, clip=clip,
                                   brick_gpu_bytes=action.cache.brick_texels * action.cache.format.itemsize,
                                   texture_budget=params.texture_budget, timeout=timeout,
                                   allow=allow_partial, unblended=action.last_missing_low)
            cam = action.last_camera
        late = clip.take_reads()  # what the loader threads read after the slice, until they stopped
    finally:
        ctx.release()
    rgba = settle_failed(command, named, st.failed_bricks, rgba,
                         lambda im: hatch_failed(im, cam, pyr, st.failed_bricks, plane=plane), allow_partial,
                         strict=True)
    h, w = values.shape
    if params.shape is not None:  # outside the cut: transparent in the PNG, NaN in the values
        from ..scene.plane import default_pixel_size
        from .slice_session import leave_out_cut

        px = default_pixel_size(pyr, plane) if pixel_size is None else pixel_size
        rgba, values = leave_out_cut(rgba, values, params.shape, plane, px)
    _write_outputs(out, npy, stats, rgba, values, st, plane, poi, params.level, edges,
                   labels and edges is not None and frame.frame == "RAS")
    _log_slice(log, st, late, edges, (w, h))
    return st


def _write_outputs(out, npy, stats, rgba, values, st, plane, poi, level, edges, letters: bool) -> None:
    """The PNG (with the edge letters when ``letters``), the values and the statistics, each whole or absent."""
    if out is not None:
        from PIL import Image

        if letters:
            from .annotate import label_edges

            rgba = label_edges(rgba, edges)
        write_atomic(out, lambda p: Image.fromarray(rgba, "RGBA").save(p, format="PNG"))
    if npy is not None:
        def save_npy(p):
            with open(p, "wb") as f:
                np.save(f, values)
        write_atomic(npy, save_npy)
    if stats is not None:
        h, w = values.shape
        doc = dict(st.as_dict(), size=[w, h], plane=dict(origin=list(plane.origin), normal=list(plane.normal),
                                                         up=list(plane.up)), poi=poi, level=level, edges=edges)

        def save_json(p):
            with open(p, "w") as f:
                f.write(json.dumps(doc, indent=1) + "\n")
        write_atomic(stats, save_json)


def _log_slice(log, st, late, edges, size) -> None:
    """The statistics lines of :func:`slice_to_files`."""
    from ..units import format_bytes

    w, h = size
    levels = ", ".join(f"L{L}: {n}" for L, n in st.tiles_per_level.items()) or "none"
    log(f"slice {w}x{h}: tiles {st.tiles} ({levels}), {st.blended} blended, converged {st.converged}")
    read = "" if st.frame_bytes_read is None else (
        f"; read {format_bytes(st.frame_bytes_read)} from storage for the slice's bricks and "
        f"{format_bytes(st.prefetch_bytes_read + sum((late or {}).values()))} prefetched around them")
    log(f"bricks needed {st.bricks_needed} ({format_bytes(st.bytes_needed)}); loaded {format_bytes(st.bytes_loaded)}{read}; "
        f"uploaded {format_bytes(st.bytes_uploaded)}; total {st.times['total'] * 1000:.1f} ms")
    if edges is not None:
        log("edges: " + ", ".join(f"{k} {v}" for k, v in edges.items()))
