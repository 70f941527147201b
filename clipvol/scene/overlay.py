"""Overlays of co-registered volumes: a second (third, ...) store drawn in the same ray cast as the primary.

A neuroscientist's statistical map over the T1 scan, a dose over a CT: each volume keeps its own
shape, voxel size and origin (OME-Zarr ``scale`` + ``translation``; ``clipvol brick --origin``),
its own transfer function (thresholded, diverging for signed data), and is sampled at the *same
world point* as the primary at every sample of the primary's rays (Bhaniramka & Demange's
Volumizer composes several volumes in one shader the same way).

Design (pragmatic, documented in ``docs/rendering.md``)
-------------------------------------------------------
* An overlay is small beside the primary (a statistical map is a few MB): it is drawn from **one
  level**, the finest whose whole volume fits the overlay's ``texture_budget`` (and GL's largest 3-D
  texture), read once from its loader into one float32 texture. It is not paged around a centre.
* The primary's rays carry it: an overlay shows only inside the primary's volume box, on the
  primary's sample lattice (step and per-level opacity correction of the primary; the overlay's
  table opacity is per the primary's level-0 smallest voxel, like the primary's own), refined
  where the primary's step at its drawn level is longer than the overlay's own (the same step
  fraction of the overlay's smallest voxel): ``n`` sub-samples per primary sample, each with its
  opacity corrected for ``1/n`` of the step, so a coarse primary level never samples a finer map
  every few of its voxels (which shows as stair-step rings on a saturated blob).
* The operator at each sample: the overlays' premultiplied colours *over* the primary's, the first
  overlay on top, then the whole sample composited front to back under what the ray holds.
  Equivalently: for each sample, ``under(acc, overlay_0)``, ``under(acc, overlay_1)``, ...,
  ``under(acc, primary)`` with ``under(acc, c) = acc + (1 - acc.a) * (c.a * c.rgb, c.a)``.
* Outside its own box (voxel coordinates ``[-0.5, n - 0.5]`` per axis) an overlay is transparent;
  inside, clamp-to-edge trilinear over its 8 neighbouring voxels. ``sampling="classified"`` (the
  default, pre-classification): each of the 8 voxels is looked up in the table first and their
  premultiplied colours are blended with the trilinear weights, so between a saturated voxel and a
  zero one lies a half-transparent saturated colour. ``sampling="interpolated"`` (post-classification,
  like the primary): the value is interpolated, then looked up. On a statistical map of the clinical
  kind (70 % zeros outside a mask, plateaus clipped at the window's end, voxel-jagged edges) the
  interpolated value of a ray grazing a vertical step stays for many samples in the ramp between
  plateau and zero, which a diverging table colours pale: thin light lines in a circuit-board pattern
  through the blobs. Classifying first shows the voxels' own colours (Engel, Kraus and Ertl,
  "High-Quality Pre-Integrated Volume Rendering Using Hardware-Accelerated Pixel Shading", 2001,
  discuss both orders). Non-finite overlay voxels are transparent: ``interpolated`` makes the samples
  that touch them transparent, ``classified`` gives them zero weight of colour and opacity.
* A **label overlay** (a segmentation, ``tf`` a :class:`~clipvol.scene.label_colors.LabelColors`)
  is sampled nearest: the id of the voxel whose cell holds the point (``texelFetch``), looked up in
  a per-id table (the ids present are numbered on the CPU, so any integer ids fit), its opacity
  corrected for the primary's step in the shader. Opacity 0 hides a label.

Geometry: each store's level-0 voxel index maps to the world by its voxel-to-world affine (the
NIfTI / DICOM / MRC affine a store records, :class:`~clipvol.bricking.worldframe.WorldFrame`; else
its spacing and ``origin``, ``clipvol brick --origin``), a level's voxels by its scale and
translation. The primary is drawn in its own array axes (voxel ``i`` at ``i * spacing``); an overlay
is sampled through the chain *primary drawing frame -> world -> overlay voxel -> texture*
(:func:`overlay_texture_transform`), one 4x4 matrix per overlay and frame. An overlay stored
flipped (LAS under RAS) or with permuted axes is then drawn exactly (a signed permutation:
voxel centres onto voxel centres); a rotated or sheared one is resampled trilinearly at each ray
sample in the shader. Overlays in another unit, in another kind of world (a patient frame under a
non-anatomical one), or not overlapping the primary's box are refused with a
:class:`~clipvol.errors.ParameterError` naming the overlay and what differs.

This module is pure numpy (the GL side is :mod:`clipvol.render.overlay_binding`).

References
----------
* P. Bhaniramka and Y. Demange, "OpenGL Volumizer: A Toolkit for High Quality Volume Rendering of
  Large Data Sets", Proc. IEEE/ACM Symposium on Volume Visualization and Graphics, 2002 (several
  volumes and their lookup tables in one volumetric shader).
* T. Porter and T. Duff, "Compositing Digital Images", SIGGRAPH 1984 (the *over* operator).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ClipvolError, ParameterError
from ..units import parse_bytes
from .label_colors import LabelColors
from .transfer import TransferFunction

__all__ = ["Overlay", "store_origin", "store_unit", "overlay_level", "voxel_to_world", "overlay_texture_transform",
           "overlay_voxel",
           "read_level", "label_indices",
           "overlay_box", "cull_outside",
           "check_overlay", "MAX_OVERLAYS", "DEFAULT_OVERLAY_BUDGET", "OVERLAY_SAMPLINGS"]

#: most overlays one frame composites (each takes two texture units and one shader block)
MAX_OVERLAYS = 3
#: default texture budget of one overlay (bytes of its float32 texture)
DEFAULT_OVERLAY_BUDGET = 64 << 20
#: how a (non-label) overlay is sampled: its voxels classified then interpolated (default), or the reverse
OVERLAY_SAMPLINGS = ("classified", "interpolated")


def store_origin(loader) -> np.ndarray:
    """World ``(z, y, x)`` of a loader's voxel 0 beyond its levels' translations (a clipvol store's
    ``origin``; 0 for loaders that do not say)."""
    o = getattr(loader, "origin", None)
    return np.zeros(3) if o is None else np.asarray(o, dtype=np.float64).reshape(3)


def store_unit(loader) -> str | None:
    """The spatial unit a loader declares (``"millimeter"``), or None when it does not say."""
    u = getattr(loader, "unit", None)
    return str(u) if u else None


@dataclass(frozen=True, eq=False)
class Overlay:
    """A co-registered volume drawn over the primary in the same ray cast.

    Parameters
    ----------
    loader : Loader
        The overlay's data (any clipvol loader: a store, ``.npy``, a procedural volume).
    tf : TransferFunction, LabelColors or str
        Its transfer function, or a preset name (``"diverging"``: blue-grey-red, transparent around
        the centre; the window is then made symmetric about 0 from the data's range), or for a label
        volume (integer ids) a :class:`~clipvol.scene.label_colors.LabelColors`: each sample takes
        the id of the voxel holding the point (nearest, never interpolated) and that id's colour.
    origin : (z, y, x), optional
        World position of voxel 0 (default: the loader's own, ``clipvol brick --origin``).
    unit : str, optional
        Spatial unit (default: the loader's own); an overlay in another unit than the primary is refused.
    texture_budget : int or str
        Bytes its one float32 texture may take; the finest level that fits is drawn.
    name : str
        What errors call it (default: the loader's path, else ``overlay``).
    frame : WorldFrame, optional
        Its voxel-to-world affine (default: the loader's own). A label image of a store shares the
        store's frame (OME image-label) without recording it: ``--label-overlay`` passes the image's.
    sampling : {"classified", "interpolated"}
        ``"classified"`` (default): the 8 neighbouring voxels are classified by the table, then their
        premultiplied colours interpolated (no pale ramp at a plateau's jagged edge);
        ``"interpolated"``: the value is interpolated, then classified (as the primary is). A label
        overlay is always nearest.
    """

    loader: object
    tf: object = "diverging"
    origin: tuple | None = None
    unit: str | None = None
    texture_budget: int | str = DEFAULT_OVERLAY_BUDGET
    name: str = ""
    frame: object = None
    sampling: str = "classified"

    @property
    def labels(self) -> bool:
        """True for a label overlay (nearest ids through a :class:`LabelColors`)."""
        return isinstance(self.tf, LabelColors)

    def __post_init__(self) -> None:
        s = object.__setattr__
        if not (hasattr(self.loader, "pyramid") and hasattr(self.loader, "read_brick")):
            raise ParameterError(f"overlay: expected a loader (with pyramid and read_brick), got {type(self.loader).__name__}")
        name = self.name or str(getattr(self.loader, "path", "") or "overlay")
        s(self, "name", name)
        if self.sampling not in OVERLAY_SAMPLINGS:
            raise ParameterError(f"overlay {name}: sampling: expected one of {', '.join(OVERLAY_SAMPLINGS)}, "
                                 f"got {self.sampling!r}")
        pyr = self.loader.pyramid
        tf = self.tf
        if isinstance(tf, LabelColors):
            if pyr.dtype.kind not in "iub":
                raise ParameterError(f"overlay {name}: label colours: expected an integer label volume, got dtype {pyr.dtype}")
        elif isinstance(tf, str):
            if tf not in TransferFunction.names():
                raise ParameterError(f"overlay {name}: transfer function: expected one of "
                                     f"{', '.join(TransferFunction.names())} or a TransferFunction, got {tf!r}")
            rng = None
            if tf == "diverging":
                lo, hi = pyr.value_range
                r = max(abs(lo), abs(hi)) or 1.0
                rng = (-r, r)
            tf = TransferFunction.preset(tf, value_range=rng)
        elif not hasattr(tf, "table") or not hasattr(tf, "window"):
            raise ParameterError(f"overlay {name}: tf: expected a preset name or a TransferFunction, got {type(tf).__name__}")
        s(self, "tf", tf)
        if self.origin is None:
            s(self, "origin", tuple(float(v) for v in store_origin(self.loader)))
        else:
            o = tuple(float(v) for v in np.asarray(self.origin, dtype=np.float64).reshape(-1))
            if len(o) != 3 or not all(np.isfinite(o)):
                raise ParameterError(f"overlay {name}: origin: expected three finite numbers z,y,x, got {self.origin!r}")
            s(self, "origin", o)
        s(self, "unit", self.unit or store_unit(self.loader))
        if self.frame is None:
            s(self, "frame", getattr(self.loader, "frame", None))
        s(self, "texture_budget", parse_bytes(self.texture_budget, f"overlay {name}: texture_budget"))


def label_indices(data: np.ndarray, colors: LabelColors) -> tuple[np.ndarray, np.ndarray]:
    """``(index, table)``: per voxel the index of its id among the ids present (float32, exact below
    2**24 distinct ids) and per index the id's straight RGBA ``(n, 4)``."""
    ids, inv = np.unique(data, return_inverse=True)
    if len(ids) >= 1 << 24:
        raise ParameterError(f"label overlay: expected fewer than {1 << 24} distinct ids, got {len(ids)}")
    return inv.reshape(data.shape).astype(np.float32), colors.table(ids)


def overlay_level(pyramid, budget: int, max_size: int = 2048, itemsize: int = 4) -> int:
    """The finest level whose whole volume fits ``budget`` bytes and ``max_size`` texels per axis."""
    for L, lv in enumerate(pyramid.levels):
        if int(np.prod(lv.shape)) * itemsize <= budget and max(lv.shape) <= max_size:
            return L
    return pyramid.num_levels - 1


def voxel_to_world(loader, origin=None, frame=None) -> np.ndarray:
    """``(4, 4)``: a loader's level-0 voxel index ``(x, y, z, 1)`` to its world position.

    A store with a recorded affine (NIfTI, DICOM, MRC: :class:`~clipvol.bricking.worldframe.WorldFrame`)
    uses it, moved to ``origin`` (z, y, x along its axes) when one is given that differs from the
    store's; any other loader is axis-aligned: its spacing, and voxel 0 at ``origin`` (default the
    loader's own, :func:`store_origin`). ``frame`` replaces the loader's own affine.
    """
    frame = getattr(loader, "frame", None) if frame is None else frame
    own = store_origin(loader)
    o = own if origin is None else np.asarray(origin, dtype=np.float64).reshape(3)
    if frame is not None:
        if np.allclose(o, frame.origin, rtol=0, atol=1e-9 * max(1.0, float(np.abs(o).max()))):
            return frame.matrix
        return frame.with_origin(o).matrix
    m = np.eye(4)
    m[:3, :3] = np.diag(np.asarray(loader.pyramid.spacing, dtype=np.float64)[::-1])
    m[:3, 3] = o[::-1]
    return m


def _render_to_world(primary_loader) -> np.ndarray:
    """``(4, 4)``: a position in the primary's drawing frame (voxel ``i`` at ``i * spacing`` along its
    array axes, :meth:`~clipvol.bricking.pyramid.Pyramid.volume_box`) to the world."""
    sp = np.asarray(primary_loader.pyramid.spacing, dtype=np.float64)[::-1]
    return voxel_to_world(primary_loader) @ np.diag(np.append(1.0 / sp, 1.0))


def overlay_texture_transform(overlay: Overlay, level: int, primary_loader) -> np.ndarray:
    """``(4, 4)``: a position in the primary's drawing frame to the texture coordinate (``[0, 1]``
    across the cells, x, y, z) of the overlay's ``level``.

    The chain is the primary's voxel-to-world affine, the overlay's world-to-voxel (its inverse
    affine), then the level's voxel grid (its scale and translation). A flip or a permutation of
    the overlay's axes is a signed permutation in the 3x3 part, so voxel centres land on voxel
    centres and nothing is resampled; a rotation or shear is resampled, trilinearly, at each ray
    sample by the shader (``c = a * p + b``).
    """
    pyr = overlay.loader.pyramid
    lv, l0 = pyr.levels[level], pyr.levels[0]
    s0 = np.asarray(l0.scale, dtype=np.float64)[::-1]
    sl = np.asarray(lv.scale, dtype=np.float64)[::-1]
    off = (np.asarray(lv.translation, dtype=np.float64) - np.asarray(l0.translation, dtype=np.float64))[::-1] / s0
    shape = np.asarray(lv.shape, dtype=np.float64)[::-1]
    grid = np.eye(4)  # level-0 voxel index -> texture coordinate of the level
    grid[:3, :3] = np.diag(s0 / sl / shape)
    grid[:3, 3] = (-off * s0 / sl + 0.5) / shape
    inv_o = np.linalg.inv(voxel_to_world(overlay.loader, overlay.origin, overlay.frame))
    return grid @ inv_o @ _render_to_world(primary_loader)


def overlay_voxel(overlay: Overlay, level: int, primary_loader) -> float:
    """The smallest voxel edge of the overlay's ``level``, in the primary's drawing frame (world
    units): the columns of the inverse of :func:`overlay_texture_transform`'s 3x3 part, over the
    level's shape, are its voxel's edges (any affine: a rotated or sheared grid included). Times the
    step fraction it is the overlay's own sample spacing, which the shader never exceeds."""
    m = overlay_texture_transform(overlay, level, primary_loader)
    shape = np.asarray(overlay.loader.pyramid.levels[level].shape, dtype=np.float64)[::-1]
    edges = np.linalg.inv(m[:3, :3]) / shape
    return float(np.linalg.norm(edges, axis=0).min())


def overlay_box(overlay: Overlay, primary_loader) -> tuple[np.ndarray, np.ndarray]:
    """World box ``(lo, hi)`` ``(x, y, z)`` in the primary's drawing frame that holds the overlay's
    level-0 cells (their corners' bounding box, for a rotated overlay larger than the cells)."""
    n = np.asarray(overlay.loader.pyramid.shape, dtype=np.float64)[::-1]
    corners = np.array([[(-0.5, n[a] - 0.5)[(k >> a) & 1] for a in range(3)] for k in range(8)])
    m = np.linalg.inv(_render_to_world(primary_loader)) @ voxel_to_world(overlay.loader, overlay.origin, overlay.frame)
    pts = corners @ m[:3, :3].T + m[:3, 3]
    return pts.min(axis=0), pts.max(axis=0)


def check_overlay(overlay: Overlay, primary_loader) -> None:
    """Refuse an overlay that cannot be placed on the primary: another unit, or no overlap in the world."""
    name = overlay.name
    pu = store_unit(primary_loader)
    if pu is not None and overlay.unit is not None and pu != overlay.unit:
        raise ParameterError(f"overlay {name}: expected the primary's unit {pu!r}, got {overlay.unit!r} "
                             "(convert the spacing, e.g. clipvol brick --spacing ... --unit ...)")
    fp, fo = getattr(primary_loader, "frame", None), overlay.frame
    kp, ko = (getattr(f, "frame", "") if f is not None else "" for f in (fp, fo))
    if kp != ko and fp is not None and fo is not None:
        raise ParameterError(f"overlay {name}: expected the primary's world frame {kp or 'non-anatomical'!r}, got "
                             f"{ko or 'non-anatomical'!r} (a patient-frame scan and a non-anatomical volume share no "
                             "coordinates; brick the overlay from its NIfTI/DICOM so it records the patient frame)")
    lo, hi = overlay_box(overlay, primary_loader)
    plo, phi = primary_loader.pyramid.volume_box()
    if np.any(np.minimum(hi, phi) <= np.maximum(lo, plo)):
        to_world = _render_to_world(primary_loader)
        w = lambda p: p @ to_world[:3, :3].T + to_world[:3, 3]  # noqa: E731
        raise ParameterError(f"overlay {name}: expected its world box to overlap the primary's, got overlay "
                             f"{_box(*_world_box(w, lo, hi))} and primary {_box(*_world_box(w, plo, phi))} (x, y, z, world)")


def _world_box(w, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[(lo[a], hi[a])[(k >> a) & 1] for a in range(3)] for k in range(8)])
    pts = w(corners)
    return pts.min(axis=0), pts.max(axis=0)


def cull_outside(transparent, pyramid, boxes):
    """The primary's transparent-brick filter ``transparent(level, idx) -> mask`` restricted to bricks
    whose node box (widened by one voxel of their level: the sampling footprint) is clear of every
    overlay box ``(lo, hi)`` (x, y, z, the primary's frame): a brick the primary's table makes
    transparent still carries the rays that sample an overlay, so only those far from every overlay
    are culled. None stays None."""
    if transparent is None:
        return None
    boxes = [(np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)) for lo, hi in boxes]

    def f(level: int, idx) -> np.ndarray:
        idx = np.asarray(idx).reshape(-1, 3)
        mask = np.array(transparent(level, idx), dtype=bool, copy=True)
        lo, hi = pyramid.node_box(level, idx)
        vox = np.asarray(pyramid.levels[level].scale, dtype=np.float64)[::-1]
        for blo, bhi in boxes:
            mask &= ~np.all((lo - vox < bhi) & (hi + vox > blo), axis=-1)
        return mask

    return f


def _box(lo, hi) -> str:
    return "[" + ", ".join(f"{a:g}..{b:g}" for a, b in zip(lo, hi)) + "]"


def read_level(loader, level: int, dtype=np.float32, failed=None) -> np.ndarray:
    """The whole ``level`` of ``loader`` as one ``(z, y, x)`` array (``dtype``; None: the data's), brick by brick.

    ``failed`` (not None): a brick whose read raises a :class:`~clipvol.errors.ClipvolError`
    (damaged, missing, unreachable) is filled with it instead of ending the read."""
    pyr = loader.pyramid
    shape = pyr.levels[level].shape
    B = pyr.brick_shape
    out = np.empty(shape, dtype=dtype or pyr.dtype)
    for idx in np.ndindex(*pyr.grid(level)):
        sl = tuple(slice(i * b, min((i + 1) * b, n)) for i, b, n in zip(idx, B, shape))
        try:
            brick = np.asarray(loader.read_brick(level, idx))
        except ClipvolError:
            if failed is None:
                raise
            out[sl] = failed
            continue
        out[sl] = brick[tuple(slice(0, s.stop - s.start) for s in sl)]
    return out
