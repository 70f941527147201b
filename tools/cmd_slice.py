"""Draw a cutting plane of a store: axial, coronal, sagittal or oblique, fine near a point of interest.

The plane is ``--plane z=94`` (an array axis letter and a level-0 voxel index: the array as
stored), ``--axis coronal --index 120`` (for a store with a patient frame the patient's plane, shown
the radiological way: anterior or superior up, the patient's right on the image left; ``--neurological``
puts it on the right), or ``--through x,y,z --normal x,y,z`` (``--up`` sets the image's up). Points
and directions are in the store's world frame, x,y,z (``clipvol info``: patient RAS+ mm for NIfTI and
DICOM), converted by :mod:`clipvol.scene.cut`; only ``--plane`` and ``--index`` are voxel indices.
Without ``--poi`` and ``--level`` the slice is as fine as its pixels need; with ``--poi`` (a world
point, which the plane passes through unless ``--plane``/``--index``/``--through`` place it) it is full
resolution near that point and coarser away from it, balanced and blended so no seam shows
(LaMar, Hamann & Joy, "Multiresolution cutting planes"); ``--level 0`` is full resolution
everywhere. Outputs: a PNG (grey ``--window C,W`` or a ``--tf`` colour map), the float32 values
(``--npy``, NaN outside the volume) and statistics (``--stats``, JSON; with the image edges'
anatomical labels, R/L A/P S/I, when the store records its patient frame). Outputs are written
to a temporary name and renamed when complete.
"""

from __future__ import annotations

import argparse
import math
import sys

from clipvol.errors import ParameterError

from .common_args import add_common_arguments, add_old_spelling, parse_xyz
from .render_args import add_render_arguments, render_params_from_args


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a clipvol store / OME-Zarr directory, procedural:NAME?size=N, a .npy file, or a NIfTI / "
                                  "DICOM folder / FILE.h5:/dataset / MRC input (bricked first into --store)")
    add_common_arguments(p, ("store",))
    g = p.add_argument_group("plane (one of)")
    g.add_argument("--plane", default=None, help="AXIS=INDEX with AXIS z (axial), y (coronal) or x (sagittal), e.g. z=94")
    g.add_argument("--axis", choices=("axial", "coronal", "sagittal"), default=None,
                   help="preset plane: the patient's plane for a store with a patient frame (radiological display: "
                        "axial anterior up, the patient's right on the image left; coronal and sagittal superior up), "
                        "the array's z, y or x plane otherwise")
    g.add_argument("--index", type=float, default=None, help="--axis: level-0 voxel index along the array axis nearest "
                                                             "the plane's normal (default: the middle, or --poi's)")
    g.add_argument("--neurological", action="store_true",
                   help="--axis of a patient-frame store: the patient's right on the image right (default: radiological)")
    g.add_argument("--through", type=parse_xyz, default=None, metavar="X,Y,Z",
                   help="oblique plane: a point x,y,z of it in the store's world frame (what clipvol info prints: "
                        "patient RAS+ mm for NIfTI/DICOM)")
    g.add_argument("--normal", type=parse_xyz, default=None, help="oblique plane: its normal x,y,z (world frame)")
    add_old_spelling(g, "--origin", "--through", " (--origin is where a volume's voxel 0 lies, for brick)", type=parse_xyz)
    add_common_arguments(g, ("up",))
    s = p.add_argument_group("image")
    add_common_arguments(s, ("size",))
    s.add_argument("--pixel-size", type=float, default=None, help="world units per pixel (default: the level-0 voxel)")
    from clipvol.tools.tf_args import add_tf_arguments

    add_tf_arguments(s, ("window", "tf"))
    s.add_argument("--out", "-o", default=None, help="output PNG")
    add_common_arguments(s, ("no_labels",))
    s.add_argument("--npy", default=None, help="write the resampled values (float32, NaN outside the volume)")
    s.add_argument("--stats", default=None, help="write statistics as JSON (bytes_loaded, tiles per level, time)")
    r = p.add_argument_group("resolution")
    r.add_argument("--poi", type=parse_xyz, default=None,
                   help="point of interest x,y,z in the store's world frame: full resolution near it; the plane "
                        "moves through it unless --plane, --index or --through place it")
    add_render_arguments(r, ("level", "distance_factor", "lod_threshold"))
    add_common_arguments(r, ("brick", "memory_budget"))
    add_render_arguments(r, ("texture_budget", "classify"))
    add_common_arguments(r, ("threads", "no_wait", "timeout"))
    add_common_arguments(p, ("remote", "cut", "unverified"))
    add_common_arguments(r, ("allow_partial",))


