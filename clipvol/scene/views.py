"""Named views in the user's frame: where the eye sits and which way is up, for every entry point.

A clinician asks for the view *from the front of the patient, head up*; a microscopist for the
view *down the stack*. clipvol draws in the array's own axes (scaled to world units, see
:mod:`clipvol.bricking.worldframe`), so a view name must be turned into array-axis directions
through the store's voxel-to-world affine. This module is the one place that does it:
``clipvol render``, ``clipvol view`` (window and offscreen), the turntable, ``clipvol.show()`` and
the tests all call :func:`view_directions` / :func:`preset_camera`, so a view name means the same
direction everywhere.

Conventions:

* **Anatomical stores** (a NIfTI, DICOM or other input with a patient frame, RAS+ in the store):
  a view is named for the side of the patient the eye is on — ``anterior`` looks at the face,
  ``left`` at the patient's left side — with the head up (superior towards the image top);
  ``superior`` and ``inferior`` have anterior up. ``iso`` looks from anterior-right-superior
  (eye direction ``(1, 1, 1)`` in RAS). The old names are aliases of the same anatomical
  directions: ``front`` = ``anterior``, ``back`` = ``posterior``, ``side`` = ``left``,
  ``top`` = ``superior``.
* **Explicit cameras**: ``--eye``, ``--target`` and ``--up`` of a patient-frame store are in the
  patient's world (RAS+ millimetres, what the store's affine gives a voxel) and are carried into
  the drawing frame by :func:`world_to_drawing`, so one point is the same anatomy in every storage
  order; for other stores, and in the viewer's camera files, they are array-axis world positions.
* **Other stores** (no patient frame): ``front`` looks along ``+z`` (down the stack, rows follow
  ``+y`` as numpy prints ``vol[k]``), ``back`` along ``-z``, ``side`` along ``+x``, ``top`` along
  ``+y``, ``iso`` along ``(0.55, 0.45, 0.7)``; the anatomical names are refused (the store does
  not say where anterior is).
* **Slices** of a patient-frame store are cut in the patient's planes and shown in the
  **radiological** convention (the default of 3D Slicer's slice views and of most PACS): axial
  with anterior up and the patient's right on the image's left, coronal with superior up and the
  patient's right on the left, sagittal with superior up and anterior on the left.
  ``convention="neurological"`` puts the patient's right on the right of axial and coronal
  slices (FSLeyes' default); sagittal slices are the same in both. Two co-registered stores give
  the same slice image whatever their storage order (:func:`anatomical_plane`).
* **Mirrored storage**: a patient frame whose affine has a negative determinant (LAS, the usual
  FSL storage, or any odd number of flips) is a mirror image of the patient in array axes. A
  right-handed camera in array axes then sees the patient mirrored, so :func:`mirrored` is True
  and every entry point flips its image left-right (exact: the frustum is symmetric) and labels
  it with the flipped screen axes (:func:`screen_axes`). Two stores of the same anatomy in any
  storage order then give the same image.

Pure numpy, no GL.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError

__all__ = [
    "ANATOMICAL_VIEWS", "ALIASES", "VIEW_CHOICES", "is_anatomical", "mirrored", "world_to_array_directions",
    "view_directions", "world_to_drawing", "preset_camera", "view_camera", "screen_axes", "edge_labels", "SLICES",
    "CONVENTIONS", "slice_axes", "anatomical_plane", "patient_path",
]

#: anatomical view -> (RAS direction from the target to the eye, RAS up)
ANATOMICAL_VIEWS = {
    "anterior": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "posterior": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "left": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "right": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "superior": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "inferior": ((0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "iso": ((1.0, 1.0, 1.0), (0.0, 0.0, 1.0)),
}
#: the array-frame names and the anatomical view each means for a patient-frame store
ALIASES = {"front": "anterior", "back": "posterior", "side": "left", "top": "superior"}
#: array-frame view -> (array-axis view direction ``forward`` (x, y, z), up)
ARRAY_VIEWS = {
    "front": ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
    "back": ((0.0, 0.0, -1.0), (0.0, -1.0, 0.0)),
    "side": ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, -1.0)),
    "iso": ((0.55, 0.45, 0.7), (0.0, -1.0, 0.0)),
}
#: every name ``--view`` accepts
VIEW_CHOICES = tuple(ANATOMICAL_VIEWS) + tuple(ALIASES)


def is_anatomical(frame) -> bool:
    """True for a :class:`~clipvol.bricking.worldframe.WorldFrame` in the patient's RAS+ frame."""
    return frame is not None and getattr(frame, "frame", "") == "RAS"


