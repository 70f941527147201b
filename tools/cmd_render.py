"""Render one image of a store, a procedural volume or a .npy file to a PNG.

By default the frame is *converged*: the command waits until every brick the view wants is
loaded and drawn at its own level (``--no-wait`` renders whatever is resident after the first
pass). The clip-texture's centre of interest is the camera target, clamped into the volume.
Frame statistics (bricks per level, uploads, texture bytes, time per stage) go to stderr.
"""

from __future__ import annotations

import argparse
import sys

from clipvol.errors import ParameterError
from clipvol.tools.common_args import add_common_arguments, parse_xyz
from clipvol.tools.overlay_args import add_channel_arguments, channels_from_args
from clipvol.tools.render_args import add_render_arguments, render_params_from_args


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a clipvol store / OME-Zarr directory or URL (s3://, https://, ...), procedural:NAME?size=N, "
                                  "a .npy file, or a NIfTI / DICOM folder / FILE.h5:/dataset / MRC input (bricked first into --store)")
    add_common_arguments(p, ("store",))
    p.add_argument("--out", "-o", required=True, help="output PNG")
    add_common_arguments(p, ("brick",))
    d = p.add_argument_group("data")
    add_common_arguments(d, ("t", "c"))
    add_channel_arguments(d)
    d.add_argument("--hide-labels", default=None, metavar="NAME:ID,ID",
                   help="hide the voxels of these label ids of the store's labels/NAME (from clipvol brick --labels)")
    v = p.add_argument_group("camera")
    add_common_arguments(v, ("view",))
    v.add_argument("--eye", type=parse_xyz, default=None,
                   help="eye position x,y,z (overrides --view) in the store's world frame (what clipvol info prints): "
                        "RAS millimetres for a store with a patient frame, the origin plus the array's axes scaled by "
                        "the spacing otherwise")
    v.add_argument("--target", type=parse_xyz, default=None,
                   help="point looked at x,y,z, in the same coordinates as --eye (default: the volume centre)")
    add_common_arguments(v, ("up", "no_labels"))
    v.add_argument("--fov", type=float, default=35.0, help="vertical field of view in degrees (perspective)")
    v.add_argument("--distance", type=float, default=None, help="eye distance from the target, in volume diagonals (default 1.6)")
    v.add_argument("--ortho", action="store_true", help="orthographic projection framing the volume")
    add_common_arguments(v, ("size", "camera"))
    r = p.add_argument_group("rendering")
    add_render_arguments(r, ("mode", "iso_value", "policy", "level", "max_texels_drawn", "distance_factor",
                             "fov_fraction", "block_budget", "max_error", "visibility", "lod_threshold"))
    from clipvol.tools.overlay_args import add_overlay_arguments
    from clipvol.tools.tf_args import add_tf_arguments

    add_tf_arguments(p.add_argument_group("transfer function"))
    add_overlay_arguments(p.add_argument_group("overlays of co-registered volumes"))
    add_render_arguments(r, ("step", "refine_tolerance", "background", "shading", "light", "skip_empty", "classify"))
    add_common_arguments(r, ("memory_budget",))
    add_render_arguments(r, ("texture_budget", "texels_per_frame"))
    add_common_arguments(r, ("threads", "no_wait", "timeout", "tolerance"))
    sl = p.add_argument_group("sort-last rendering on Dask (needs clipvol[dask])")
    add_common_arguments(sl, ("workers", "scheduler"))
    add_common_arguments(r, ("allow_partial",))
    add_common_arguments(p, ("cut", "remote", "unverified"))


