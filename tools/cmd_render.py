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

from clipvol.tools.common_args import add_common_arguments, parse_xyz
from clipvol.tools.overlay_args import add_channel_arguments
from clipvol.tools.render_args import add_render_arguments


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


def run(args) -> int:
    from clipvol.tools.kind_cli import kind_command

    return kind_command(args.source, "render")(args)  # clipvol.tools.volume_cli.render for a volume
