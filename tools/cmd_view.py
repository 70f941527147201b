"""Interactive roaming / multiresolution viewer, or offscreen flythrough frames (--offscreen).

``clipvol view STORE|procedural:...|x.npy`` opens a window (GLFW + moderngl) that renders the data
with the multiresolution clip renderer, never waiting for I/O: coarse data shows at once and
refines as bricks arrive. Keys: left drag orbit, right/middle drag pan, wheel zoom, WASD/QE fly
(moves the centre of interest), M mode, [ ] fixed level, +/- LOD threshold, I MIP/composite,
T transfer function, B brick outlines, P screenshot, H HUD, R reset, Esc quit.

``--offscreen --path orbit|turntable|fly|zoom --frames N --out DIR|anim.gif|movie.mp4`` renders a
camera path without a window (EGL) and writes PNG frames, a GIF or a movie (imageio-ffmpeg; ``--fps``,
``--quality``) plus a per-frame CSV. For a store built from NIfTI or DICOM the turntable spins the
patient head-up, starting from the front, and every frame's edges are labelled R/L, A/P, S/I.
"""

from __future__ import annotations

import argparse


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 640x480, got {text!r}") from None
    if w < 1 or h < 1 or w > 16384 or h > 16384:
        raise argparse.ArgumentTypeError(f"expected a size between 1x1 and 16384x16384, got {text!r}")
    return w, h


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a clipvol store / OME-Zarr directory, procedural:NAME?size=N, a .npy file, or a NIfTI / "
                   "DICOM folder / FILE.h5:/dataset / MRC input (bricked first into --store)")
    p.add_argument("--store", default=None, help="where a NIfTI/DICOM/HDF5/MRC input is bricked (default ./NAME.zarr; reused when it exists)")
    p.add_argument("--brick", type=int, default=None, help="brick edge for .npy and procedural sources (default: the loader's, 64)")
    g = p.add_argument_group("rendering")
    g.add_argument("--mode", choices=("composite", "mip"), default="composite", help="compositing or maximum intensity projection")
    g.add_argument("--selection", "--policy", dest="selection", choices=("multiresolution", "roaming", "fixed"),
                   default="multiresolution", help="selection policy the viewer starts with (M cycles them)")
    g.add_argument("--level", type=int, default=None, help="level drawn with --selection fixed (default 0)")
    g.add_argument("--lod-threshold", type=float, default=1.0, help="refine while a voxel projects to more than this many pixels")
    g.add_argument("--tf", default="viridis", help="transfer-function preset (grey, viridis, magma, inferno, plasma, bone) or demo (the demo's)")
    g.add_argument("--step", type=float, default=0.5, help="sample spacing in voxels of the drawn level")
    g.add_argument("--memory-budget", default="256MB", help="clip-texture (main memory) budget")
    g.add_argument("--texture-budget", default="256MB", help="GPU brick cache budget")
    g.add_argument("--texels-per-frame", type=int, default=None, help="most texels uploaded per frame")
    g.add_argument("--threads", type=int, default=None, help="loader threads (default: cores)")
    g.add_argument("--no-jitter", action="store_true", help="sample every pixel's ray from t = 0 (shows lattice rings; for comparisons)")
    g.add_argument("--render-path", choices=("single-pass", "bricks"), default="bricks",
                   help="one ray-guided pass through a page table of the cut, or one proxy box per brick")
    g.add_argument("--shading", action="store_true", help="start with gradient lighting on (key L)")
    g.add_argument("--outlines", action="store_true", help="draw brick outlines coloured by level (key B)")
    g.add_argument("--size", type=_size, default=None, help="window or image size WxH (default 960x640 window, 256x256 offscreen)")
    o = p.add_argument_group("offscreen")
    o.add_argument("--offscreen", action="store_true", help="render a camera path to files instead of opening a window")
    o.add_argument("--path", choices=("orbit", "turntable", "fly", "zoom"), default="orbit",
                   help="camera path (turntable: one upright turn, head-up for patient-frame stores)")
    o.add_argument("--frames", type=int, default=36, help="frames along the path")
    o.add_argument("--out", default="frames", help="output directory (PNG frames), anim.gif or movie.mp4/.webm/.mkv/.mov")
    o.add_argument("--converged", action="store_true", help="wait each frame until its bricks are drawn at their own level")
    o.add_argument("--timeout", type=float, default=60.0, help="seconds to wait per frame with --converged")
    o.add_argument("--fps", type=float, default=12.0, help="GIF or movie frame rate")
    o.add_argument("--quality", type=float, default=8.0, help="movie quality, 0 (smallest) .. 10 (best), default 8")
    o.add_argument("--no-labels", action="store_true", help="do not write anatomical edge labels on the frames")
    w = p.add_argument_group("window")
    w.add_argument("--screenshot-dir", default=".", help="where P saves screenshots")
    w.add_argument("--max-frames", type=int, default=None, help=argparse.SUPPRESS)


