"""Anatomical labels of directions: which of R/L, A/P, S/I a view or a slice's edges point to.

A store built from a NIfTI file or a DICOM series records its voxel-to-world affine in RAS+
(:class:`clipvol.bricking.worldframe.WorldFrame`). clipvol draws in the array's own axes, so a
direction on screen — the camera's right or up, a slice plane's row or column — is a direction
``(x, y, z)`` along the array axes; the affine's rotation turns it into the patient frame, and the
largest components name it, the way radiology viewers label the edges of an image (e.g. 3D Slicer
and ITK-SNAP show ``R`` on the right edge of an axial slice in neurological convention).

Pure functions of numpy arrays, no GL: the HUD of ``clipvol view``, the offscreen frames and
``clipvol slice`` call :func:`view_labels` / :func:`plane_labels`; :func:`axis_codes` is what
nibabel calls ``aff2axcodes``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ParameterError

__all__ = ["anatomical_axes", "direction_label", "axis_codes", "view_labels", "plane_labels", "opposite", "RAS_LETTERS"]

#: letters for the +/- direction of each RAS+ world axis
RAS_LETTERS = (("R", "L"), ("A", "P"), ("S", "I"))
#: letters for non-anatomical worlds
XYZ_LETTERS = (("+X", "-X"), ("+Y", "-Y"), ("+Z", "-Z"))
#: a component counts towards a label when at least this fraction of the largest one
SECONDARY = 0.5


def _letters(frame: str):
    return RAS_LETTERS if frame == "RAS" else XYZ_LETTERS


def direction_label(world_dir: Sequence[float], frame: str = "RAS", secondary: float = SECONDARY) -> str:
    """The label of a world direction: its dominant axis letter, then any other strong ones.

    ``(1, 0, 0)`` in RAS is ``"R"``; ``(0.7, 0.7, 0)`` is ``"RA"``; ``(-0.2, 0, -1)`` is ``"I"``.
    Components below ``secondary`` times the largest are left out.
    """
    d = np.asarray(world_dir, dtype=np.float64).reshape(-1)
    if d.shape != (3,) or not np.all(np.isfinite(d)):
        raise ParameterError(f"world_dir: expected three finite numbers, got {world_dir!r}")
    mag = np.abs(d)
    top = mag.max()
    if top <= 0:
        raise ParameterError("world_dir: expected a non-zero direction, got (0, 0, 0)")
    letters = _letters(frame)
    order = np.argsort(-mag, kind="stable")
    return "".join(letters[i][0 if d[i] > 0 else 1] for i in order if mag[i] >= secondary * top)


def opposite(label: str) -> str:
    """``"RA"`` -> ``"LP"``, ``"+X"`` -> ``"-X"``."""
    swap = {a: b for pair in RAS_LETTERS for a, b in (pair, pair[::-1])}
    if label.startswith(("+", "-")):
        return "".join({"+": "-", "-": "+"}.get(c, c) for c in label)
    return "".join(swap.get(c, c) for c in label)


def _rotation(affine) -> np.ndarray:
    m = np.asarray(affine, dtype=np.float64)[:3, :3]
    return m / np.linalg.norm(m, axis=0)


def axis_codes(affine, frame: str = "RAS") -> tuple[str, str, str]:
    """The world direction each array axis ``(x, y, z)`` increases towards, one letter each.

    Each array axis gets a distinct world axis (the best one-to-one match of the affine's
    columns), as nibabel's ``aff2axcodes`` does: an ``LPS`` volume is ``("L", "P", "S")``.
    """
    rot = _rotation(affine)
    u, _, vt = np.linalg.svd(rot)
    r = np.abs(u @ vt)  # the nearest pure rotation: shears and float noise do not decide a label
    world = [-1, -1, -1]
    for _ in range(3):  # greedy: the strongest remaining (world axis, array axis) pair first
        w, c = np.unravel_index(int(np.argmax(r)), r.shape)
        world[c] = int(w)
        r[w, :] = -1.0
        r[:, c] = -1.0
    letters = _letters(frame)
    return tuple(letters[world[c]][0 if rot[world[c], c] > 0 else 1] for c in range(3))  # type: ignore[return-value]


def view_labels(affine, right, up, frame: str = "RAS") -> dict[str, str]:
    """Labels of a view's four edges from its screen ``right`` and ``up`` (array-axis ``(x, y, z)`` vectors).

    Returns ``{"right", "left", "top", "bottom"}``: e.g. a view from the front of a patient in
    RAS (screen right = patient's left) gives ``{"right": "L", "left": "R", "top": "S", "bottom": "I"}``.
    """
    rot = _rotation(affine)
    r = direction_label(rot @ np.asarray(right, dtype=np.float64), frame)
    u = direction_label(rot @ np.asarray(up, dtype=np.float64), frame)
    return {"right": r, "left": opposite(r), "top": u, "bottom": opposite(u)}


def plane_labels(affine, axis: str, frame: str = "RAS") -> dict[str, str]:
    """Edge labels of an axis-aligned slice image ``vol[k]``, ``vol[:, j]`` or ``vol[:, :, i]``.

    ``axis`` is the array axis the plane is normal to (``'z'``, ``'y'`` or ``'x'``). The image is
    drawn as numpy shows it: its first remaining axis runs down (rows), its second to the right
    (columns), so ``right`` is the direction of the column index and ``bottom`` that of the row index.
    """
    cols = {"z": (1, 0, 0), "y": (1, 0, 0), "x": (0, 1, 0)}
    rows = {"z": (0, 1, 0), "y": (0, 0, 1), "x": (0, 0, 1)}
    if axis not in cols:
        raise ParameterError(f"axis: expected 'z', 'y' or 'x', got {axis!r}")
    return view_labels(affine, cols[axis], -np.asarray(rows[axis], dtype=np.float64), frame)


def anatomical_axes(affine) -> tuple[np.ndarray, np.ndarray]:
    """``(up, front)``: the array-axis ``(x, y, z)`` directions of *superior* and *anterior*.

    What a camera needs to show a RAS-frame volume the way a clinician expects (head up, seen from
    the front); :func:`clipvol.scene.paths.turntable` takes them as ``up`` and ``front``.
    """
    rot = _rotation(affine)
    inv = np.linalg.inv(rot)  # world direction -> array-axis direction
    up = inv @ np.array([0.0, 0.0, 1.0])
    front = inv @ np.array([0.0, 1.0, 0.0])
    return up / np.linalg.norm(up), front / np.linalg.norm(front)
