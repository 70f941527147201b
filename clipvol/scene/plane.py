"""A cutting plane through the volume: its frame, its pixel grid, and where it crosses brick boxes.

Why a module of its own, free of GL: the slice's selection (which bricks a plane crosses, how fine
near the point of interest), the slice render action, the CLI, the viewer's slice layout and the
tests' scipy reference all need the very same mapping from an image pixel to a world point.

Conventions (world vectors are ``(x, y, z)``, arrays ``(z, y, x)``):

* ``normal`` is the direction one looks along (like a camera's ``forward``); ``up`` points towards
  image row 0; ``right = normal x up`` towards the last column. Pixel ``(row r, column c)`` of a
  ``W x H`` image with pixel size ``p`` lies at
  ``origin + ((c + 0.5) - W / 2) * p * right + (H / 2 - (r + 0.5)) * p * up``: the origin is the
  image centre.
* Axis presets use the store's axis order and the radiological display of a DICOM-like (LPS)
  volume, where ``x`` runs towards the patient's left, ``y`` towards posterior and ``z`` towards
  superior: **axial** (normal ``+z``, up ``-y``) shows ``vol[k]`` as numpy prints it - rows follow
  ``+y`` (anterior at the top), columns ``+x`` (the patient's left on the image's right);
  **coronal** (normal ``+y``, up ``+z``) shows ``vol[:, j, :][::-1]`` - superior at the top,
  columns ``+x``; **sagittal** (normal ``-x``, up ``+z``) shows ``vol[:, :, i][::-1]`` - superior
  at the top, columns ``+y`` (anterior on the left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from .camera import _vec3 as _camera_vec3

__all__ = ["Plane", "AXES", "AXIS_LETTERS", "default_pixel_size", "default_size"]

#: preset name -> (array axis (0 = z, 1 = y, 2 = x), normal, up)
AXES = {
    "axial": (0, (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
    "coronal": (1, (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "sagittal": (2, (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
}
#: the 12 edges of a box as pairs of corner numbers (bit a of a corner number: high side of axis a)
_EDGES = np.array([(i, i | (1 << a)) for i in range(8) for a in range(3) if not i & (1 << a)], dtype=np.int64)
#: axis letter of ``--plane z=94`` -> preset
AXIS_LETTERS = {"z": "axial", "y": "coronal", "x": "sagittal"}


def _vec3(value, name: str) -> np.ndarray:
    """:func:`clipvol.scene.camera._vec3` (three finite numbers, else a ParameterError naming
    ``name``) as an array."""
    return np.array(_camera_vec3(value, name))


@dataclass(frozen=True, slots=True)
class Plane:
    """An oriented plane: ``origin`` (a point of it, the image centre), unit ``normal``, unit ``up``.

    ``up`` is made orthogonal to ``normal`` (its in-plane part); a zero normal, or an ``up``
    parallel to the normal, is a :class:`~clipvol.errors.ParameterError` naming the parameter.
    """

    origin: tuple[float, float, float]
    normal: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    _right: np.ndarray = field(init=False, repr=False, compare=False, default=None)

    def __post_init__(self) -> None:
        o = _vec3(self.origin, "origin")
        n = _vec3(self.normal, "normal")
        u = _vec3(self.up, "up")
        nn = float(np.linalg.norm(n))
        if not nn > 0:
            raise ParameterError(f"normal: expected a non-zero vector, got {tuple(n.tolist())}")
        n = n / nn
        u = u - (u @ n) * n
        nu = float(np.linalg.norm(u))
        if not nu > 1e-9 * max(1.0, float(np.linalg.norm(_vec3(self.up, "up")))):
            raise ParameterError(f"up: expected a vector not parallel to the normal {tuple(n.tolist())}, got {self.up!r}")
        u = u / nu
        object.__setattr__(self, "origin", tuple(o.tolist()))
        object.__setattr__(self, "normal", tuple(n.tolist()))
        object.__setattr__(self, "up", tuple(u.tolist()))
        r = np.cross(n, u)
        r.setflags(write=False)
        object.__setattr__(self, "_right", r)

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def through(cls, origin, normal, up=None) -> "Plane":
        """A plane through ``origin``; ``up`` defaults to the preset up of the axis nearest ``normal``."""
        n = _vec3(normal, "normal")
        if up is None:
            if not np.linalg.norm(n) > 0:
                raise ParameterError(f"normal: expected a non-zero vector, got {tuple(n.tolist())}")
            k = int(np.argmax(np.abs(n)))  # x, y or z
            up = {2: (0.0, -1.0, 0.0), 1: (0.0, 0.0, 1.0), 0: (0.0, 0.0, 1.0)}[k]
        return cls(tuple(_vec3(origin, "origin")), tuple(n), tuple(_vec3(up, "up")))

    @classmethod
    def axis(cls, pyramid, name: str, index: float | None = None) -> "Plane":
        """The ``axial`` / ``coronal`` / ``sagittal`` plane through level-0 voxel ``index`` of its axis.

        ``index`` defaults to the middle of the axis; it may be fractional but must lie in
        ``[0, n - 1]``. The origin is the volume's centre moved onto the plane.
        """
        if name not in AXES:
            raise ParameterError(f"axis: expected one of {', '.join(AXES)}, got {name!r}")
        a, normal, up = AXES[name]
        n = pyramid.shape[a]
        if index is None:
            index = (n - 1) / 2.0
        try:
            i = float(index)
        except (TypeError, ValueError):
            i = math.nan
        if not (0.0 <= i <= n - 1):
            raise ParameterError(f"index: expected 0..{n - 1} for the {name} axis ({'zyx'[a]}), got {index!r}")
        lo, hi = pyramid.volume_box()
        origin = (lo + hi) / 2.0
        origin[2 - a] = i * pyramid.spacing[a]
        return cls(tuple(origin), normal, up)

    def moved_through(self, point) -> "Plane":
        """This plane shifted along its normal to pass through ``point`` (same orientation; the image
        centre is the old one projected onto the new plane), as a point of interest places a slice."""
        p = _vec3(point, "point")
        o = np.asarray(self.origin)
        n = np.asarray(self.normal)
        return Plane(tuple((o + ((p - o) @ n) * n).tolist()), self.normal, self.up)

    # -- frame ----------------------------------------------------------------------------------
    @property
    def right(self) -> np.ndarray:
        """Unit ``normal x up``: towards the image's last column."""
        return self._right

    def signed_distance(self, points) -> np.ndarray:
        """``(n,)`` signed distances of world points ``(n, 3)`` from the plane (positive along the normal)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        return (p - np.asarray(self.origin)) @ np.asarray(self.normal)

    def crosses(self, lo, hi) -> np.ndarray:
        """``(n,)`` bool: the plane meets the closed box ``[lo, hi]`` (``(n, 3)`` each)."""
        lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
        hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
        c, h = (lo + hi) * 0.5, (hi - lo) * 0.5
        n = np.asarray(self.normal)
        return np.abs((c - np.asarray(self.origin)) @ n) <= h @ np.abs(n) * (1 + 1e-12) + 1e-12

    def box_polygon(self, lo, hi) -> np.ndarray:
        """The plane's intersection with the box ``[lo, hi]``: ``(k, 3)`` world points, ``k`` in 0 or 3..6.

        The vertices are in counter-clockwise order in the ``(right, up)`` frame, so the polygon is
        a triangle fan. Empty when the plane misses the box or only touches it on its negative side
        (a corner, an edge or a face: points exactly on the plane count as on its positive side,
        so boxes that tile space give polygons that tile the plane once).
        """
        pts, k = self.box_polygons(np.atleast_2d(lo), np.atleast_2d(hi))
        return pts[0, : k[0]]

    def box_polygons(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`box_polygon` of ``n`` boxes at once: ``(points (n, 6, 3), counts (n,))``."""
        lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
        hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
        sel = np.array([[(i >> a) & 1 for a in range(3)] for i in range(8)], dtype=bool)  # (8, 3) x, y, z
        corners = np.where(sel[None], hi[:, None, :], lo[:, None, :])  # (n, 8, 3)
        d = (corners - np.asarray(self.origin)) @ np.asarray(self.normal)  # (n, 8)
        ea, eb = _EDGES[:, 0], _EDGES[:, 1]
        da, db = d[:, ea], d[:, eb]  # (n, 12)
        cross = (da >= 0) != (db >= 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.where(cross, da / np.where(cross, da - db, 1.0), 0.0)
        p = corners[:, ea] + t[..., None] * (corners[:, eb] - corners[:, ea])  # (n, 12, 3)
        k = cross.sum(axis=1)
        cen = np.where(k[:, None] > 0, (p * cross[..., None]).sum(axis=1) / np.maximum(k, 1)[:, None], 0.0)
        rel = p - cen[:, None, :]
        ang = np.arctan2(rel @ np.asarray(self.up), rel @ self.right)
        ang = np.where(cross, ang, np.inf)
        order = np.argsort(ang, axis=1)[:, :6]
        out = np.take_along_axis(p, order[..., None], axis=1)
        k = np.where(k >= 3, k, 0)
        return out, k

    # -- pixels ---------------------------------------------------------------------------------
    def pixel_points(self, size, pixel_size: float) -> np.ndarray:
        """``(h, w, 3)`` world points of the pixel centres of a ``(w, h)`` image, row 0 at the top."""
        w, h = (int(v) for v in size)
        p = float(pixel_size)
        u = ((np.arange(w) + 0.5) - w / 2.0) * p
        v = (h / 2.0 - (np.arange(h) + 0.5)) * p
        return (np.asarray(self.origin) + u[None, :, None] * self.right + v[:, None, None] * np.asarray(self.up))

    def to_pixels(self, points, size, pixel_size: float) -> np.ndarray:
        """``(n, 2)`` image coordinates ``(column, row)`` (pixel centres at ``+0.5``) of world points."""
        w, h = (int(v) for v in size)
        rel = np.atleast_2d(np.asarray(points, dtype=np.float64)) - np.asarray(self.origin)
        c = rel @ self.right / float(pixel_size) + w / 2.0
        r = h / 2.0 - rel @ np.asarray(self.up) / float(pixel_size)
        return np.stack([c, r], axis=-1)

    def footprint(self, box_lo, box_hi) -> tuple[float, float, float, float]:
        """``(umin, umax, vmin, vmax)``: the in-plane extent (world units, relative to ``origin``) of
        the plane's intersection with the box; NaNs if the plane misses it."""
        poly = self.box_polygon(box_lo, box_hi)
        if not len(poly):
            return (math.nan,) * 4  # type: ignore[return-value]
        rel = poly - np.asarray(self.origin)
        u, v = rel @ self.right, rel @ np.asarray(self.up)
        return float(u.min()), float(u.max()), float(v.min()), float(v.max())

    def camera(self, size, pixel_size: float):
        """An orthographic :class:`~clipvol.scene.camera.Camera` that sees exactly this slice's pixels
        (looking along the normal, ``up`` to row 0): the selection's frustum and projected size."""
        from .camera import Camera

        w, h = (int(v) for v in size)
        p = float(pixel_size)
        if not (math.isfinite(p) and p > 0):
            raise ParameterError(f"pixel_size: expected a finite size > 0 (world units), got {pixel_size!r}")
        return Camera.orthographic(self.origin, self.normal, self.up, w * p, h * p, size=(w, h))


def default_pixel_size(pyramid, plane: Plane) -> float:
    """The level-0 voxel size seen in the plane: the smallest spacing of the two axes most in-plane."""
    sp = np.asarray(pyramid.spacing[::-1], dtype=np.float64)  # (x, y, z)
    n = np.abs(np.asarray(plane.normal))
    keep = np.argsort(n)[:2]
    return float(sp[keep].min())


def default_size(pyramid, plane: Plane, pixel_size: float, max_side: int = 4096) -> tuple[int, int]:
    """``(w, h)`` pixels that cover the plane's cut through the volume, centred on ``origin``."""
    lo, hi = pyramid.volume_box()
    umin, umax, vmin, vmax = plane.footprint(lo, hi)
    if math.isnan(umin):
        raise ParameterError(f"plane: expected a plane that meets the volume {tuple(lo)}..{tuple(hi)}, got {plane}")
    w = 2.0 * max(abs(umin), abs(umax)) / pixel_size
    h = 2.0 * max(abs(vmin), abs(vmax)) / pixel_size
    return (int(min(max_side, max(1, math.floor(w + 1e-6)))), int(min(max_side, max(1, math.floor(h + 1e-6)))))
