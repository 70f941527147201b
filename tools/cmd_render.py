"""Render one image of a store, a procedural volume or a .npy file to a PNG.

By default the frame is *converged*: the command waits until every brick the view wants is
loaded and drawn at its own level (``--no-wait`` renders whatever is resident after the first
pass). The clip-texture's centre of interest is the camera target, clamped into the volume.
Frame statistics (bricks per level, uploads, texture bytes, time per stage) go to stderr.

This module is the command's flags; the source's data kind draws it
(:func:`clipvol.tools.kind_cli.kind_command`: :func:`clipvol.tools.volume_cli.render` for a volume,
which calls :func:`clipvol.app.render_png.render_to_png`).
"""

from __future__ import annotations

import argparse
import math

from clipvol.scene.views import VIEW_CHOICES as VIEWS
from clipvol.tools.overlay_args import add_channel_arguments
from clipvol.tools.common_args import add_common_arguments
from clipvol.tools.render_args import add_render_arguments


def _triple(text: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(t) for t in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected three numbers x,y,z, got {text!r}")
    return v  # type: ignore[return-value]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a clipvol store / OME-Zarr directory or URL (s3://, https://, ...), procedural:NAME?size=N, "
                                  "a .npy file, or a NIfTI / DICOM folder / FILE.h5:/dataset / MRC input (bricked first into --store)")
    add_common_arguments(p, ("store",))
    p.add_argument("--out", "-o", required=True, help="output PNG")
    add_common_arguments(p, ("brick",))
    d = p.add_argument_group("data")
    d.add_argument("--t", type=int, default=None, help="time point of an OME-Zarr image with a t axis (default 0)")
    d.add_argument("--c", type=int, default=None, help="channel of an OME-Zarr image with a c axis (default 0)")
    add_channel_arguments(d)
    d.add_argument("--hide-labels", default=None, metavar="NAME:ID,ID",
                   help="hide the voxels of these label ids of the store's labels/NAME (from clipvol brick --labels)")
    v = p.add_argument_group("camera")
    v.add_argument("--view", choices=VIEWS, default="iso", type=str.lower,
                   help="the side the eye is on: anterior, posterior, left, right, superior, inferior for a store with a "
                        "patient frame (head up; front/back/side/top mean anterior/posterior/left/superior there), "
                        "front/back/side/top along the array's z/-z/x/y otherwise; iso from anterior-right-superior "
                        "(default iso)")
    v.add_argument("--eye", type=_triple, default=None,
                   help="eye position x,y,z (overrides --view) in the store's world frame (what clipvol info prints): "
                        "RAS millimetres for a store with a patient frame, the origin plus the array's axes scaled by "
                        "the spacing otherwise")
    v.add_argument("--target", type=_triple, default=None,
                   help="point looked at x,y,z, in the same coordinates as --eye (default: the volume centre)")
    v.add_argument("--up", type=_triple, default=None,
                   help="up direction x,y,z, in the same frame as --eye (default: superior for a patient frame, "
                        "-y otherwise: image rows follow +y)")
    v.add_argument("--no-labels", action="store_true", help="do not write the R/L, A/P, S/I letters at the image edges")
    v.add_argument("--fov", type=float, default=35.0, help="vertical field of view in degrees (perspective)")
    v.add_argument("--distance", type=float, default=None, help="eye distance from the target, in volume diagonals (default 1.6)")
    v.add_argument("--ortho", action="store_true", help="orthographic projection framing the volume")
    add_common_arguments(v, ("size",), size=dict(default=(512, 512), help="image size WxH (default 512x512)"))
    v.add_argument("--camera", default=None, metavar="FILE.json",
                   help="a camera saved by the viewer's C key (overrides --view/--eye/--target/--up/--fov/--ortho)")
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
    add_common_arguments(r, ("threads", "no_wait", "timeout"))
    r.add_argument("--tolerance", default="0.01", help="point stores: largest splat, a fraction of the screen (0.05), '5%%' or '12px' (default 0.01)")
    sl = p.add_argument_group("sort-last rendering on Dask (needs clipvol[dask])")
    sl.add_argument("--workers", type=int, default=None, metavar="N",
                   help="draw N spatially disjoint brick groups in N worker processes and composite them")
    sl.add_argument("--scheduler", default="processes", metavar="S",
                    help="with --workers: processes (a local cluster, default) or tcp://HOST:PORT of a dask.distributed scheduler")
    add_common_arguments(r, ("allow_partial",))
    add_common_arguments(p, ("cut", "remote", "unverified"))


def run(args) -> int:
    from clipvol.tools.kind_cli import kind_command

    return kind_command(args.source, "render")(args)  # clipvol.tools.volume_cli.render for a volume
