"""The command-line hooks of the volume data kind (:class:`clipvol.app.volume_kind.VolumeKind`):
`clipvol info`, `check`, `render`, `slice`, `view` and `report` on a volume.

The commands hand every source to its kind through :func:`clipvol.tools.kind_cli.kind_command`;
these hooks follow :class:`clipvol.app.kinds.KindCommands`, as the point kind's
(:mod:`clipvol.tools.point_cli`) do. A hook turns the flags into the library's objects (a loader,
a camera or a plane, :class:`~clipvol.scene.params.RenderParams`, a transfer function) and makes
one call into the application: :func:`clipvol.app.render_png.render_to_png`,
:func:`clipvol.app.slice_files.slice_to_files`, or the command module's volume function for
``info``, ``check``, ``view`` and ``report``.
"""

from __future__ import annotations

import sys

from clipvol.errors import ParameterError

__all__ = ["info", "check", "render", "slice", "view", "report", "hidden_labels"]


def _log(line: str) -> None:
    print(line, file=sys.stderr)


def info(args) -> int:
    """`clipvol info` of a local volume store."""
    from clipvol.tools.cmd_info import volume_info

    return volume_info(args)


def check(args) -> int:
    """`clipvol check` of a volume store or image set."""
    from clipvol.tools.cmd_check import volume_check

    return volume_check(args)


def view(args) -> int:
    """`clipvol view` of a volume: the window, or ``--offscreen`` frames."""
    from clipvol.tools.cmd_view import volume_view

    return volume_view(args)


def report(args, source, out) -> int:
    """`clipvol report` of a volume into ``out``."""
    from clipvol.tools.cmd_report import volume_report

    return volume_report(args, source, out)


def hidden_labels(source, loader, spec: str):
    """``loader`` with the voxels of ``--hide-labels NAME:ID,ID`` (a label image of the store) hidden."""
    from pathlib import Path

    from clipvol.bricking.labels import label_names
    from clipvol.paging.open import open_store
    from clipvol.paging.tagging import TaggedLoader

    name, _, ids = spec.partition(":")
    names = label_names(source)
    if name not in names:
        raise ParameterError(f"--hide-labels: expected one of the store's labels {names or '(none)'}, got {name!r}")
    try:
        hidden = [int(v) for v in ids.split(",") if v.strip()]
    except ValueError:
        raise ParameterError(f"--hide-labels: expected NAME:ID,ID with integer ids, got {spec!r}") from None
    return TaggedLoader(loader, open_store(Path(source) / "labels" / name), hidden)


def _world_camera_points(pyr, frame, eye, target, up):
    """``--eye``/``--target``/``--up`` as :func:`clipvol.scene.views.view_camera` takes them: a patient
    frame's points go as typed (it converts them itself); another store's world points (an origin,
    an affine from MRC or OME-Zarr) are carried into the drawing frame here, as ``--crop`` is, so the
    numbers ``clipvol info`` prints mean the same place in every flag."""
    from clipvol.scene.views import is_anatomical

    if frame is None or is_anatomical(frame):
        return eye, target, up
    from clipvol.scene.cut import direction_to_render, point_to_render

    def conv(v, f):
        return None if v is None else tuple(float(c) for c in f(v))

    return (conv(eye, lambda v: point_to_render(pyr, frame, v, "--eye")),
            conv(target, lambda v: point_to_render(pyr, frame, v, "--target")),
            conv(up, lambda v: direction_to_render(pyr, frame, v, "--up")))


def _camera(args, loader):
    """The camera of ``--camera FILE.json``, or of ``--view``/``--eye``/``--target``/``--up``/``--fov``/
    ``--distance``/``--ortho`` framed on the volume."""
    from clipvol.scene.views import view_camera

    if args.camera is not None:
        from clipvol.scene.bookmarks import load_camera

        return load_camera(args.camera, size=args.size)
    pyr, frame = loader.pyramid, getattr(loader, "frame", None)
    eye, target, up = _world_camera_points(pyr, frame, args.eye, args.target, args.up)
    return view_camera(pyr, args.view, args.size, eye=eye, target=target, up=up, fov=args.fov,
                       distance=args.distance, ortho=args.ortho, frame=frame)


