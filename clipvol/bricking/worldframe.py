"""Where a volume sits in its scanner's or instrument's world: the voxel-to-world affine of a source.

Medical and microscopy files carry their geometry (NIfTI's ``sform``/``qform``, DICOM's image
position and orientation, MRC's voxel size and origin) and a user must not retype it. clipvol
keeps it as one 4x4 affine per store, in the convention of NIfTI (Cox et al., *A (Sort of) New
Image Data Format Standard: NIfTI-1*, 2004): the matrix maps a voxel index ``(x, y, z)`` — the
array's axes in world order, i.e. ``(i, j, k) = (x, y, z)`` for a clipvol array ``a[z, y, x]`` —
to world coordinates. For anatomical data the world frame is **RAS+** (x to the patient's Right
→ Left is *negative*, y to Anterior, z to Superior); DICOM's LPS+ patient frame is converted when
read. ``frame`` is ``"RAS"`` for patient coordinates and ``""`` for non-anatomical data (HDF5, MRC).

From the affine follow the values an OME-Zarr 0.5 reader understands — per-axis ``scale`` (the
voxel size, the lengths of the affine's columns) and ``translation`` — and the rotation that OME
0.5 cannot say, which stays in clipvol's attributes. The translation is the world position of voxel
0 expressed along the array's own axes, ``R^-1 · t`` for the affine ``[R·S | t]``: the renderer
draws in that rotated frame (array axes), so positions and distances are in world units, and
:mod:`clipvol.scene.orientation` labels the screen directions with the anatomical axes they point
to. For an axis-aligned affine (the common case) the translation is simply the origin.

This module is pure numpy: it neither reads files nor imports anything above ``bricking``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ParameterError, StoreFormatError

__all__ = ["WorldFrame", "FRAMES", "LPS_TO_RAS"]

#: world frames a store may declare: patient RAS+ or not anatomical
FRAMES = ("RAS", "")
#: DICOM's patient frame (LPS+) to NIfTI's (RAS+): negate x and y
LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


@dataclass(frozen=True, slots=True)
class WorldFrame:
    """The voxel-to-world affine of a volume.

    Parameters
    ----------
    affine : 4x4 nested sequence of float
        Maps a voxel index ``(x, y, z, 1)`` (array axes in world order) to world ``(X, Y, Z, 1)``.
    frame : {'RAS', ''}
        ``'RAS'``: world is the patient's RAS+ frame (mm); ``''``: not anatomical.
    """

    affine: tuple[tuple[float, float, float, float], ...]
    frame: str = ""

    def __post_init__(self) -> None:
        try:
            a = np.array(self.affine, dtype=np.float64)
        except (TypeError, ValueError):
            raise ParameterError(f"affine: expected a 4x4 matrix of numbers, got {self.affine!r:.120}") from None
        if a.shape == (3, 4):
            a = np.vstack([a, [0.0, 0.0, 0.0, 1.0]])
        if a.shape != (4, 4):
            raise ParameterError(f"affine: expected a 4x4 matrix, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ParameterError(f"affine: expected finite numbers, got {a.tolist()}")
        if not np.allclose(a[3], [0.0, 0.0, 0.0, 1.0]):
            raise ParameterError(f"affine: expected a last row 0, 0, 0, 1, got {a[3].tolist()}")
        norms = np.linalg.norm(a[:3, :3], axis=0)
        if np.any(norms <= 0) or abs(np.linalg.det(a[:3, :3] / norms)) < 1e-6:
            raise ParameterError(f"affine: expected three independent axes with a voxel size > 0, got {a[:3, :3].tolist()}")
        if self.frame not in FRAMES:
            raise ParameterError(f"frame: expected one of {FRAMES}, got {self.frame!r}")
        object.__setattr__(self, "affine", tuple(tuple(float(v) for v in row) for row in a))

    # -- constructors --------------------------------------------------------------------------
    @classmethod
    def from_spacing(cls, spacing_zyx, origin_zyx=(0.0, 0.0, 0.0), frame: str = "") -> "WorldFrame":
        """An axis-aligned frame: voxel size ``spacing_zyx`` and voxel 0 at ``origin_zyx``."""
        sz, sy, sx = (float(v) for v in spacing_zyx)
        oz, oy, ox = (float(v) for v in origin_zyx)
        return cls(((sx, 0, 0, ox), (0, sy, 0, oy), (0, 0, sz, oz), (0, 0, 0, 1)), frame)

    def with_spacing(self, spacing_zyx) -> "WorldFrame":
        """The same axes and origin with voxel size ``spacing_zyx`` (a user's ``--spacing`` wins)."""
        m = self.matrix
        sz, sy, sx = (float(v) for v in spacing_zyx)
        m[:3, :3] = self.directions * np.array([sx, sy, sz])
        return WorldFrame(tuple(tuple(r) for r in m), self.frame)

    def with_origin(self, origin_zyx) -> "WorldFrame":
        """The same axes and voxel size with voxel 0 at ``origin_zyx`` along the array's axes (a
        user's ``--origin`` wins; for an oblique frame the translation is ``directions @ origin``)."""
        o = np.asarray([float(v) for v in origin_zyx], dtype=np.float64)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ParameterError(f"origin: expected three finite numbers z,y,x, got {origin_zyx!r}")
        m = self.matrix
        m[:3, 3] = self.directions @ o[::-1]
        return WorldFrame(tuple(tuple(r) for r in m), self.frame)

    # -- derived values ------------------------------------------------------------------------
    @property
    def matrix(self) -> np.ndarray:
        """The affine as a float64 ``(4, 4)`` array."""
        return np.array(self.affine, dtype=np.float64)

    @property
    def directions(self) -> np.ndarray:
        """``(3, 3)``: column ``c`` is the unit world direction of array axis ``c`` (x, y, z)."""
        m = self.matrix[:3, :3]
        return m / np.linalg.norm(m, axis=0)

    @property
    def spacing(self) -> tuple[float, float, float]:
        """Voxel size ``(z, y, x)`` in world units (the lengths of the affine's columns)."""
        n = np.linalg.norm(self.matrix[:3, :3], axis=0)
        return (float(n[2]), float(n[1]), float(n[0]))

    @property
    def origin(self) -> tuple[float, float, float]:
        """World position of voxel 0 along the array's axes, ``(z, y, x)``: OME's level-0 translation."""
        local = np.linalg.solve(self.directions, self.matrix[:3, 3])
        return (float(local[2]), float(local[1]), float(local[0]))

    @property
    def oblique(self) -> bool:
        """True when the array axes are not the world axes (up to order and sign)."""
        d = np.abs(self.directions)
        return not np.allclose(np.sort(d, axis=0)[-1], 1.0, atol=1e-6)

    def voxel_to_world(self, index_xyz) -> np.ndarray:
        """World coordinates of voxel indices ``(..., 3)`` given in ``(x, y, z)`` order."""
        p = np.asarray(index_xyz, dtype=np.float64)
        m = self.matrix
        return p @ m[:3, :3].T + m[:3, 3]

    # -- store attributes ----------------------------------------------------------------------
    def to_attrs(self) -> dict[str, Any]:
        """The ``affine`` / ``world_frame`` entries of a store's ``attrs['clipvol']``."""
        return {"affine": [list(r) for r in self.affine], "world_frame": self.frame}

    @classmethod
    def from_attrs(cls, cv: dict[str, Any], where: str) -> "WorldFrame | None":
        """The frame recorded in ``attrs['clipvol']`` (None when the store has none)."""
        if cv.get("affine") is None:
            return None
        a = cv["affine"]
        ok = isinstance(a, list) and len(a) == 4 and all(isinstance(r, list) and len(r) == 4 for r in a)
        if not ok or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for r in a for v in r):
            raise StoreFormatError(f"{where}: attrs['clipvol']['affine']: expected a 4x4 matrix of finite numbers, got {a!r:.120}")
        try:
            return cls(tuple(tuple(r) for r in a), str(cv.get("world_frame", "")))
        except ParameterError as e:
            raise StoreFormatError(f"{where}: attrs['clipvol']: {e}") from None
