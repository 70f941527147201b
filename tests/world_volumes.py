"""One small patient in three storage orders, as NIfTI files: RAS, LAS (x flipped) and permuted axes.

A bright marker sits at the patient's left-anterior-superior corner of a dim body; the copies hold
the same patient (the tests check nibabel's ``aff2axcodes`` of each), so every view, slice and
overlay of them must agree.
"""

from __future__ import annotations

import numpy as np

#: voxel grid (i, j, k) as nibabel holds it, and the RAS affine of the first copy

SHAPE = (20, 16, 12)
RAS = np.array([[2.0, 0, 0, -19], [0, 2.0, 0, -15], [0, 0, 2.0, -11], [0, 0, 0, 1]])


def marker_volume() -> np.ndarray:
    """The RAS copy's voxels ``(i, j, k)``: a dim body and the bright left-anterior-superior marker."""
    v = np.zeros(SHAPE, dtype=np.float32)
    v[4:16, 3:13, 2:10] = 100.0  # a dim body
    v[0:3, -3:, -3:] = 1000.0  # the marker: left (low i), anterior (high j), superior (high k)
    return v


def write_copy(tmp_path, name: str) -> str:
    """Write copy ``name`` (``ras``, ``las`` or ``perm``) as ``tmp_path/NAME.nii.gz``; return its path."""
    import nibabel as nib

    v, a = marker_volume(), RAS
    if name == "las":
        flip = np.array([[-1.0, 0, 0, SHAPE[0] - 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        v, a = v[::-1], RAS @ flip
        assert nib.aff2axcodes(a) == ("L", "A", "S")
    elif name == "perm":
        perm = np.array([[0.0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])  # new (a, b, c) = old (k, i, j)
        v, a = v.transpose(2, 0, 1), RAS @ perm
        assert nib.aff2axcodes(a) == ("S", "R", "A")
    p = tmp_path / f"{name}.nii.gz"
    nib.save(nib.Nifti1Image(np.ascontiguousarray(v), a), p)
    return str(p)