def plane_from_args(pyramid, args, frame=None):
    """The :class:`~clipvol.scene.plane.Plane` the arguments name (default: the middle axial plane).

    With a patient ``frame`` the ``--axis`` presets (and the default) are the patient's planes in
    the radiological display (``--neurological`` for the other), :func:`clipvol.scene.views.anatomical_plane`.

    Errors name the command-line option (``--plane: index: expected 0..255 ...``)."""
    option = "--plane" if args.plane is not None else "--axis/--index" if args.axis is not None else "--through/--normal/--up"
    try:
        return _plane_from_args(pyramid, args, frame)
    except ParameterError as e:
        text = str(e)
        raise ParameterError(text if text.startswith("--") else f"{option}: {text}") from None


def _plane_from_args(pyramid, args, frame=None):
    from clipvol.scene.plane import AXIS_LETTERS, Plane

    given = [name for name, v in (("--plane", args.plane), ("--axis", args.axis), ("--through/--normal",
             args.through if args.through is not None else args.normal)) if v is not None]
    if len(given) > 1:
        raise ParameterError(f"plane: expected one of --plane, --axis, --through/--normal, got {' and '.join(given)}")
    if args.index is not None and args.axis is None:
        raise ParameterError("--index: expected together with --axis, got --index alone")
    from clipvol.scene.views import anatomical_plane, is_anatomical

    neuro = getattr(args, "neurological", False)
    if neuro and not (is_anatomical(frame) and args.plane is None and args.through is None and args.normal is None):
        raise ParameterError("--neurological: expected an --axis slice (or the default) of a store with a patient frame "
                             "(from NIfTI or DICOM), got " + ("a store without one" if not is_anatomical(frame)
                                                               else "--plane or --through/--normal"))
    if args.plane is not None:
        letter, _, index = args.plane.partition("=")
        if letter.strip().lower() not in AXIS_LETTERS or not index:
            raise ParameterError(f"--plane: expected AXIS=INDEX with AXIS x, y or z, got {args.plane!r}")
        try:
            i = float(index)
        except ValueError:
            raise ParameterError(f"--plane: expected a number after '=', got {args.plane!r}") from None
        return Plane.axis(pyramid, AXIS_LETTERS[letter.strip().lower()], i)
    if args.axis is not None:
        if is_anatomical(frame):
            return anatomical_plane(pyramid, frame, args.axis, args.index, "neurological" if neuro else "radiological")
        return Plane.axis(pyramid, args.axis, args.index)
    if args.through is not None or args.normal is not None:
        if args.through is None or args.normal is None:
            raise ParameterError("--through/--normal: expected both for an oblique plane, got one")
        return _world_plane(pyramid, frame, args.through, args.normal, args.up)
    if is_anatomical(frame):
        return anatomical_plane(pyramid, frame, "axial", None, "neurological" if neuro else "radiological")
    return Plane.axis(pyramid, "axial")


def _world_plane(pyramid, frame, origin, normal, up):
    """The render-frame plane of ``--through``/``--normal``/``--up`` given in the store's world frame.

    The image's right is ``normal x up`` in the world (so a mirrored store, LAS, is not shown
    mirrored); without ``--up`` a patient-frame store takes superior up (anterior for a plane
    facing superior), another store the preset up of the array axis nearest the normal.
    """
    import numpy as np

    from clipvol.scene.cut import direction_to_render, point_to_render
    from clipvol.scene.plane import Plane
    from clipvol.scene.views import is_anatomical

    o = point_to_render(pyramid, frame, origin, "--through")
    n_r = direction_to_render(pyramid, frame, normal, "--normal", normal=True)
    if up is None and not is_anatomical(frame):
        return Plane.through(o, n_r)
    n_w = np.asarray(normal, dtype=np.float64)
    if up is None:
        up = (0.0, 1.0, 0.0) if int(np.argmax(np.abs(n_w))) == 2 else (0.0, 0.0, 1.0)
    u_w = np.asarray(up, dtype=np.float64)
    r_w = np.cross(n_w, u_w)
    if not np.linalg.norm(r_w) > 1e-9 * np.linalg.norm(n_w) * max(1.0, float(np.linalg.norm(u_w))):
        raise ParameterError(f"--up: expected a vector not parallel to the normal {tuple(n_w.tolist())}, got {tuple(u_w.tolist())}")
    u_r = direction_to_render(pyramid, frame, u_w, "--up")
    r_r = direction_to_render(pyramid, frame, r_w, "--up")
    n = np.cross(u_r, r_r)  # so that Plane's right = normal x up is the world's right
    return Plane(tuple(o.tolist()), tuple((n / np.linalg.norm(n)).tolist()), tuple(u_r.tolist()))


