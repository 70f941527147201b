"""``--crop``, ``--crop-voxels`` and ``--clip-plane`` (repeatable) for ``clipvol render``, ``view`` and ``slice``.

One argument group each command adds with :func:`add_cut_arguments` and turns into the renderer's
:class:`~clipvol.scene.geometry.Shape` with :func:`shape_from_args`; the numbers are in the store's
world frame (what ``clipvol info`` prints) or in level-0 voxels, converted by
:mod:`clipvol.scene.cut`. Only bricks that meet the cut are selected, loaded and drawn.
"""

from __future__ import annotations

import math

from clipvol.errors import ParameterError

__all__ = ["add_cut_arguments", "parse_crop", "parse_voxel_ranges", "parse_crop_voxels", "parse_clip_plane", "shape_from_args"]


def add_cut_arguments(p) -> None:
    """Add the cut group to ``p`` (a parser or an argument group's parent parser)."""
    g = p.add_argument_group("cut the volume open")
    g.add_argument("--crop", default=None, metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="draw only the box between two opposite corners in world units (the frame clipvol info "
                        "prints: patient RAS+ mm for NIfTI/DICOM), x,y,z")
    g.add_argument("--crop-voxels", default=None, metavar="X0:X1,Y0:Y1,Z0:Z1",
                   help="draw only these level-0 voxels (stop exclusive, an empty side: the whole axis)")
    g.add_argument("--clip-plane", action="append", default=[], metavar="X,Y,Z,NX,NY,NZ",
                   help="keep the side of the plane through world point X,Y,Z that the normal NX,NY,NZ points to "
                        "(repeatable, at most 6)")


def _numbers(text: str, n: int, flag: str, form: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ParameterError(f"{flag}: expected {n} numbers {form}, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ParameterError(f"{flag}: expected {n} finite numbers {form}, got {text!r}")
    return vals


def parse_crop(text: str) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """``"x0,y0,z0,x1,y1,z1"`` -> two world corners."""
    v = _numbers(text, 6, "--crop", "X0,Y0,Z0,X1,Y1,Z1")
    return v[:3], v[3:]  # type: ignore[return-value]


def parse_voxel_ranges(text: str, shape0, flag: str = "--crop-voxels") -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """``"x0:x1,y0:y1,z0:z1"`` -> ``(start, stop)`` in voxels of level 0, ``(z, y, x)`` like the array
    (empty sides: the axis's ends); the one parser of ``--crop-voxels`` and ``clipvol export --box``
    (``flag`` names it in errors). Typed x,y,z as every coordinate of the CLI, world or voxel.
    Bounds are the caller's: a crop may reach past the volume, an export may not."""
    parts = text.split(",")
    if len(parts) != 3:
        raise ParameterError(f"{flag}: expected X0:X1,Y0:Y1,Z0:Z1 (three ranges), got {text!r}")
    start, stop = [], []
    for part, n, axis in zip(parts[::-1], shape0, "zyx"):  # typed x,y,z like every coordinate; kept z,y,x
        a, sep, b = part.partition(":")
        if not sep:
            raise ParameterError(f"{flag}: expected START:STOP for {axis}, got {part!r}")
        try:
            start.append(int(a) if a.strip() else 0)
            stop.append(int(b) if b.strip() else int(n))
        except ValueError:
            raise ParameterError(f"{flag}: expected integer voxel ranges X0:X1,Y0:Y1,Z0:Z1, got {part!r} for {axis}") from None
    return tuple(start), tuple(stop)  # type: ignore[return-value]


def parse_crop_voxels(text: str, shape0) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """``--crop-voxels "x0:x1,y0:y1,z0:z1"`` -> ``(start, stop)`` of level 0, z,y,x (:func:`parse_voxel_ranges`)."""
    return parse_voxel_ranges(text, shape0, "--crop-voxels")


def parse_clip_plane(text: str) -> tuple[float, ...]:
    """``"x,y,z,nx,ny,nz"`` -> a world point and normal."""
    return _numbers(text, 6, "--clip-plane", "X,Y,Z,NX,NY,NZ")


def shape_from_args(args, loader):
    """The :class:`~clipvol.scene.geometry.Shape` of ``args``' cut for ``loader``'s store, or None."""
    from clipvol.scene.cut import cut_shape

    crop = getattr(args, "crop", None)
    crop_voxels = getattr(args, "crop_voxels", None)
    planes = getattr(args, "clip_plane", None) or []
    if crop is None and crop_voxels is None and not planes:
        return None
    pyr = loader.pyramid
    return cut_shape(pyr, getattr(loader, "frame", None),
                     crop=parse_crop(crop) if crop is not None else None,
                     crop_voxels=parse_crop_voxels(crop_voxels, pyr.shape) if crop_voxels is not None else None,
                     clip_planes=[parse_clip_plane(t) for t in planes])