def check_output_file(path, suffix: str, flag: str) -> None:
    """Fail before any work when ``path`` cannot be written: wrong suffix, or a missing folder."""
    from pathlib import Path

    p = Path(path)
    if suffix and not p.name.lower().endswith(suffix):
        raise ParameterError(f"{flag}: expected a {suffix} file name, got {str(path)!r}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ParameterError(f"{flag}: {str(path)!r}: the folder {str(parent)!r} does not exist")


def hidden_labels(source, loader, spec: str):
    """``loader`` with the voxels of ``NAME:ID,ID`` (a label image of the store) hidden."""
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


def run(args) -> int:
    import numpy as np
    from PIL import Image

    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction
    from clipvol.units import format_bytes

    from clipvol.render.failures import hatch_failed
    from clipvol.scene.bookmarks import load_camera
    from clipvol.scene.views import view_camera
    from clipvol.tools.partial import settle_failed, settle_unconverged
    from clipvol.tools.cut_args import shape_from_args
    from clipvol.tools.tf_args import transfer_function_from_args

    check_output_file(args.out, ".png", "--out")
    from clipvol.tools.deadline import CommandDeadline

    deadline = CommandDeadline(None if args.no_wait else args.timeout)  # --timeout bounds the whole command
    from clipvol.bricking.output_guard import check_not_input

    check_not_input(args.out, [args.source], "--out")
    from clipvol.tools.kind_cli import kind_command

    hook = kind_command(args.source, "render")  # another data kind than a volume: its own render
    if hook is not None:
        return hook(args)
    from clipvol.tools.remote_args import check_trust, remote_kwargs

    from clipvol.app.autobrick import bricked_source

    args.source = bricked_source(args.source, args.store, log=lambda line: print(line, file=sys.stderr))
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
    pyr = loader.pyramid
    frame = getattr(loader, "frame", None)  # the store's voxel-to-world affine and patient frame, if any
    if args.camera is not None:
        cam = load_camera(args.camera, size=args.size)
    else:
        eye, target, up = _world_camera_points(pyr, frame, args.eye, args.target, args.up)
        cam = view_camera(pyr, args.view, args.size, eye=eye, target=target, up=up, fov=args.fov,
                          distance=args.distance, ortho=args.ortho, frame=frame)
    lo, hi = pyr.volume_box()
    centre = np.clip(np.asarray(cam.center, dtype=np.float64), lo, hi)
    params = render_params_from_args(
        args, overlays=channel_overlays + _overlays(args, loader), blend=args.blend or ("additive" if args.channels else "over"),
        shape=shape_from_args(args, loader),
    ).check_for(pyr)
    tf = channel_tf or transfer_function_from_args(args, loader)
    if args.workers is not None:  # sort-last on Dask: groups of bricks in worker processes
        return _run_sort_last(args, params, cam, tf, kwargs, frame)
    ctx = create_context()
    try:
        from clipvol.scene.cut import outside_bricks

        with deadline.closing("render") as register, \
                ClipTexture(loader, args.memory_budget, args.threads, center=centre,
                            outside=outside_bricks(pyr, params.shape)) as clip, \
                ClipRenderAction(ctx, register(clip), params) as action:
            image = action.render(cam, tf, wait=not args.no_wait,
                                  timeout=args.timeout if args.no_wait else deadline.left())
            st = action.last_frame_stats
            overlay_levels = action.overlays.levels()
            unread = clip.stats.empty_skipped
            if not st.failed_bricks:  # failed bricks are settled below, with their causes
                settle_unconverged("render", args.out, converged=st.converged, waited=not args.no_wait,
                                   selection=action.last_selection, clip=clip, timeout=args.timeout,
                                   brick_gpu_bytes=action.cache.brick_texels * action.cache.format.itemsize,
                                   texture_budget=params.texture_budget, allow=args.allow_partial)
        late = clip.take_reads()  # what the loader threads read after the frame, until they stopped
    finally:
        ctx.release()
    from clipvol.app.annotate import present

    image = settle_failed("render", args.out, st.failed_bricks, image,
                          lambda im: hatch_failed(im, cam, pyr, st.failed_bricks), args.allow_partial, strict=True)
    Image.fromarray(present(image, cam, frame, labels=not args.no_labels), "RGBA").save(args.out)
    t = st.times
    levels = ", ".join(f"L{L}: {n}" for L, n in st.bricks_drawn.items()) or "none"
    print(f"wrote {args.out} ({cam.size[0]}x{cam.size[1]}, {args.mode}, {params.policy}, transfer function "
          f"{tf.name or 'custom'})", file=sys.stderr)
    print(f"bricks drawn {sum(st.bricks_drawn.values())} ({levels}); texels drawn {st.texels_drawn:,}; "
          f"converged {st.converged} after {st.passes} pass(es)", file=sys.stderr)
    if params.shape is not None:
        print(f"cut: {st.counts.get('culled_shape', 0)} bricks outside the crop box / clip planes not drawn; "
              f"{unread} bricks filled without reading (outside the cut, or empty)", file=sys.stderr)
    read = "" if st.frame_bytes_read is None else (
        f"; read {format_bytes(st.frame_bytes_read)} from storage for the frame's bricks and "
        f"{format_bytes(st.prefetch_bytes_read + sum((late or {}).values()))} prefetched around them")
    print(f"uploaded {format_bytes(st.bytes_uploaded)} in {st.bricks_uploaded} bricks; textures "
          f"{format_bytes(st.texture_bytes)} of {format_bytes(st.texture_budget)}{read}", file=sys.stderr)
    if params.policy == "image":
        est = getattr(action.last_policy, "estimated_error", float("nan"))
        budget = "" if params.max_error is None else f", error budget {100 * params.max_error:g} %"
        sampled = " (of the cut; adaptive image sampling adds an error of its own, not estimated)" \
            if params.refine_tolerance > 0 and params.mode == "composite" else ""
        print(f"image policy: block budget {params.block_budget or 'none'}{budget}, {st.bricks_distinct} bricks drawn, "
              f"estimated {100 * est:.1f} % of pixels dE>=6 against the converged picture{sampled}", file=sys.stderr)
    if overlay_levels:
        print("overlays: " + "; ".join(f"{name} (level {L})" for name, L in overlay_levels.items()), file=sys.stderr)
    print("time: " + ", ".join(f"{k} {v * 1000:.1f} ms" for k, v in t.items()), file=sys.stderr)
    return 0


def _run_sort_last(args, params, cam, tf, kwargs, frame=None) -> int:
    """``--workers N``: :class:`clipvol.app.sortlast.DistributedRenderer` instead of one action."""
    from PIL import Image

    from clipvol.app.sortlast import DistributedRenderer
    from clipvol.tools.remote_args import remote_kwargs

    if args.workers < 1:
        raise ParameterError(f"--workers: expected an integer >= 1, got {args.workers}")
    if args.no_wait:
        raise ParameterError("--no-wait: sort-last frames are always converged; drop --no-wait or --workers")
    if params.overlays:
        raise ParameterError("--overlay: not available with --workers (each worker draws a part of the primary alone)")
    if args.hide_labels:
        raise ParameterError("--hide-labels: not available with --workers (the workers draw the image alone)")
    with DistributedRenderer(args.source, args.workers, params, scheduler=args.scheduler,
                             memory_budget=args.memory_budget, timeout=args.timeout,
                             source_kwargs={**kwargs, **remote_kwargs(args)}) as dr:
        image = dr.render(cam, tf)
        st = dr.last_stats
    from clipvol.app.annotate import present
    from clipvol.render.failures import hatch_failed
    from clipvol.tools.partial import settle_failed

    image = settle_failed("render", args.out, st.failed_bricks, image,
                          lambda im: hatch_failed(im, cam, dr.pyramid, st.failed_bricks), args.allow_partial,
                          strict=True)
    Image.fromarray(present(image, cam, frame, labels=not args.no_labels), "RGBA").save(args.out)
    print(f"wrote {args.out} ({cam.size[0]}x{cam.size[1]}, {args.mode}, {params.policy}, sort-last over "
          f"{args.workers} workers)", file=sys.stderr)
    print(f"converged {st.converged}", file=sys.stderr)
    print("time: frame {:.1f} ms, groups {}, compositing {:.1f} ms".format(
        st.frame_seconds * 1000, ", ".join(f"{t * 1000:.1f} ms" for t in st.group_seconds), st.composite_seconds * 1000),
        file=sys.stderr)
    return 0


def _overlays(args, loader) -> tuple:
    from clipvol.tools.overlay_args import overlays_from_args

    return overlays_from_args(args, args.source, loader)