def render(args) -> int:
    """`clipvol render` of a volume: one frame to ``--out`` (:func:`clipvol.app.render_png.render_to_png`)."""
    from clipvol.app.autobrick import bricked_source
    from clipvol.app.deadline import CommandDeadline
    from clipvol.app.outputs import check_output_file, check_outputs
    from clipvol.paging.open import open_store
    from clipvol.tools.cut_args import shape_from_args
    from clipvol.tools.overlay_args import channels_from_args, overlays_from_args
    from clipvol.tools.remote_args import check_trust, remote_kwargs
    from clipvol.tools.render_args import render_params_from_args
    from clipvol.tools.tf_args import transfer_function_from_args

    check_output_file(args.out, ".png", "--out")
    deadline = CommandDeadline(None if args.no_wait else args.timeout)  # --timeout bounds the whole command
    check_outputs([("--out", args.out)], [args.source])
    args.source = bricked_source(args.source, args.store, log=_log)
    kwargs = {} if args.brick is None else {"brick": args.brick}
    kwargs.update({k: v for k, v in (("t", args.t), ("c", args.c)) if v is not None})
    channel_overlays, channel_tf = (), None
    channels = channels_from_args(args, args.source, {**kwargs, **remote_kwargs(args)})
    if channels is not None:
        loader, channel_tf, channel_overlays = channels
    else:
        loader = open_store(args.source, **kwargs, **deadline.remote_kwargs(args.source, remote_kwargs(args)))
        check_trust(loader, args, "render")
    if args.hide_labels:
        loader = hidden_labels(args.source, loader, args.hide_labels)
    cam = _camera(args, loader)
    params = render_params_from_args(
        args, overlays=channel_overlays + overlays_from_args(args, args.source, loader),
        blend=args.blend or ("additive" if args.channels else "over"), shape=shape_from_args(args, loader),
    ).check_for(loader.pyramid)
    tf = channel_tf or transfer_function_from_args(args, loader)
    if args.workers is not None:  # sort-last on Dask: groups of bricks in worker processes
        from clipvol.app.render_png import render_sort_last_to_png

        render_sort_last_to_png(args.source, args.out, cam, params, tf, workers=args.workers, scheduler=args.scheduler,
                                memory_budget=args.memory_budget, timeout=args.timeout,
                                source_kwargs={**kwargs, **remote_kwargs(args)}, frame=getattr(loader, "frame", None),
                                wait=not args.no_wait, hidden_labels=bool(args.hide_labels),
                                allow_partial=args.allow_partial, labels=not args.no_labels, log=_log)
        return 0
    from clipvol.app.render_png import render_to_png

    render_to_png(loader, args.out, cam, params, tf, memory_budget=args.memory_budget, threads=args.threads,
                  wait=not args.no_wait, timeout=args.timeout, deadline=deadline, allow_partial=args.allow_partial,
                  labels=not args.no_labels, log=_log)
    return 0


def slice(args) -> int:  # noqa: A001 - the hook is named for its command
    """`clipvol slice` of a volume: a cutting plane to ``--out``/``--npy``/``--stats``
    (:func:`clipvol.app.slice_files.slice_to_files`)."""
    import math

    from clipvol.app.autobrick import bricked_source
    from clipvol.app.deadline import CommandDeadline
    from clipvol.app.outputs import check_output_file, check_outputs
    from clipvol.paging.open import open_store
    from clipvol.scene.transfer import TransferFunction
    from clipvol.tools.cut_args import shape_from_args
    from clipvol.tools.plane_args import plane_from_args
    from clipvol.tools.remote_args import check_trust, remote_kwargs
    from clipvol.tools.render_args import render_params_from_args

    if args.out is None and args.npy is None and args.stats is None:
        raise ParameterError("--out: expected at least one output (--out PNG, --npy, --stats), got none")
    for flag, out, suffix in (("--out", args.out, ".png"), ("--npy", args.npy, ".npy"), ("--stats", args.stats, "")):
        if out is not None:  # a missing folder is refused before any work, not found when the slice is written
            check_output_file(out, suffix, flag)
    check_outputs([("--out", args.out), ("--npy", args.npy), ("--stats", args.stats)], [args.source])
    if args.tf == "auto":  # slice's auto: the grey window
        args.tf = None
    if args.tf is not None and args.tf not in TransferFunction.names():
        raise ParameterError(f"--tf: expected one of {', '.join(TransferFunction.names())}, got {args.tf!r}")
    if args.tf is not None and args.window is not None:
        raise ParameterError("--window: expected either --window or --tf, got both")
    if args.pixel_size is not None and not (math.isfinite(args.pixel_size) and args.pixel_size > 0):
        raise ParameterError(f"--pixel-size: expected a finite size > 0 (world units), got {args.pixel_size}")
    exact_tol = _exact_tol(args.exact_tol)
    kwargs = {} if args.brick is None else {"brick": args.brick}
    deadline = CommandDeadline(None if args.no_wait else args.timeout)  # --timeout bounds the whole command
    loader = open_store(bricked_source(args.source, args.store, log=_log), **kwargs,
                        **deadline.remote_kwargs(args.source, remote_kwargs(args)))
    check_trust(loader, args, "slice")
    pyr = loader.pyramid
    frame = getattr(loader, "frame", None)
    plane = plane_from_args(pyr, args, frame)
    poi = None
    if args.poi is not None:  # a world point: the plane moves through it unless its place was given
        from clipvol.scene.cut import point_to_render

        poi = point_to_render(pyr, frame, args.poi, "--poi")
        if args.plane is None and args.index is None and args.through is None:
            plane = plane.moved_through(poi)
    cut = shape_from_args(args, loader)  # --crop / --crop-voxels / --clip-plane: pixels outside are left out
    params = render_params_from_args(args, policy="plane", focus=None if poi is None else tuple(map(float, poi)), shape=cut)
    from clipvol.app.slice_files import slice_to_files

    slice_to_files(loader, plane, params, out=args.out, npy=args.npy, stats=args.stats, size=args.size,
                   pixel_size=args.pixel_size, tf=TransferFunction.preset(args.tf) if args.tf is not None else None,
                   window=args.window, center=poi, poi=args.poi, memory_budget=args.memory_budget,
                   threads=args.threads, wait=not args.no_wait, timeout=args.timeout, deadline=deadline,
                   allow_partial=args.allow_partial, labels=not args.no_labels, log=_log, exact_tol=exact_tol)
    return 0


def _exact_tol(text):
    """``--exact-tol``: a CIELUV Delta E >= 0, ``off`` (None), or not given (the slice action's default)."""
    import math

    from clipvol.scene.slice_exact import DEFAULT_TOL

    if text is None:
        return DEFAULT_TOL
    if str(text).strip().lower() == "off":
        return None
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not (math.isfinite(v) and v >= 0):
        raise ParameterError(f"--exact-tol: expected a CIELUV Delta E >= 0 or 'off', got {text!r}")
    return v
