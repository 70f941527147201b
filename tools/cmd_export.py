"""Take a region out of a store as .npy, .tif, .nii / .nii.gz or .zarr, with its place in the world.

``clipvol export STORE --box x0:x1,y0:y1,z0:z1 --level K --out region.nii.gz`` writes the voxels of
level ``K`` that overlap the box (given in voxels of level 0, so the same box works at every level);
``--box-world x0,y0,z0,x1,y1,z1`` gives the box in world units instead (the frame ``clipvol info``
prints). The region streams brick by brick through the verified loader into a memory-mapped file
under a temporary name, renamed when complete; see :mod:`clipvol.app.export` for what each format
keeps of the geometry.
"""

from __future__ import annotations

import argparse

from clipvol.errors import ParameterError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("store", metavar="STORE",
                        help="a clipvol store, OME-Zarr image, channel set / time series root, .npy, procedural:... URL, "
                             "or a NIfTI / DICOM / HDF5 / MRC file (bricked once into ./NAME.zarr, as `view` does)")
    g = parser.add_mutually_exclusive_group(required=True)
    g.add_argument("--box", metavar="X0:X1,Y0:Y1,Z0:Z1",
                   help="the region in voxels of level 0, x,y,z like every coordinate (stop exclusive; an empty side "
                        "means the whole axis, e.g. 0:128,:,10:50)")
    g.add_argument("--box-world", metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="the region in world units (two opposite corners x,y,z, the store's frame as `clipvol info` "
                        "prints it); the voxels whose centres lie inside are written")
    from clipvol.tools.common_args import add_common_arguments
    from clipvol.tools.render_args import add_render_arguments

    add_render_arguments(parser, ("level",))
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="region.npy (geometry in region.npy.json), region.tif, region.nii, region.nii.gz "
                             "(NIfTI affine) or region.zarr (a clipvol store, OME scale/translation)")
    add_common_arguments(parser, ("c", "t"))
    add_common_arguments(parser, ("store",), store=dict(dest="brick_store", metavar="DIR"))
    add_common_arguments(parser, ("overwrite", "quiet"))
    add_common_arguments(parser, ("unverified", "remote"))


def parse_box(text: str, shape0) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """``--box "x0:x1,y0:y1,z0:z1"`` -> ``(start, stop)`` (z, y, x) in voxels of level 0, inside the volume."""
    from clipvol.tools.cut_args import parse_voxel_ranges

    start, stop = parse_voxel_ranges(text, shape0, "--box")
    for lo, hi, n, axis in zip(start, stop, shape0, "zyx"):
        if not 0 <= lo < hi <= n:
            raise ParameterError(f"--box: {axis} range {lo}:{hi}: expected 0 <= start < stop <= {n} (level 0 is "
                                 f"{shape0[2]}x{shape0[1]}x{shape0[0]} voxels, x, y, z)")
    return start, stop


def parse_world_box(text: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``"x0,y0,z0,x1,y1,z1"`` -> two world corners."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise ParameterError(f"--box-world: expected six numbers X0,Y0,Z0,X1,Y1,Z1, got {text!r}") from None
    if len(vals) != 6:
        raise ParameterError(f"--box-world: expected six numbers X0,Y0,Z0,X1,Y1,Z1, got {len(vals)} in {text!r}")
    return tuple(vals[:3]), tuple(vals[3:])


def run(args: argparse.Namespace) -> int:
    from clipvol.app.export import export_region, output_format, region_from_voxels, region_from_world
    from clipvol.app.volume_access import open as open_volume

    from clipvol.bricking.output_guard import check_not_input

    output_format(args.out)  # a bad name fails before anything is opened or bricked
    check_not_input(args.out, [args.store], "--out")  # never the input, a folder holding it, or a path inside it
    from clipvol.app.autobrick import bricked_source

    from clipvol.tools.remote_args import check_trust, remote_kwargs

    kwargs = remote_kwargs(args)
    source = bricked_source(args.store, args.brick_store, log=(lambda line: None) if args.quiet else print)
    vol = open_volume(source, **kwargs)
    member = []
    for name in vol.lead_axes:
        v = getattr(args, name)
        n = vol.lead_shape[vol.lead_axes.index(name)]
        if v is None:
            if n > 1:
                raise ParameterError(f"--{name}: {args.store} has {n} {'channels' if name == 'c' else 'time steps'}; "
                                     f"name one with --{name} 0..{n - 1}")
            v = 0
        if not 0 <= v < n:
            raise ParameterError(f"--{name}: expected 0..{n - 1} for {args.store}, got {v}")
        member.append(v)
    for name in ("c", "t"):
        if getattr(args, name) is not None and name not in vol.lead_axes:
            raise ParameterError(f"--{name}: {args.store} has no {name!r} axis (axes {', '.join(vol.axes)})")
    check_trust(vol.member(tuple(member)), args, "export")  # an unverified store only with --unverified
    if args.box is not None:
        start, stop = parse_box(args.box, vol.levels[0].shape)
        region = region_from_voxels(vol, start, stop, args.level or 0)
    else:
        a, b = parse_world_box(args.box_world)
        region = region_from_world(vol, a, b, args.level or 0)
    geom = export_region(vol, region, args.out, member=member, overwrite=args.overwrite, progress=not args.quiet,
                         inputs=[args.store])
    if not args.quiet:
        z, y, x = region.shape
        corner = [round(float(v), 6) for v in (geom["affine"][0][3], geom["affine"][1][3], geom["affine"][2][3])]
        print(f"wrote {args.out}: level {region.level} voxels {region.start}..{region.stop} (z, y, x), {z}x{y}x{x} "
              f"{vol.dtype}, voxel size {', '.join(f'{s:g}' for s in geom['spacing_zyx'])} {vol.unit or ''} (z, y, x); "
              f"voxel 0 at world {corner} (x, y, z)")
    return 0
