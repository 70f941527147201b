"""Interactive roaming / multiresolution viewer, or offscreen flythrough frames (--offscreen).

``clipvol view STORE|procedural:...|x.npy`` opens a window (GLFW + moderngl) that renders the data
with the multiresolution clip renderer, never waiting for I/O: coarse data shows at once and
refines as bricks arrive; while the camera moves it renders one coarse level at a lower resolution
and sampling to hold --frame-time, and at full quality once still. Keys: left drag orbit, right/middle drag pan,
wheel zoom, WASD/QE fly (moves the centre of interest), M mode, [ ] fixed level, +/- LOD threshold,
I MIP/composite, T colour map, Left/Right/Up/Down (or a drag on the HUD's histogram) move/widen
the transfer-function window, Shift+S save it, C save the camera, B brick outlines, P screenshot
(Shift+P without HUD), H HUD, R reset, Esc quit.

``--offscreen --path orbit|turntable|fly|zoom --frames N --out DIR|anim.gif|movie.mp4`` renders a
camera path without a window (EGL) and writes PNG frames, a GIF or a movie (imageio-ffmpeg; ``--fps``,
``--quality``) plus a per-frame CSV. For a store built from NIfTI or DICOM every path is head-up:
the turntable (and the orbit, a turntable raised 25 degrees) spins the patient starting from the
front (or the side ``--view`` names), the fly loop lies in the patient's axial plane, the zoom
looks from anterior-left-superior; every frame's edges are labelled R/L, A/P, S/I.
"""

from __future__ import annotations

import argparse



def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a clipvol store / OME-Zarr directory or URL (s3://, https://, ...), procedural:NAME?size=N, "
                   "a .npy file, or a NIfTI / DICOM folder / FILE.h5:/dataset / MRC input (bricked first into --store)")
    from clipvol.tools.common_args import add_common_arguments

    add_common_arguments(p, ("store", "remote", "unverified", "brick"))
    g = p.add_argument_group("rendering")
    from clipvol.tools.render_args import add_render_arguments

    add_render_arguments(g, ("mode", "iso_value", "policy", "level", "lod_threshold", "step", "max_error"))
    add_common_arguments(g, ("memory_budget",))
    add_render_arguments(g, ("texture_budget", "texels_per_frame"))
    add_common_arguments(g, ("threads",))
    add_render_arguments(g, ("jitter", "path", "shading", "skip_empty", "refine_tolerance", "classify"))
    g.add_argument("--play", action="store_true",
                   help="an OME-Zarr image with a t axis: play its time steps (Space play/pause, J/K step, { } rate; "
                        "the next step prefetched under the same memory budget)")
    g.add_argument("--rate", type=float, default=4.0, help="--play: most time steps per second (default 4)")
    add_common_arguments(g, ("c",))
    g.add_argument("--outlines", action="store_true", help="draw brick outlines coloured by level (key B)")
    add_common_arguments(g, ("tolerance", "size"))
    from clipvol.tools.overlay_args import add_channel_arguments, add_overlay_arguments
    from clipvol.tools.tf_args import add_tf_arguments

    add_channel_arguments(g)
    add_tf_arguments(p.add_argument_group("transfer function"))
    add_overlay_arguments(p.add_argument_group("overlays of co-registered volumes"))
    o = p.add_argument_group("offscreen")
    o.add_argument("--offscreen", action="store_true", help="render a camera path to files instead of opening a window")
    add_common_arguments(o, ("path", "frames"))
    add_common_arguments(o, ("allow_partial",))
    o.add_argument("--out", default="frames", help="output directory (PNG frames), anim.gif or movie.mp4/.webm/.mkv/.mov")
    o.add_argument("--converged", action="store_true", help="wait each frame until its bricks are drawn at their own level")
    add_common_arguments(o, ("timeout",))
    o.add_argument("--fps", type=float, default=12.0, help="GIF or movie frame rate")
    o.add_argument("--quality", type=float, default=8.0, help="movie quality, 0 (smallest) .. 10 (best), default 8")
    add_common_arguments(o, ("no_labels", "workers", "scheduler"))
    add_common_arguments(p, ("cut",))
    w = p.add_argument_group("window")
    w.add_argument("--screenshot-dir", default="clipvol-screenshots",
                   help="folder where P (with the HUD) and Shift+P (without) save screenshots, S the transfer "
                        "function and C the camera (created; default ./clipvol-screenshots)")
    add_common_arguments(w, ("camera",))
    add_common_arguments(p, ("view",))
    w.add_argument("--frame-time", type=float, default=round(1e3 / 15, 1), metavar="MS",
                   help="target frame time while the camera moves, in ms: the viewer lowers resolution and "
                        "sampling and draws one coarse level to hold it, and refines to full quality when still "
                        "(default 66.7: 15 frames a second; 0 turns it off)")
    w.add_argument("--max-frames", type=int, default=None, help=argparse.SUPPRESS)


