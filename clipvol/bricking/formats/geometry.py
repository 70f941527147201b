"""Is a voxel-to-world affine one rigid, orthogonal grid? The readers' shared geometry check.

clipvol stores a volume as voxels on a rectangular grid: a world frame of three orthogonal axes,
each with one spacing (rotated, in any orientation, is fine). A NIfTI ``sform`` may shear (a
gantry-tilted CT resampled into a sheared frame) and a DICOM series may place a slice sideways,
tilt the stack, mix pixel spacings or leave gaps; drawn on a rectangular grid, any of these shows
the anatomy distorted with nothing to say so. The readers refuse them, saying what differs.

Tolerances (each stated in the refusal):

* axes orthogonal to within :data:`ORTHO_TOLERANCE` in the cosine of the angle between two axes
  (0.057°): far below any real shear (a 1° gantry tilt is a cosine of 0.017), above the rounding of
  an ``sform`` stored as float32;
* slice positions on the stack's axis to within :data:`SIDEWAYS_TOLERANCE` of the smaller pixel
  spacing (5 %), which absorbs DICOM's decimal-string rounding of positions;
* pixel spacings equal to within :data:`SPACING_TOLERANCE` (0.1 %, relative).
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import InputFormatError

__all__ = ["ORTHO_TOLERANCE", "SIDEWAYS_TOLERANCE", "SPACING_TOLERANCE", "check_orthogonal_axes"]

ORTHO_TOLERANCE = 1e-3
SIDEWAYS_TOLERANCE = 0.05
SPACING_TOLERANCE = 1e-3

_AXES = ("i (x)", "j (y)", "k (z)")


def check_orthogonal_axes(affine, where: str, what: str = "voxel-to-world affine") -> None:
    """Raise :class:`~clipvol.errors.InputFormatError` unless the three columns of ``affine``'s
    linear part are finite, non-zero and pairwise orthogonal (to :data:`ORTHO_TOLERANCE`)."""
    m = np.asarray(affine, dtype=np.float64)[:3, :3]
    if not np.all(np.isfinite(m)):
        raise InputFormatError(f"{where}: the {what} is not finite: {m.tolist()}")
    norms = np.linalg.norm(m, axis=0)
    for a in range(3):
        if not norms[a] > 0:
            raise InputFormatError(f"{where}: the {what} gives the {_AXES[a]} axis zero length; not a grid")
    u = m / norms
    for a, b in ((0, 1), (0, 2), (1, 2)):
        c = float(u[:, a] @ u[:, b])
        if abs(c) > ORTHO_TOLERANCE:
            angle = math.degrees(math.acos(max(-1.0, min(1.0, c))))
            raise InputFormatError(
                f"{where}: the {what} is sheared: its {_AXES[a]} and {_AXES[b]} axes meet at {angle:.3f}°, expected "
                f"90° (to within {math.degrees(math.asin(ORTHO_TOLERANCE)):.3f}°); drawn on a rectangular grid it "
                "would look unsheared (a gantry tilt?): resample it onto an orthogonal grid first")