def _write_atomic(path: str, write) -> None:
    import os

    tmp = f"{path}.partial"
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def run(args) -> int:
    import json

    import numpy as np
    from PIL import Image

    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.paging.region import Region
    from clipvol.render import create_context
    from clipvol.render.slice_action import SliceAction
    from clipvol.scene.transfer import TransferFunction
    from clipvol.units import format_bytes

    if args.out is None and args.npy is None and args.stats is None:
        raise ParameterError("--out: expected at least one output (--out PNG, --npy, --stats), got none")
    if args.out is not None and not str(args.out).lower().endswith(".png"):
        raise ParameterError(f"--out: expected a .png file name, got {args.out!r}")
    if args.npy is not None and not str(args.npy).lower().endswith(".npy"):
        raise ParameterError(f"--npy: expected a .npy file name, got {args.npy!r}")
    from clipvol.bricking.output_guard import check_not_input

    for flag, out in (("--out", args.out), ("--npy", args.npy), ("--stats", args.stats)):
        if out is not None:  # `slice u.npy --npy u.npy` wrote the slice over its input
            check_not_input(out, [args.source], flag)
    if args.tf == "auto":  # slice's auto: the grey window
        args.tf = None
    if args.tf is not None and args.tf not in TransferFunction.names():
        raise ParameterError(f"--tf: expected one of {', '.join(TransferFunction.names())}, got {args.tf!r}")
    if args.tf is not None and args.window is not None:
        raise ParameterError("--window: expected either --window or --tf, got both")
    if args.pixel_size is not None and not (math.isfinite(args.pixel_size) and args.pixel_size > 0):
        raise ParameterError(f"--pixel-size: expected a finite size > 0 (world units), got {args.pixel_size}")
    from clipvol.app.autobrick import bricked_source

    kwargs = {} if args.brick is None else {"brick": args.brick}
    from clipvol.tools.deadline import CommandDeadline
    from clipvol.tools.remote_args import check_trust, remote_kwargs

    deadline = CommandDeadline(None if args.no_wait else args.timeout)  # --timeout bounds the whole command
    loader = open_store(bricked_source(args.source, args.store, log=lambda line: print(line, file=sys.stderr)), **kwargs,
                        **deadline.remote_kwargs(args.source, remote_kwargs(args)))
    check_trust(loader, args, "slice")
    pyr = loader.pyramid
    frame = getattr(loader, "frame", None)  # the source's voxel-to-world affine (NIfTI, DICOM, ...)
    plane = plane_from_args(pyr, args, frame)
    poi = None
    if args.poi is not None:  # a world point: the plane moves through it unless its place was given
        from clipvol.scene.cut import point_to_render

        poi = point_to_render(pyr, frame, args.poi, "--poi")
        if args.plane is None and args.index is None and args.through is None:
            plane = plane.moved_through(poi)
    lo, hi = pyr.volume_box()
    if not plane.crosses(lo, hi)[0]:
        raise ParameterError(f"plane: expected a plane that meets the volume {tuple(lo.tolist())}..{tuple(hi.tolist())}, "
                             f"got origin {plane.origin} normal {plane.normal}")
    if args.level is not None and not (0 <= args.level < pyr.num_levels):
        raise ParameterError(f"--level: expected 0..{pyr.num_levels - 1} for this store, got {args.level}")
    edges = None
    if frame is not None:
        from clipvol.scene.orientation import view_labels

        edges = view_labels(frame.affine, plane.right, plane.up, frame.frame)
    from clipvol.tools.cut_args import shape_from_args

    cut = shape_from_args(args, loader)  # --crop / --crop-voxels / --clip-plane: pixels outside are left out
    params = render_params_from_args(args, policy="plane", focus=None if poi is None else tuple(map(float, poi)), shape=cut)
    centre = np.clip(np.asarray(poi if poi is not None else plane.origin, dtype=np.float64), lo, hi)
    tf = TransferFunction.preset(args.tf) if args.tf is not None else None
    ctx = create_context()
    try:
        from clipvol.scene.cut import outside_bricks

        # Region.empty: nothing is read before the slice hands the clip-texture its slab
        with deadline.closing("slice") as register, \
                ClipTexture(loader, args.memory_budget, args.threads, center=centre,
                            region=Region.empty(loader.pyramid.num_levels), outside=outside_bricks(pyr, cut)) as clip, \
                SliceAction(ctx, register(clip), params) as action:
            rgba, values = action.render(plane, args.size, args.pixel_size, transfer_function=tf, window=args.window,
                                         wait=not args.no_wait, timeout=args.timeout if args.no_wait else deadline.left(),
                                         return_values=True)
            st = action.last_stats
            if not st.failed_bricks:  # failed bricks are settled below, with their causes
                from clipvol.tools.partial import settle_unconverged

                settle_unconverged("slice", args.out or args.npy or args.stats, converged=st.converged,
                                   waited=not args.no_wait, selection=action.last_selection, clip=clip,
                                   brick_gpu_bytes=action.cache.brick_texels * action.cache.format.itemsize,
                                   texture_budget=params.texture_budget, timeout=args.timeout,
                                   allow=args.allow_partial, unblended=action.last_missing_low)
        late = clip.take_reads()  # what the loader threads read after the slice, until they stopped
    finally:
        ctx.release()
    from clipvol.render.failures import hatch_failed
    from clipvol.tools.partial import settle_failed

    cam = action.last_camera
    rgba = settle_failed("slice", args.out or args.npy or args.stats, st.failed_bricks, rgba,
                         lambda im: hatch_failed(im, cam, pyr, st.failed_bricks, plane=plane), args.allow_partial,
                         strict=True)
    h, w = values.shape
    if cut is not None:  # outside the cut: transparent in the PNG, NaN in the values
        from clipvol.scene.plane import default_pixel_size

        px = default_pixel_size(pyr, plane) if args.pixel_size is None else args.pixel_size
        outside = ~cut.contains(plane.pixel_points((w, h), px))
        rgba, values = rgba.copy(), values.copy()
        rgba[outside] = 0
        values[outside] = np.nan
    if args.out is not None:
        if edges is not None and frame.frame == "RAS" and not args.no_labels:
            from clipvol.app.annotate import label_edges

            rgba = label_edges(rgba, edges)
        _write_atomic(args.out, lambda p: Image.fromarray(rgba, "RGBA").save(p, format="PNG"))
    if args.npy is not None:
        def save_npy(p):
            with open(p, "wb") as f:
                np.save(f, values)
        _write_atomic(args.npy, save_npy)
    if args.stats is not None:
        doc = dict(st.as_dict(), size=[w, h], plane=dict(origin=list(plane.origin), normal=list(plane.normal),
                                                         up=list(plane.up)), poi=args.poi, level=args.level,
                   edges=edges)
        _write_atomic(args.stats, lambda p: open(p, "w").write(json.dumps(doc, indent=1) + "\n"))
    levels = ", ".join(f"L{L}: {n}" for L, n in st.tiles_per_level.items()) or "none"
    print(f"slice {w}x{h}: tiles {st.tiles} ({levels}), {st.blended} blended, converged {st.converged}", file=sys.stderr)
    read = "" if st.frame_bytes_read is None else (
        f"; read {format_bytes(st.frame_bytes_read)} from storage for the slice's bricks and "
        f"{format_bytes(st.prefetch_bytes_read + sum((late or {}).values()))} prefetched around them")
    print(f"bricks needed {st.bricks_needed} ({format_bytes(st.bytes_needed)}); loaded {format_bytes(st.bytes_loaded)}{read}; "
          f"uploaded {format_bytes(st.bytes_uploaded)}; total {st.times['total'] * 1000:.1f} ms", file=sys.stderr)
    if edges is not None:
        print("edges: " + ", ".join(f"{k} {v}" for k, v in edges.items()), file=sys.stderr)
    return 0