def _rotation(frame) -> np.ndarray:
    m = np.asarray(frame.affine, dtype=np.float64)[:3, :3]
    return m / np.linalg.norm(m, axis=0)


def mirrored(frame) -> bool:
    """True when the array axes are a mirror image of the patient frame (negative determinant)."""
    return is_anatomical(frame) and float(np.linalg.det(_rotation(frame))) < 0.0


def patient_path(path: str, frame) -> tuple[str, dict]:
    """``(path name, keyword arguments)`` of :func:`clipvol.scene.paths.make_path` that keep a camera
    path head-up and seen the patient's way round for a patient-frame store.

    Every path takes the store's superior as ``up`` and anterior as ``front`` and, for a store whose
    array is the patient's mirror image, ``mirror`` (so it turns the world's way); the ``orbit``,
    which has no up of its own, becomes a turntable raised 25 degrees. Other stores keep ``path``
    and the paths' defaults (the array's frame).
    """
    if not is_anatomical(frame):
        return path, {}
    from .orientation import anatomical_axes

    up, front = anatomical_axes(frame.affine)
    kw = {"up": tuple(float(v) for v in up), "front": tuple(float(v) for v in front), "mirror": mirrored(frame)}
    if path == "orbit":
        return "turntable", {**kw, "elevation": 25.0}
    return path, kw


def world_to_array_directions(frame, world_dirs) -> np.ndarray:
    """Unit array-axis ``(x, y, z)`` directions of world (RAS) directions ``(..., 3)``."""
    d = np.asarray(world_dirs, dtype=np.float64) @ np.linalg.inv(_rotation(frame)).T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def view_directions(view: str, frame=None) -> tuple[np.ndarray, np.ndarray]:
    """``(forward, up)``: the array-axis view direction and screen up of a named view.

    ``frame`` is the store's :class:`~clipvol.bricking.worldframe.WorldFrame` (or None). Anatomical
    names need a patient frame; the array names mean the anatomical direction of :data:`ALIASES`
    when there is one, the array's otherwise.
    """
    name = str(view).lower()
    if name not in ANATOMICAL_VIEWS and name not in ALIASES:
        raise ParameterError(f"--view: expected one of {', '.join(VIEW_CHOICES)}, got {view!r}")
    if is_anatomical(frame):
        eye_dir, up = ANATOMICAL_VIEWS[ALIASES.get(name, name)]
        d = world_to_array_directions(frame, np.array([eye_dir, up], dtype=np.float64))
        return -d[0], d[1]
    if name not in ARRAY_VIEWS:
        raise ParameterError(f"--view {name}: expected a store with a patient frame (RAS/LPS, from NIfTI or DICOM); "
                             f"this one has none, so use one of {', '.join(ARRAY_VIEWS)} or --eye")
    fwd, up = (np.asarray(v, dtype=np.float64) for v in ARRAY_VIEWS[name])
    return fwd / np.linalg.norm(fwd), up


