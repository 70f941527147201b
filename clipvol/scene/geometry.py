"""The shape a clip render action draws: a region-of-interest box and up to six clip planes.

After OpenGL Volumizer's shape geometry (Bhaniramka & Demange 2002): the part of the volume that is drawn is the
intersection of an axis-aligned box and half-spaces ``a x + b y + c z + d >= 0`` (world
``(x, y, z)``). The selection culls bricks wholly outside it (never loaded, never drawn); the
shader discards samples outside it. Both read the same numbers, from :class:`Shape`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError

__all__ = ["Shape", "MAX_PLANES"]

MAX_PLANES = 6
#: stand-in for "no box" in :meth:`Shape.box_and_planes_arrays` (finite in float32)
NO_BOX = 1e30


@dataclass(frozen=True, slots=True)
class Shape:
    """A region of interest: ``box`` ``(lo_xyz, hi_xyz)`` or None, and ``planes`` ``(a, b, c, d)``.

    A point is inside when it lies in the box (bounds included) and ``a x + b y + c z + d >= 0``
    for every plane.
    """

    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    planes: tuple[tuple[float, float, float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.box is not None:
            try:
                lo, hi = (np.asarray(v, dtype=np.float64).reshape(-1) for v in self.box)
            except (TypeError, ValueError):
                raise ParameterError(f"box: expected (lo_xyz, hi_xyz) or None, got {self.box!r}") from None
            if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)):
                raise ParameterError(f"box: expected two finite (x, y, z) points, got {self.box!r}")
            if np.any(hi < lo):
                raise ParameterError(f"box: expected lo <= hi on every axis, got lo={tuple(lo)}, hi={tuple(hi)}")
            object.__setattr__(self, "box", (tuple(map(float, lo)), tuple(map(float, hi))))
        try:
            planes = np.asarray(self.planes, dtype=np.float64).reshape(-1, 4) if len(self.planes) else np.zeros((0, 4))
        except (TypeError, ValueError):
            raise ParameterError(f"planes: expected a sequence of (a, b, c, d), got {self.planes!r}") from None
        if planes.shape[0] > MAX_PLANES:
            raise ParameterError(f"planes: expected at most {MAX_PLANES} clip planes, got {planes.shape[0]}")
        if not np.all(np.isfinite(planes)):
            raise ParameterError(f"planes: expected finite (a, b, c, d), got {self.planes!r}")
        if np.any(np.all(planes[:, :3] == 0, axis=1)):
            raise ParameterError(f"planes: expected a non-zero normal (a, b, c) for every plane, got {self.planes!r}")
        object.__setattr__(self, "planes", tuple(tuple(map(float, p)) for p in planes))

    @property
    def is_everything(self) -> bool:
        """True when the shape culls nothing (no box, no planes)."""
        return self.box is None and not self.planes

    def boxes_outside(self, lo, hi) -> np.ndarray:
        """``(n,)`` bool: True for boxes ``[lo, hi]`` (``(n, 3)``) that lie wholly outside the shape.

        Conservative: False means the box may touch the shape (a box that only touches the shape
        box's boundary or a plane counts as inside).
        """
        lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
        hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
        out = np.zeros(lo.shape[0], dtype=bool)
        if self.box is not None:
            blo, bhi = np.asarray(self.box[0]), np.asarray(self.box[1])
            out |= np.any((hi < blo) | (lo > bhi), axis=1)
        if self.planes:
            p = np.asarray(self.planes)
            c, h = (lo + hi) * 0.5, (hi - lo) * 0.5
            reach = c @ p[:, :3].T + h @ np.abs(p[:, :3]).T + p[:, 3]
            out |= np.any(reach < 0, axis=1)
        return out

    def contains(self, points) -> np.ndarray:
        """Bool array of shape ``points.shape[:-1]``: which ``(x, y, z)`` points are inside."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.shape[-1:] != (3,):
            raise ParameterError(f"points: expected an array of shape (..., 3), got {pts.shape}")
        ok = np.ones(pts.shape[:-1], dtype=bool)
        if self.box is not None:
            ok &= np.all((pts >= self.box[0]) & (pts <= self.box[1]), axis=-1)
        for a, b, c, d in self.planes:
            ok &= pts[..., 0] * a + pts[..., 1] * b + pts[..., 2] * c + d >= 0
        return ok

    def box_and_planes_arrays(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Uniform-ready arrays ``(box (2, 3), planes (6, 4), n_planes)``, float64.

        Without a box, ``box`` is ``[-1e30, 1e30]`` on every axis. ``planes`` is padded to six
        rows with ``(0, 0, 0, 1)``, which every point satisfies, so a shader may test all six.
        """
        box = np.array([[-NO_BOX] * 3, [NO_BOX] * 3]) if self.box is None else np.array(self.box)
        planes = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (MAX_PLANES, 1))
        if self.planes:
            planes[: len(self.planes)] = self.planes
        return box, planes, len(self.planes)
