"""Image error against run time for a sweep of quality settings (LOD threshold, memory, texture and block budgets).

``clipvol report STORE --out DIR`` renders a few views along a camera path for each setting: cold
(as the bricks come, and the time to converge from an empty clip-texture) and warm (every setting
and the full-resolution reference timed over ``--rounds`` interleaved rounds in one process, each
frame paired with a full-resolution frame drawn next to it; median and spread). It compares each
frame, the full-resolution frame's included, with the converged picture of the same view (level 0
at step ``--converged-step``, ``--supersample`` rays per pixel along each axis, box-filtered; %
pixels with ΔE ≥ 6 in CIELUV, RMSE, PSNR), prints the answer in one line - how much faster than
the full-resolution frame frames are at <= 5 % of pixels visibly different from the converged
picture, with which setting, and the full-resolution frame's own error - and writes ``report.csv``,
``timing.csv``, plots of error against frame time and bytes, and ``report.md``. The work is done
by :func:`clipvol.app.report.run_report`.
"""

from __future__ import annotations

import argparse


def _floats(text: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers such as 0.5,1,2,4, got {text!r}") from None
    if not vals or any(not (v > 0) for v in vals):
        raise argparse.ArgumentTypeError(f"expected numbers > 0, got {text!r}")
    return vals


def _floats_one(text: str) -> float:
    """One number > 0 (``--converged-step``)."""
    vals = _floats(text)
    if len(vals) != 1:
        raise argparse.ArgumentTypeError(f"expected one number > 0, got {text!r}")
    return vals[0]


def _rounds(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return n


def _listed(text: str | None) -> list[str] | None:
    """A comma-separated list flag of the report: None (not given: the report's defaults), ``[]`` for
    ``none`` (no such settings), else the stripped items."""
    if text is None:
        return None
    if text.strip().lower() == "none":
        return []
    return [t.strip() for t in text.split(",") if t.strip()]


def _sizes(text: str) -> list[str]:
    """``--memory-budgets`` / ``--texture-budgets``: sizes checked while parsing (before anything is
    drawn); ``''`` or ``none``: no such settings."""
    from clipvol.errors import ParameterError
    from clipvol.units import parse_bytes

    out = _listed(text)
    for v in out:
        try:
            parse_bytes(v, "budget")
        except (ParameterError, ValueError):
            raise argparse.ArgumentTypeError(f"expected sizes like 64MB,16MB or 'none', got {v!r}") from None
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    from clipvol.tools.common_args import add_common_arguments, add_old_spelling

    p.add_argument("source", help="a clipvol store / OME-Zarr directory or URL (s3://, https://, ...), procedural:NAME?size=N, "
                                  "a .npy file, or a NIfTI / DICOM folder / FILE.h5:/dataset / MRC input (bricked once into ./NAME.zarr)")
    add_common_arguments(p, ("remote", "unverified"))
    p.add_argument("--out", required=True, help="output directory (created)")
    add_common_arguments(p, ("brick",))
    add_common_arguments(p, ("path",))
    p.add_argument("--views", type=int, default=3, help="views along the path")
    p.add_argument("--frame", choices=("visible", "volume"), default="visible",
                   help="what the orbit's views frame: the voxels the transfer function makes visible, each view "
                        "at the distance where they fill it (composite), or the sphere around the whole volume")
    add_common_arguments(p, ("size",))  # the image size also caps the reference's cost
    p.add_argument("--thresholds", type=_floats, default=[0.5, 1, 2, 4, 8, 16], help="LOD thresholds (pixels), comma-separated")
    p.add_argument("--memory-budgets", type=_sizes, default=None,
                   help="clip-texture budgets swept at LOD 1, e.g. 64MB,16MB (default: 1/2 and 1/8 of the data; 'none' to skip)")
    p.add_argument("--texture-budgets", type=_sizes, default=None,
                   help="GPU cache budgets swept at LOD 1 (default: 1/2 and 1/8 of the data; 'none' to skip)")
    from clipvol.tools.tf_args import add_tf_arguments

    add_tf_arguments(p.add_argument_group("transfer function"))
    from clipvol.tools.render_args import add_render_arguments

    add_render_arguments(p, ("mode", "iso_value", "step", "classify"))
    add_common_arguments(p, ("threads", "timeout", "allow_partial"))
    p.add_argument("--max-frames", type=int, default=8, help="as-it-comes frames per view at most")
    p.add_argument("--rounds", type=_rounds, default=5,
                   help="warm interleaved rounds per setting and view, each frame paired with a reference frame; "
                        "frame times and speed-ups are medians over them (default 5; each round costs four "
                        "frames per setting and view)")
    p.add_argument("--reference-cap", default="1GB", help="most bytes the full-resolution reference may hold")
    p.add_argument("--supersample", type=_rounds, default=2, metavar="K",
                   help="rays per pixel along each axis of the converged picture errors are measured against "
                        "(default 2; 4 where the time is there)")
    p.add_argument("--converged-step", type=_floats_one, default=0.25, metavar="VOXELS",
                   help="sample spacing of the converged picture in voxels (default 0.25)")
    p.add_argument("--no-plots", action="store_true", help="skip the matplotlib plots")
    pts = p.add_argument_group("point stores (frame time and image error against splat tolerance)")
    pts.add_argument("--tolerances", default=None, metavar="T,T,...",
                     help="splat tolerances of a point store, comma-separated fractions of the screen or Npx "
                          "(default 1px,2px,4px,0.02,0.05,0.1,0.2)")
    pts.add_argument("--points", default=None, metavar="POINTS.zarr",
                     help="also report this point store (into OUT/points) beside the volume store")
    p.add_argument("--max-errors", default=None, metavar="E,E,...",
                   help="visible-error budgets of the image policy measured as settings, comma-separated "
                        "fractions or percentages (predicted share of pixels with CIELUV dE >= 6), or 'none' "
                        "(default 10%%,5%%,2%%; needs the store's summary tables)")
    add_old_spelling(p, "--max-error", "--max-errors", " (report measures a list of budgets; --max-error is one "
                                                       "budget in render and view)")
    p.add_argument("--refine", default=None, metavar="STEP:TOL[:LEVEL],...",
                   help="one level (default the reference, full resolution) sampled at STEP voxels with adaptive "
                        "image sampling at tolerance TOL (--refine-tolerance of clipvol render) measured as settings, "
                        "comma-separated, or 'none' (default 2:0.16,2:0.25,2.5:0.2,2.5:0.25,2.5:0.3,1:0.08:1,1:0.16:1; "
                        "composite only)")
    p.add_argument("--block-budgets", default=None,
                   help="block budgets of the policy comparison (image-based LOD, after Wang, Garcia & Shen 2007, "
                        "Fig. 6), comma-separated, or 'none' (default 8,16,32,64,128,256)")


def _budgets(text):
    from clipvol.errors import ParameterError

    items = _listed(text)
    if items is None or text.strip().lower() == "none":  # the defaults; no policy comparison
        return None if items is None else ()
    try:
        vals = [int(t) for t in items]
    except ValueError:
        vals = []
    if not vals or min(vals) < 1:
        raise ParameterError(f"--block-budgets: expected comma-separated integers >= 1 or 'none', got {text!r}")
    return vals


def _max_errors(text):
    """``--max-errors``: None (the report's default budgets), ``()`` for 'none', else the listed values
    (each validated by RenderParams, which names ``max_error`` when one is wrong)."""
    return _listed(text)


def _refines(text):
    """``--refine``: None (the report's default settings), ``()`` for 'none', else ``(step, tolerance)``
    pairs or ``(step, tolerance, level)`` triples (each validated by RenderParams, which names ``step``
    or ``refine_tolerance``, and by the report, which names the level)."""
    from clipvol.errors import ParameterError

    items = _listed(text)
    if items is None:
        return None
    out = []
    for item in items:
        parts = item.split(":")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            vals = tuple(float(v) for v in parts[:2]) + tuple(int(v) for v in parts[2:])
        except ValueError:
            raise ParameterError(f"--refine: expected STEP:TOLERANCE[:LEVEL] like 2.5:0.3 or 1:0.16:1, comma-separated, "
                                 f"or 'none', got {item!r}") from None
        out.append(vals)
    return out


def run(args) -> int:
    from clipvol.bricking.output_guard import check_not_input
    from clipvol.tools.kind_cli import kind_command

    check_not_input(args.out, [args.source], "--out")  # the report's files never go into or over the input
    return kind_command(args.source, "report")(args, args.source, args.out)  # volume_report for a volume


def volume_report(args, source, out) -> int:
    """``clipvol report`` of a volume (the volume kind's hook, :mod:`clipvol.tools.volume_cli`): image
    error against time into ``out``, and with ``--points`` the point store's report into ``out/points``."""
    from clipvol.app.kinds import KINDS
    from clipvol.app.report import run_report
    from clipvol.app.session import open_loader
    from clipvol.tools.kind_cli import kind_command

    if args.points is not None and not KINDS["points"].claims(args.points):
        from clipvol.errors import ParameterError

        raise ParameterError(f"--points: expected a point store written by clipvol brick-points, got {args.points!r}")

    from clipvol.tools.tf_args import transfer_function_from_args

    from clipvol.tools.remote_args import check_trust, remote_kwargs

    from clipvol.app.autobrick import bricked_source

    source = bricked_source(source, None)  # a NIfTI / DICOM / HDF5 / MRC input: bricked once into ./NAME.zarr
    loader = open_loader(source, **({} if args.brick is None else {"brick": args.brick}), **remote_kwargs(args))
    check_trust(loader, args, "report")
    tf = transfer_function_from_args(args, loader)
    res = run_report(
        loader, out, path=args.path, views=args.views, size=args.size, thresholds=args.thresholds,
        memory_budgets=args.memory_budgets, texture_budgets=args.texture_budgets, tf=tf, mode=args.mode, iso_value=args.iso_value,
        step=args.step, threads=args.threads, timeout=args.timeout, max_frames=args.max_frames,
        reference_cap=args.reference_cap, log=lambda s: print(s, flush=True), plots=not args.no_plots,
        block_budgets=_budgets(args.block_budgets), rounds=args.rounds, allow_partial=args.allow_partial,
        max_errors=_max_errors(args.max_errors), refines=_refines(args.refine), frame=args.frame,
        supersample=args.supersample, converged_step=args.converged_step, classify=args.classify,
    )
    print(f"wrote {res.csv}, {res.timing_csv}, {res.markdown}" + "".join(f", {p}" for p in res.plots))
    print(res.headline[:1].upper() + res.headline[1:] + ".")
    if args.points is not None:
        from pathlib import Path

        return kind_command(args.points, "report")(args, args.points, Path(out) / "points")
    return 0