def _store_name(text: str) -> str:
    from pathlib import Path

    base = text.split(".h5:")[0].split(".hdf5:")[0].rstrip("/\\")
    name = Path(base).name
    for suf in (".nii.gz", ".nii", ".hdr", ".img", ".mrc", ".map", ".mrcs", ".rec", ".st", ".h5", ".hdf5", ".hdf", ".nxs", ".dcm"):
        if name.lower().endswith(suf):
            return name[: -len(suf)] or "volume"
    return name or "volume"


def _bricked(args) -> str:
    """The source itself, or for a NIfTI / DICOM / HDF5 / MRC input the store it is bricked into.

    One command from a scan to a view: ``clipvol view ct_folder/`` bricks the series into
    ``./ct_folder.zarr`` (or ``--store``) the first time and reuses that store afterwards.
    """
    import json
    import os
    from pathlib import Path

    text = args.source
    p = Path(text)
    if text.startswith("procedural:") or p.suffix.lower() == ".npy" or (p.is_dir() and any((p / m).exists() for m in ("zarr.json", ".zgroup"))):
        return text
    from clipvol.bricking.formats import open_format

    src = open_format(text)
    if src is None:
        return text
    src.close()
    store = Path(args.store) if args.store else Path.cwd() / f"{_store_name(text)}.zarr"
    try:
        cv = json.loads((store / "zarr.json").read_text())["attributes"]["clipvol"]
        if cv.get("complete") and str(cv.get("source", "")).startswith(os.path.abspath(text) + " ("):
            print(f"using {store} (bricked from {text})")
            return str(store)
    except (OSError, ValueError, KeyError, TypeError):
        pass
    from clipvol.bricking.pipeline import brick_volume

    print(f"bricking {text} into {store}")
    brick_volume(text, store, progress=True)
    return str(store)


def run(args) -> int:
    from clipvol.app.session import open_loader
    from clipvol.errors import ParameterError
    from clipvol.scene.params import RenderParams

    if args.frames < 1:
        raise ParameterError(f"--frames: expected >= 1, got {args.frames}")
    params = RenderParams(
        lod_threshold=args.lod_threshold, policy=args.selection, level=args.level, mode=args.mode,
        step=args.step, texels_per_frame=args.texels_per_frame, texture_budget=args.texture_budget,
        jitter=not args.no_jitter, path=args.render_path, shading=args.shading,
    )
    tf = args.tf
    from clipvol.scene.transfer import TransferFunction

    if args.tf == "demo":
        from clipvol.tools.cmd_demo import demo_transfer_function

        tf = demo_transfer_function()
    elif args.tf not in TransferFunction.names():
        raise ParameterError(f"--tf: expected one of {', '.join(TransferFunction.names())} or demo, got {args.tf!r}")
    kwargs = {} if args.brick is None else {"brick": args.brick}
    source = _bricked(args)
    loader = open_loader(source, **kwargs)
    if params.level is not None and params.level >= loader.pyramid.num_levels:
        raise ParameterError(f"--level: expected 0..{loader.pyramid.num_levels - 1}, got {params.level}")
    if args.offscreen:
        from clipvol.app.flythrough import render_path

        def show(row: dict) -> None:
            print(f"frame {row['frame']:4d}  {row['frame_s'] * 1e3:7.1f} ms  {row['bricks_drawn']:5d} bricks  "
                  f"loaded {row['bytes_loaded'] / 1e6:6.2f} MB  uploaded {row['bytes_uploaded'] / 1e6:6.2f} MB"
                  + ("" if row["converged"] else "  (refining)"), flush=True)

        frame = getattr(loader, "frame", None)  # the store's voxel-to-world affine, if it records one
        path_kwargs = {}
        if args.path == "turntable" and frame is not None and frame.frame == "RAS":
            from clipvol.scene.orientation import anatomical_axes

            up, front = anatomical_axes(frame.affine)
            path_kwargs = {"up": tuple(up), "front": tuple(front)}
        res = render_path(
            loader, args.out, path=args.path, frames=args.frames, size=args.size or (256, 256),
            converged=args.converged, timeout=args.timeout, memory_budget=args.memory_budget,
            texture_budget=args.texture_budget, threads=args.threads, params=params, tf=tf, outlines=args.outlines,
            fps=args.fps, progress=show, path_kwargs=path_kwargs, quality=args.quality,
            orientation=None if args.no_labels or frame is None or frame.frame != "RAS" else frame,
        )
        print(f"wrote {res.frames} frames to {args.out}; per-frame statistics in {res.csv}")
        return 0
    from clipvol.viewer.window import Viewer

    with Viewer(loader, size=args.size or (960, 640), memory_budget=args.memory_budget,
                texture_budget=args.texture_budget, threads=args.threads, params=params, tf=tf,
                screenshot_dir=args.screenshot_dir, title=f"clipvol - {args.source}") as viewer:
        if args.outlines:
            viewer.key("B")
        return viewer.run(max_frames=args.max_frames)
