"""One browser's view of a store: what it asks for, checked, and the camera it means (pure numpy).

Each WebSocket of ``clipvol serve`` owns a :class:`ViewState`. The page sends changes as the
notebook widget's model does (``{"method": "update", "state": {...}}``: ``azimuth``, ``elevation``,
``zoom`` from a drag or the wheel, ``tf`` and ``mode`` from the menus, and the page's own controls
``view``, ``window``, ``slice``, ``slice_index``, ``crop_voxels``, ``clip_plane``, ``iso_value``);
:meth:`ViewState.apply` checks each against the store (a wrong one raises
:class:`~clipvol.errors.ParameterError` naming the field, and nothing of that message is applied)
and says which kind of change it was, which decides what is drawn next: a camera move draws fast
frames until the camera rests (:mod:`clipvol.app.adaptive`), anything else the converged frame.

**The camera.** A named view (``clipvol render --view``, :func:`clipvol.scene.views.view_camera`:
the same eye, target, up and field of view) turned about the target: ``azimuth`` degrees about
the view's up, then ``elevation`` degrees about its right, the eye's distance divided by ``zoom``.
At azimuth 0, elevation 0 and zoom 1 it *is* the named view's camera, so the converged frame of a
preset equals ``clipvol render --view NAME`` of the same size; any other camera is sent to the page
with its frame (:func:`clipvol.scene.bookmarks.camera_to_json`) and ``clipvol render --camera``
draws it again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...errors import ParameterError

__all__ = ["ViewState", "orbit_camera", "CAMERA_FIELDS", "mode_names", "SLICE_NAMES"]

#: fields whose change moves the camera (drawn fast while they keep changing)
CAMERA_FIELDS = frozenset({"azimuth", "elevation", "zoom"})
#: slice planes: "" shows the 3D view
SLICE_NAMES = ("", "axial", "coronal", "sagittal")


def mode_names() -> tuple[str, ...]:
    """The render modes the page offers (its menu): every registered one (:mod:`clipvol.render.modes`
    adds its modes to ``clipvol.scene.params.MODES``)."""
    from ...scene import params

    return params.MODES


def _rotate(v: np.ndarray, axis: np.ndarray, deg: float) -> np.ndarray:
    """``v`` turned ``deg`` degrees about the unit ``axis`` (Rodrigues)."""
    a = math.radians(deg)
    k = axis / np.linalg.norm(axis)
    return v * math.cos(a) + np.cross(k, v) * math.sin(a) + k * float(k @ v) * (1.0 - math.cos(a))


def orbit_camera(pyramid, view: str, size, *, azimuth: float = 0.0, elevation: float = 0.0, zoom: float = 1.0,
                 frame=None):
    """The named ``view``'s camera (:func:`~clipvol.scene.views.view_camera`) turned about its target
    by ``azimuth`` (about its up) and ``elevation`` (about its right), ``zoom`` times nearer."""
    from ...scene.camera import Camera
    from ...scene.views import view_camera

    base = view_camera(pyramid, view, size, frame=frame)
    if azimuth == 0.0 and elevation == 0.0 and zoom == 1.0:
        return base  # exactly `clipvol render --view`'s camera
    target = np.asarray(base.target, dtype=np.float64)
    up = np.asarray(base.up, dtype=np.float64)
    d = np.asarray(base.eye, dtype=np.float64) - target
    d = _rotate(d, up, -float(azimuth))  # a drag to the right turns the volume to the right
    right = np.cross(-d, up)
    d2 = _rotate(d, right, float(elevation))
    up2 = _rotate(up, right, float(elevation))
    eye = target + d2 / float(zoom)
    return Camera.perspective(tuple(eye), tuple(target), up=tuple(up2), fov_y=base.fov_y, size=tuple(size))


def _number(name: str, v, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ParameterError(f"{name}: expected a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _numbers(name: str, v, n: int) -> tuple[float, ...] | None:
    if v is None or v == "" or v == []:
        return None
    if not isinstance(v, (list, tuple)) or len(v) != n:
        raise ParameterError(f"{name}: expected {n} numbers or nothing, got {v!r}")
    return tuple(_number(name, x) for x in v)


@dataclass
class ViewState:
    """What one browser asks to see; changed only through :meth:`apply` (checked).

    Parameters
    ----------
    views : tuple of str
        The view presets of the store (anatomical names for a patient frame).
    tf_names : tuple of str
        The transfer-function presets offered (``auto`` first).
    shape : (z, y, x)
        The store's level-0 shape (bounds of ``slice_index`` and ``crop_voxels``).
    """

    views: tuple[str, ...]
    tf_names: tuple[str, ...]
    shape: tuple[int, int, int]
    view: str = "iso"
    azimuth: float = 0.0
    elevation: float = 0.0
    zoom: float = 1.0
    tf: str = "auto"
    window: tuple[float, float] | None = None
    mode: str = "composite"
    iso_value: float | None = None
    slice: str = ""
    slice_index: float | None = None
    crop_voxels: tuple[float, ...] | None = None
    clip_plane: tuple[float, ...] | None = None
    #: update messages taken (the page's acknowledgement count, the widget's ``handled``)
    handled: int = 0
    extra: dict = field(default_factory=dict)

    def public(self) -> dict:
        """The state the page holds (JSON)."""
        return {"view": self.view, "views": list(self.views), "azimuth": self.azimuth, "elevation": self.elevation,
                "zoom": self.zoom, "tf": self.tf, "tf_names": list(self.tf_names),
                "mode_names": list(mode_names()),
                "window": list(self.window) if self.window else None, "mode": self.mode,
                "iso_value": self.iso_value, "slice": self.slice, "slice_index": self.slice_index,
                "crop_voxels": list(self.crop_voxels) if self.crop_voxels else None,
                "clip_plane": list(self.clip_plane) if self.clip_plane else None, "handled": self.handled}

    def apply(self, changes) -> set[str]:
        """Check and apply one message's ``changes``; returns the kinds changed (``camera``, ``look``).

        All or nothing: a wrong field raises :class:`~clipvol.errors.ParameterError` naming it and
        leaves the state as it was. Fields the page does not send (``handled``, lists) are refused.
        """
        if not isinstance(changes, dict):
            raise ParameterError(f"update: expected an object of fields, got {type(changes).__name__}")
        new: dict = {}
        for k, v in changes.items():
            if k == "azimuth":
                new[k] = _number(k, v, -1e6, 1e6)
            elif k == "elevation":
                new[k] = _number(k, v, -89.0, 89.0)
            elif k == "zoom":
                new[k] = _number(k, v, 0.05, 50.0)
            elif k == "view":
                if v not in self.views:
                    raise ParameterError(f"view: expected one of {', '.join(self.views)}, got {v!r}")
                new[k] = v
            elif k == "tf":
                if v not in self.tf_names:
                    raise ParameterError(f"tf: expected one of {', '.join(self.tf_names)}, got {v!r}")
                new[k] = v
            elif k == "mode":
                if v not in mode_names():
                    raise ParameterError(f"mode: expected one of {', '.join(mode_names())}, got {v!r}")
                new[k] = v
            elif k == "window":
                w = _numbers(k, v, 2)
                if w is not None and not w[0] < w[1]:
                    raise ParameterError(f"window: expected low < high, got {w[0]:g}, {w[1]:g}")
                new[k] = w
            elif k == "iso_value":
                new[k] = None if v is None or v == "" else _number(k, v)
            elif k == "slice":
                if v not in SLICE_NAMES:
                    raise ParameterError(f"slice: expected one of none, axial, coronal, sagittal, got {v!r}")
                new[k] = v
            elif k == "slice_index":
                new[k] = None if v is None or v == "" else _number(k, v, 0.0, float(max(self.shape) - 1))
            elif k == "crop_voxels":
                c = _numbers(k, v, 6)
                if c is not None:
                    lo, hi = np.asarray(c[:3]), np.asarray(c[3:])  # x, y, z: as every coordinate a user types
                    xyz = np.asarray(self.shape)[::-1]
                    if not (np.all(lo >= 0) and np.all(hi <= xyz) and np.all(lo < hi)):
                        raise ParameterError(f"crop_voxels: expected x0,y0,z0,x1,y1,z1 with 0 <= start < stop <= "
                                             f"{tuple(int(n) for n in xyz)} (x, y, z), got {c}")
                new[k] = c
            elif k == "clip_plane":
                c = _numbers(k, v, 6)
                if c is not None and not any(c[3:]):
                    raise ParameterError("clip_plane: expected a non-zero normal nx,ny,nz, got 0,0,0")
                new[k] = c
            elif k == "pick":
                continue  # a probe request, handled by the server, not state
            else:
                raise ParameterError(f"update: no field {k!r} in a view")
        if "view" in new:  # a preset: its own camera, unturned
            new.setdefault("azimuth", 0.0)
            new.setdefault("elevation", 0.0)
            new.setdefault("zoom", 1.0)
        kinds = set()
        for k, v in new.items():
            if getattr(self, k) != v:
                setattr(self, k, v)
                kinds.add("camera" if k in CAMERA_FIELDS else "look")
        return kinds

    def camera(self, pyramid, size, frame=None):
        """The camera of this view at image ``size`` (:func:`orbit_camera`)."""
        return orbit_camera(pyramid, self.view, size, azimuth=self.azimuth, elevation=self.elevation, zoom=self.zoom,
                            frame=frame)

    def cut(self, pyramid, frame=None):
        """The :class:`~clipvol.scene.cut.Shape` of the crop box and clip plane, or None."""
        from ...scene.cut import cut_shape

        # typed x, y, z (as the CLI's --crop-voxels); the library takes numpy's z, y, x
        crop = None if self.crop_voxels is None else (tuple(self.crop_voxels[:3])[::-1], tuple(self.crop_voxels[3:])[::-1])
        planes = [self.clip_plane] if self.clip_plane is not None else []
        return cut_shape(pyramid, frame, crop_voxels=crop, clip_planes=planes)
