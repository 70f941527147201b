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
(LaMar, Hamann & Joy, "Multiresolution cutting planes"), and on a store with summary tables coarser
still where the tables show the coarser data looks the same under the slice's colours
(``--exact-tol``, :mod:`clipvol.scene.slice_exact`); ``--level 0`` is full resolution
everywhere. Outputs: a PNG (grey ``--window C,W`` or a ``--tf`` colour map), the float32 values
(``--npy``, NaN outside the volume) and statistics (``--stats``, JSON; with the image edges'
anatomical labels, R/L A/P S/I, when the store records its patient frame). Outputs are written
to a temporary name and renamed when complete.

This module is the command's flags; the source's data kind draws the plane
(:func:`clipvol.tools.kind_cli.kind_command`: :func:`clipvol.tools.volume_cli.slice` for a volume,
which calls :func:`clipvol.app.slice_files.slice_to_files`; the flags' plane is
:func:`clipvol.tools.plane_args.plane_from_args`).
"""

from __future__ import annotations

import argparse

from .common_args import add_common_arguments, add_old_spelling, parse_xyz
from .render_args import add_render_arguments


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
    r.add_argument("--exact-tol", default=None, metavar="DELTA_E",
                   help="with --poi, on a store with summary tables: draw a coarser brick where every voxel beneath "
                        "it stays within this CIELUV Delta E of level 0 under the slice's colours (default 4, under "
                        "the Delta E of 6 a reader sees; 0: only where nothing changes); 'off': by distance alone")
    add_common_arguments(r, ("brick", "memory_budget"))
    add_render_arguments(r, ("texture_budget", "classify"))
    add_common_arguments(r, ("threads", "no_wait", "timeout"))
    add_common_arguments(p, ("remote", "cut", "unverified"))
    add_common_arguments(r, ("allow_partial",))


def run(args) -> int:
    from clipvol.tools.kind_cli import kind_command

    return kind_command(args.source, "slice")(args)  # clipvol.tools.volume_cli.slice for a volume