def world_to_drawing(frame, spacing) -> np.ndarray:
    """``(4, 4)``: a patient-frame world point ``(X, Y, Z, 1)`` (RAS+ millimetres, what nibabel's
    ``apply_affine`` gives for a voxel) to the drawing frame, voxel ``i`` at ``i * spacing`` along the
    array axes ``(x, y, z)`` (``spacing`` is the store's ``(z, y, x)``)."""
    sp = np.asarray(spacing, dtype=np.float64).reshape(3)[::-1]
    return np.diag(np.append(sp, 1.0)) @ np.linalg.inv(np.asarray(frame.matrix, dtype=np.float64))


def preset_camera(box_lo, box_hi, view: str, size, *, frame=None, eye=None, target=None, up=None, fov: float = 35.0,
                  distance: float | None = None, ortho: bool = False, spacing=None):
    """The :class:`~clipvol.scene.camera.Camera` of a named ``view`` (or an explicit ``eye``) looking at ``target``.

    ``target`` defaults to the box centre, ``distance`` (in box diagonals, default 1.6) places the
    eye, ``up`` overrides the view's up. For a patient-frame store ``eye``, ``target`` and ``up``
    are in the patient's world (RAS+ millimetres, the coordinates the store's affine gives, so a
    point means the same anatomy whatever the storage order) and ``spacing`` (the store's, z, y, x)
    is needed to place them; otherwise they are array-axis world positions (voxel ``i`` at
    ``i * spacing``), as the camera files of the viewer are.
    """
    from .camera import Camera

    lo = np.asarray(box_lo, dtype=np.float64)
    hi = np.asarray(box_hi, dtype=np.float64)
    centre = (lo + hi) / 2.0
    diag = float(np.linalg.norm(hi - lo))
    world = is_anatomical(frame) and any(v is not None for v in (eye, target, up))
    if world:
        if spacing is None:
            raise ParameterError("preset_camera: spacing: expected the store's voxel size (z, y, x) to place "
                                 "--eye/--target/--up given in the patient's world")
        to_draw = world_to_drawing(frame, spacing)
        point = lambda v: to_draw[:3, :3] @ np.asarray(v, dtype=np.float64) + to_draw[:3, 3]  # noqa: E731
    else:
        point = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    tgt = centre if target is None else point(target)
    fwd, view_up = view_directions(view, frame)
    if eye is not None:
        e = point(eye)
        if np.allclose(e, tgt):
            shown = tuple(float(v) for v in (target if target is not None else tgt))
            raise ParameterError(f"--eye: expected a point other than the target {shown}, got {tuple(eye)}")
        fwd = (tgt - e) / np.linalg.norm(tgt - e)
        if abs(float(fwd @ view_up)) > 0.9:  # looking along the view's up: anterior (or -z) is up instead
            view_up = (world_to_array_directions(frame, (0.0, 1.0, 0.0)) if is_anatomical(frame)
                       else np.array([0.0, 0.0, -1.0]))
    else:
        dist = (1.6 if distance is None else float(distance)) * diag
        if not (dist > 0 and math.isfinite(dist)):
            raise ParameterError(f"--distance: expected a number > 0, got {distance}")
        e = tgt - fwd * dist
    if up is None:
        u = view_up
    elif world:  # a patient-frame direction: its array-axis direction
        w = np.asarray(up, dtype=np.float64)
        if w.shape != (3,) or not np.all(np.isfinite(w)) or np.linalg.norm(w) == 0:
            raise ParameterError(f"--up: expected a non-zero direction x,y,z, got {up!r}")
        u = world_to_array_directions(frame, w)
    else:
        u = np.asarray(up, dtype=np.float64)
    if ortho:
        w, h = size
        ext = diag * 1.05
        width, height = (ext, ext * h / w) if w >= h else (ext * w / h, ext)
        return Camera.orthographic(tuple(tgt), tuple(fwd), tuple(u), width, height, size=size)
    return Camera.perspective(tuple(e), tuple(tgt), up=tuple(u), fov_y=fov, size=size)