def _bricked(args) -> str:
    """The source itself, or for a NIfTI / DICOM / HDF5 / MRC input the store it is bricked into
    (:func:`clipvol.app.autobrick.bricked_source`: ``./NAME.zarr`` or ``--store``, reused)."""
    from clipvol.app.autobrick import bricked_source

    return bricked_source(args.source, args.store)


def run(args) -> int:
    from clipvol.tools.kind_cli import kind_command

    if args.offscreen:  # frames, a GIF or a movie: never written into or over the input
        from clipvol.bricking.output_guard import check_not_input

        check_not_input(args.out, [args.source], "--out")
    return kind_command(args.source, "view")(args)  # the data kind's viewer (volume_view for a volume)


def volume_view(args) -> int:
    """``clipvol view`` of a volume (the volume kind's hook, :mod:`clipvol.tools.volume_cli`): the
    window, or with ``--offscreen`` a camera path to frames, a GIF or a movie."""
    from clipvol.app.session import open_loader
    from clipvol.errors import ParameterError
    from clipvol.tools.render_args import render_params_from_args

    _check_frames(args)
    if args.frame_time < 0:
        raise ParameterError(f"--frame-time: expected milliseconds >= 0, got {args.frame_time}")
    from clipvol.tools.tf_args import transfer_function_from_args

    params = render_params_from_args(args)
    from clipvol.tools.remote_args import check_trust, remote_kwargs

    kwargs = {} if args.brick is None else {"brick": args.brick}
    if args.c is not None:
        kwargs["c"] = args.c
    source = _bricked(args)
    from clipvol.tools.overlay_args import channels_from_args

    channels = channels_from_args(args, source, {**kwargs, **remote_kwargs(args)})
    if channels is not None and args.play:
        raise ParameterError("--channels: expected either --channels or --play, got both")
    loader = channels[0] if channels is not None else open_loader(source, **kwargs, **remote_kwargs(args))
    check_trust(loader, args, "view")
    series = _series(args, source, loader, {**kwargs, **remote_kwargs(args)}) if args.play else None
    if params.level is not None and params.level >= loader.pyramid.num_levels:
        raise ParameterError(f"--level: expected 0..{loader.pyramid.num_levels - 1}, got {params.level}")
    params.check_for(loader.pyramid)  # an --iso-value outside the data's range, before any output exists
    tf = channels[1] if channels is not None else transfer_function_from_args(args, loader)
    from clipvol.tools.cut_args import shape_from_args

    cut = shape_from_args(args, loader)
    if cut is not None:
        from dataclasses import replace

        params = replace(params, shape=cut)
    if args.overlay or args.label_overlay or channels is not None:
        from dataclasses import replace

        params = replace(params, overlays=(channels[2] if channels is not None else ())
                         + (_overlays(args, loader, source) if args.overlay or args.label_overlay else ()),
                         blend=args.blend or ("additive" if channels is not None else "over"))
    if args.workers is not None and not args.offscreen:
        raise ParameterError("--workers: sort-last frames are drawn offscreen only; add --offscreen")
    if args.workers is not None and params.overlays:
        raise ParameterError("--overlay: not available with --workers (each worker draws a part of the primary alone)")
    if args.offscreen:
        from clipvol.scene.views import patient_path

        frame = getattr(loader, "frame", None)  # the store's voxel-to-world affine, if it records one
        path, path_kwargs = patient_path(args.path, frame)  # every path head-up, from the patient's front
        if args.path == "turntable" and args.view is not None:  # start from the side --view names
            from clipvol.scene.views import view_directions

            path_kwargs["front"] = tuple(-view_directions(args.view, frame)[0])
        elif args.view is not None:
            raise ParameterError(f"--view: sets the window's first view or the turntable's first frame; "
                                 f"expected --path turntable, got --path {args.path}")
    if args.offscreen and args.workers is not None:  # sort-last frames on Dask
        from clipvol.app.sortlast import render_path_sort_last

        rows = render_path_sort_last(source, args.out, workers=args.workers, scheduler=args.scheduler,
                                     path=path, path_kwargs=path_kwargs, frame=frame, labels=not args.no_labels,
                                     frames=args.frames, size=args.size or (256, 256), params=params,
                                     tf=tf, memory_budget=args.memory_budget, source_kwargs={**kwargs, **remote_kwargs(args)},
                                     on_failed=_on_failed(args, loader.pyramid),
                                     progress=lambda r: print(f"frame {r['frame']:4d}  {r['frame_s'] * 1e3:7.1f} ms  "
                                                              f"compositing {r['composite_s'] * 1e3:5.1f} ms", flush=True))
        print(f"wrote {len(rows)} frames to {args.out}; per-frame times in {args.out}/frames.csv")
        return 0
    if args.offscreen:
        from clipvol.app.flythrough import render_path

        def show(row: dict) -> None:
            print(f"frame {row['frame']:4d}  {row['frame_s'] * 1e3:7.1f} ms  {row['bricks_drawn']:5d} bricks  "
                  f"loaded {row['bytes_loaded'] / 1e6:6.2f} MB  uploaded {row['bytes_uploaded'] / 1e6:6.2f} MB"
                  + ("" if row["converged"] else "  (refining)"), flush=True)

        res = render_path(
            loader, args.out, path=path, frames=args.frames, size=args.size or (256, 256),
            converged=args.converged, timeout=args.timeout, memory_budget=args.memory_budget,
            texture_budget=args.texture_budget, threads=args.threads, params=params, tf=tf, outlines=args.outlines,
            fps=args.fps, progress=show, path_kwargs=path_kwargs, quality=args.quality,
            orientation=None if args.no_labels or frame is None or frame.frame != "RAS" else frame,
            on_failed=_on_failed(args, loader.pyramid),
        )
        print(f"wrote {res.frames} frames to {args.out}; per-frame statistics in {res.csv}")
        return 0
    from clipvol.choices import VIEWER_POLICIES
    from clipvol.viewer.window import Viewer

    if params.policy not in VIEWER_POLICIES:  # --policy offers every policy; the window cycles these
        raise ParameterError(f"--policy: the window starts with one of {', '.join(VIEWER_POLICIES)}, got "
                             f"{params.policy!r} (every policy draws with --offscreen)")
    camera = None
    if args.camera is not None:
        from clipvol.scene.bookmarks import load_camera

        camera = load_camera(args.camera)
    elif args.view is not None:  # the named view of clipvol render (clipvol.scene.views)
        from clipvol.scene.views import preset_camera

        lo, hi = loader.pyramid.volume_box()
        camera = preset_camera(lo, hi, args.view, args.size or (960, 640), frame=getattr(loader, "frame", None))

    with Viewer(loader, size=args.size or (960, 640), memory_budget=args.memory_budget,
                texture_budget=args.texture_budget, threads=args.threads, params=params, tf=tf,
                screenshot_dir=args.screenshot_dir, title=f"clipvol - {args.source}",
                frame_time=args.frame_time / 1000.0 or None, camera=camera, series=series, rate=args.rate) as viewer:
        if args.outlines:
            viewer.key("B")
        return viewer.run(max_frames=args.max_frames)