def view_camera(pyramid, view: str, size, *, eye=None, target=None, up=None, fov: float = 35.0,
                distance: float | None = None, ortho: bool = False, frame=None):
    """:func:`preset_camera` around a store's volume box: the camera of ``clipvol render --view``.

    The one call every entry point with a pyramid makes (the CLI, the point renderer, the sort-last
    tests and benchmarks), so that a view name frames every store the same way; ``frame`` is the
    store's patient frame, when it has one."""
    lo, hi = pyramid.volume_box()
    return preset_camera(lo, hi, view, size, frame=frame, eye=eye, target=target, up=up, fov=fov, distance=distance,
                         ortho=ortho, spacing=getattr(pyramid, "spacing", None))


def screen_axes(cam, frame=None) -> tuple[np.ndarray, np.ndarray]:
    """``(right, up)``: the array-axis directions of the image's right and top once :func:`clipvol.app.annotate.present`
    has flipped a mirrored store's image."""
    right = np.asarray(cam.right, dtype=np.float64)
    return (-right if mirrored(frame) else right), np.asarray(cam.up, dtype=np.float64)


def edge_labels(cam, frame) -> dict[str, str]:
    """R/L, A/P, S/I letters of the four edges of a presented image (``{}`` without a patient frame)."""
    if not is_anatomical(frame):
        return {}
    from .orientation import view_labels

    right, up = screen_axes(cam, frame)
    return view_labels(frame.affine, right, up, frame.frame)



#: slice name -> (RAS image up, RAS image right in the radiological convention)
SLICES = {
    "axial": ((0.0, 1.0, 0.0), (-1.0, 0.0, 0.0)),
    "coronal": ((0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)),
    "sagittal": ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
}
#: slice display conventions: radiological (patient's right on the image left) or neurological
CONVENTIONS = ("radiological", "neurological")


def slice_axes(name: str, frame, convention: str = "radiological") -> tuple[np.ndarray, np.ndarray]:
    """``(normal, up)``: array-axis directions of a patient-frame slice, for
    :class:`~clipvol.scene.plane.Plane` (whose ``right = normal x up``)."""
    if name not in SLICES:
        raise ParameterError(f"--axis: expected one of {', '.join(SLICES)}, got {name!r}")
    if convention not in CONVENTIONS:
        raise ParameterError(f"convention: expected one of {', '.join(CONVENTIONS)}, got {convention!r}")
    up_w, right_w = (np.asarray(v, dtype=np.float64) for v in SLICES[name])
    if convention == "neurological" and name != "sagittal":
        right_w = -right_w
    up, right = world_to_array_directions(frame, np.array([up_w, right_w]))
    normal = np.cross(up, right)  # so that Plane's normal x up is the wanted right
    return normal / np.linalg.norm(normal), up


def anatomical_plane(pyramid, frame, name: str, index: float | None = None, convention: str = "radiological"):
    """The ``axial`` / ``coronal`` / ``sagittal`` :class:`~clipvol.scene.plane.Plane` of a patient-frame store.

    The plane is the patient's (for an oblique acquisition it is resampled, as Slicer's slice
    views are), through the volume centre, or through level-0 voxel ``index`` of the array axis
    most nearly along its normal (``index`` in ``[0, n - 1]`` of that axis).
    """
    import math

    from .plane import Plane

    normal, up = slice_axes(name, frame, convention)
    lo, hi = pyramid.volume_box()
    origin = (lo + hi) / 2.0
    if index is not None:
        c = int(np.argmax(np.abs(normal)))  # array axis x, y or z
        n = pyramid.shape[2 - c]
        try:
            i = float(index)
        except (TypeError, ValueError):
            i = math.nan
        if not (0.0 <= i <= n - 1):
            raise ParameterError(f"index: expected 0..{n - 1} for the {name} plane (array axis {'xyz'[c]}), got {index!r}")
        origin[c] = i * pyramid.spacing[2 - c]
    return Plane(tuple(origin), tuple(normal), tuple(up))