def _overlays(args, loader, source) -> tuple:
    from clipvol.tools.overlay_args import overlays_from_args

    return overlays_from_args(args, source, loader)


def _series(args, source, loader, kwargs) -> list:
    """``--play``: one loader per time step of ``source`` (an OME-Zarr image with a ``t`` axis)."""
    from clipvol.app.session import open_loader
    from clipvol.errors import ParameterError

    axes = tuple(getattr(loader, "axes", ()) or ())
    if "t" not in axes:
        raise ParameterError(f"--play: expected an OME-Zarr image with a t axis, got {args.source} with axes "
                             f"{list(axes) + ['z', 'y', 'x']}")
    if args.offscreen or args.workers is not None:
        raise ParameterError("--play: plays in the window only; drop --offscreen / --workers")
    if not args.rate > 0:
        raise ParameterError(f"--rate: expected steps per second > 0, got {args.rate}")
    n = int(loader.lead_shape[axes.index("t")])
    return [loader] + [open_loader(source, t=k, **kwargs) for k in range(1, n)]


def _on_failed(args, pyramid):
    """``render_path``'s ``on_failed``: a frame with failed bricks that nothing stands in for stops
    the path (exit 3), or with ``--allow-partial`` is written hatched (:mod:`clipvol.app.partial`)."""
    from clipvol.render.failures import hatch_failed
    from clipvol.app.partial import settle_failed

    noted: set = set()

    def on_failed(k, cam, img, failed):
        replaced = {(f.level, f.index) for f in failed if f.replaced}
        note = not replaced <= noted  # each replaced brick noted once along the path
        noted.update(replaced)
        return settle_failed("view", f"{args.out} frame {k}", failed, img,
                             lambda im: hatch_failed(im, cam, pyramid, failed), args.allow_partial,
                             stopped=f"stopped there, the {k} frame(s) before it are written", note=note)

    return on_failed


#: most frames of one offscreen path (an hour at 24 fps)
MAX_FRAMES = 86_400
#: most bytes of frames a GIF holds in memory before it is written
MAX_GIF_BYTES = 2 << 30


def _check_frames(args) -> None:
    """``--frames`` in 1..:data:`MAX_FRAMES`, and for a GIF (every frame held in memory until it is
    written) no more than :data:`MAX_GIF_BYTES` of frames."""
    from clipvol.errors import ParameterError
    from clipvol.units import format_bytes

    n = args.frames
    if not 1 <= n <= MAX_FRAMES:
        raise ParameterError(f"--frames: expected 1..{MAX_FRAMES}, got {n}")
    if args.offscreen and str(args.out).lower().endswith(".gif"):
        w, h = args.size or (256, 256)
        need = n * w * h * 4
        if need > MAX_GIF_BYTES:
            raise ParameterError(f"--frames: a GIF holds every frame in memory until it is written: {n} frames of "
                                 f"{w}x{h} need {format_bytes(need)}, expected at most {format_bytes(MAX_GIF_BYTES)} "
                                 f"({MAX_GIF_BYTES // (w * h * 4)} frames); write PNG frames (--out DIR) or a movie")
