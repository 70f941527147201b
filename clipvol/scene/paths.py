"""Camera paths over a pyramid's volume: orbit, fly-through and zoom (pure numpy, no GL).

The viewer's offscreen mode, the report and the demo need repeatable motion that exercises what
the clip-texture is for (roaming a large volume, as in OpenGL Volumizer, Bhaniramka & Demange 2002): an **orbit** looks at the whole volume from every side
(the multiresolution cut changes with the view, the centre of interest stays put); a **fly** path
goes *through* the volume and drags the centre of interest with it, so the per-level windows roam
and bricks stream in ahead of the camera; a **zoom** moves from the whole view to a close-up of a
point, so ever finer levels are wanted around that point.

Every path is a generator of ``(camera, center_of_interest)`` pairs, ``center_of_interest`` an
``(x, y, z)`` float64 world point inside the volume box (what the application passes to
``ClipTexture.set_center``). Cameras are :class:`clipvol.scene.camera.Camera` objects with their depth
range fitted to the volume box. By default the "up" of every path is world ``-y`` so that the first
orbit frame (looking along ``+z``) shows the volume like ``numpy``'s ``vol.max(axis=0)``: ``x`` to
the right, ``y`` growing down the image. The turntable, fly and zoom paths take ``up`` and
``front`` (array-axis directions): for a store in a patient frame the callers pass *superior* and
*anterior* (:func:`clipvol.scene.orientation.anatomical_axes`), so the camera stays head up, the
fly loop lies in the patient's axial plane and the zoom looks from anterior-left-superior, the
same anatomy whatever the storage order.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from ..bricking.pyramid import Pyramid
from ..errors import ParameterError
from .camera import Camera

__all__ = ["PATHS", "orbit", "turntable", "fly", "zoom", "make_path", "volume_center", "volume_radius", "UP"]

#: world "up" of every path: -y, so images look like numpy's vol.max(axis=0) from the front
UP = (0.0, -1.0, 0.0)


def volume_center(pyramid: Pyramid) -> np.ndarray:
    """Centre ``(x, y, z)`` of the pyramid's volume box."""
    lo, hi = pyramid.volume_box()
    return (lo + hi) / 2.0


def volume_radius(pyramid: Pyramid) -> float:
    """Radius of the sphere around the volume box (half its diagonal)."""
    lo, hi = pyramid.volume_box()
    return float(np.linalg.norm(hi - lo) / 2.0)


def _check_frames(frames: int) -> int:
    try:
        n = int(frames)
    except (TypeError, ValueError):
        raise ParameterError(f"frames: expected a whole number >= 1, got {frames!r}") from None
    if n < 1 or n != frames:
        raise ParameterError(f"frames: expected a whole number >= 1, got {frames!r}")
    return n


def _check_orbit(frames: int, size, elevation: float) -> tuple[int, tuple[int, int]]:
    """Frames and size of an orbit-like path, checked with its elevation (-89..89 degrees)."""
    if not -89.0 <= float(elevation) <= 89.0:
        raise ParameterError(f"elevation: expected -89..89 degrees, got {elevation!r}")
    return _check_frames(frames), _check_size(size)


def _check_size(size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ParameterError(f"size: expected (width, height) in pixels, got {size!r}") from None
    if w < 1 or h < 1:
        raise ParameterError(f"size: expected (width, height) >= 1 pixel, got {size!r}")
    return w, h


def _basis(up, front, mirror: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(u, f, side)``: unit ``up``, the part of ``front`` perpendicular to it, and ``u x f`` (``f``
    turned +90 degrees about ``u``); the default ``UP`` and ``(0, 0, -1)`` give ``side = +x``.

    ``mirror``: the array axes are a mirror image of the world (a patient frame with a negative
    determinant, :func:`clipvol.scene.views.mirrored`); ``side`` is then ``-(u x f)``, the array
    direction of the *world's* ``up x front``, so a path turns and flies the same way through the
    anatomy as in an unmirrored copy (the frames are flipped back when presented)."""
    u = np.asarray(up, dtype=np.float64)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
        raise ParameterError(f"up: expected a non-zero (x, y, z) direction, got {up!r}")
    u = u / np.linalg.norm(u)
    f = np.asarray(front, dtype=np.float64)
    f = f - (f @ u) * u if f.shape == (3,) and np.all(np.isfinite(f)) else np.zeros(3)
    if np.linalg.norm(f) < 1e-9:
        raise ParameterError(f"front: expected a direction not parallel to up {tuple(u)}, got {front!r}")
    f = f / np.linalg.norm(f)
    return u, f, (-1.0 if mirror else 1.0) * np.cross(u, f)


def _direction(azimuth_deg: float, elevation_deg: float, up=UP, front=(0.0, 0.0, -1.0)) -> np.ndarray:
    """Unit vector from the target to the eye: azimuth about ``up`` from ``front`` (right-handed),
    elevation towards ``up``.

    With the defaults, azimuth 0 and elevation 0 put the eye on the ``-z`` side (looking along ``+z``).
    """
    u, f, side = _basis(up, front)
    az = np.radians(azimuth_deg)
    el = np.radians(elevation_deg)
    return np.cos(el) * (np.cos(az) * f + np.sin(az) * side) + np.sin(el) * u


def _reach(half: np.ndarray, v: np.ndarray) -> float:
    """How far from the box centre the box reaches along unit ``v`` (``half`` its half extents)."""
    a = np.abs(v)
    return float(np.min(half[a > 1e-12] / a[a > 1e-12]))


def _perspective(eye, target, fov_y: float, size, pyramid: Pyramid, up=UP):

    cam = Camera.perspective(tuple(eye), tuple(target), up=tuple(up), fov_y=fov_y, size=size)
    lo, hi = pyramid.volume_box()
    return cam.fit_depth(lo, hi)


def _centre_distance(pyramid: Pyramid, fit, distance, fov_y: float, size, dirs, up) -> tuple[np.ndarray, float]:
    """Centre and eye distance of an orbit-like path whose eyes lie along ``dirs`` (unit, from the
    centre): the volume's centre and the distance that fits its bounding sphere, or with ``fit``
    (world points ``(n, 3)``, e.g. :func:`clipvol.scene.framing.visible_points`) the middle of their
    bounding box and the distance at which they fit every view
    (:func:`~clipvol.scene.framing.fit_points_distance`); ``distance`` (not None) overrides the distance."""
    if fit is None:
        c = volume_center(pyramid)
        d = fit_distance(pyramid, fov_y, size) if distance is None else float(distance)
    else:
        from .framing import fit_points_distance

        pts = np.asarray(fit, dtype=np.float64).reshape(-1, 3)
        if not (len(pts) and np.all(np.isfinite(pts))):
            raise ParameterError(f"fit: expected finite world points (n, 3), got {len(pts)} points")
        c = (pts.min(axis=0) + pts.max(axis=0)) / 2.0
        cams = [Camera.perspective(tuple(c + v), tuple(c), up=tuple(up), fov_y=fov_y, size=size) for v in dirs]
        d = fit_points_distance(pts, c, cams) if distance is None else float(distance)
    if not (np.isfinite(d) and d > 0):
        raise ParameterError(f"distance: expected a finite value > 0, got {distance!r}")
    return c, d


def fit_distance(pyramid: Pyramid, fov_y: float, size=(1, 1), margin: float = 1.05) -> float:
    """Distance from the volume centre at which the whole bounding sphere fits in the view."""
    w, h = _check_size(size)
    half = np.radians(fov_y) / 2.0
    half_min = min(half, np.arctan(np.tan(half) * w / h))
    return margin * volume_radius(pyramid) / np.sin(half_min)


def orbit(
    pyramid: Pyramid,
    frames: int = 36,
    *,
    size=(256, 256),
    fov_y: float = 35.0,
    elevation: float = 25.0,
    distance: float | None = None,
    fit=None,
    turns: float = 1.0,
    start_azimuth: float = 0.0,
) -> Iterator[tuple[object, np.ndarray]]:
    """Circle the volume centre: ``frames`` views at equal azimuth steps over ``turns`` turns.

    Parameters
    ----------
    pyramid : Pyramid
        The data's pyramid (its volume box sets the centre and the default distance).
    frames : int
        Number of views; frame ``k`` is at azimuth ``start_azimuth + 360 * turns * k / frames``.
    size : (int, int)
        Image ``(width, height)`` of every camera.
    fov_y : float
        Vertical field of view in degrees.
    elevation : float
        Degrees above the horizontal plane (towards world up, ``-y``).
    distance : float, optional
        Eye distance from the centre; default: the whole volume fits (:func:`fit_distance`).
    fit : array (n, 3), optional
        Frame these world points (``(x, y, z)``, e.g. :func:`clipvol.scene.framing.visible_points`)
        instead of the volume: the views look at the middle of their bounding box from the distance
        at which all of them fit every view.
    turns, start_azimuth : float
        How far the orbit goes, where it starts (degrees).

    Yields
    ------
    (Camera, ndarray)
        The camera and the centre of interest (the volume centre, or the middle of ``fit``).
    """
    n, size = _check_orbit(frames, size, elevation)
    dirs = [_direction(start_azimuth + 360.0 * turns * k / n, elevation) for k in range(n)]
    c, d = _centre_distance(pyramid, fit, distance, fov_y, size, dirs, UP)
    for k in range(n):
        yield _perspective(c + d * dirs[k], c, fov_y, size, pyramid), c.copy()


def turntable(
    pyramid: Pyramid,
    frames: int = 72,
    *,
    size=(256, 256),
    fov_y: float = 30.0,
    up=UP,
    front=(0.0, 0.0, -1.0),
    elevation: float = 0.0,
    distance: float | None = None,
    fit=None,
    azimuth: float = 0.0,
    mirror: bool = False,
) -> Iterator[tuple[object, np.ndarray]]:
    """The volume spinning upright once about ``up`` as on a turntable, first seen from ``front``.

    A movie preset: ``frames`` views at equal steps over exactly one turn (frame ``frames`` would
    repeat frame 0, so the movie loops without a stutter). For a patient-frame store pass the
    array-axis directions of *superior* and *anterior* (:func:`clipvol.scene.orientation.anatomical_axes`):
    the first frame is then the frontal view, head up, the patient's left on screen right.

    Parameters
    ----------
    pyramid : Pyramid
        The data's pyramid (volume box: centre and default distance).
    frames : int
        Number of views (e.g. 72 at 24 fps: a 3 s turn).
    size : (int, int)
        Image ``(width, height)``.
    fov_y : float
        Vertical field of view in degrees.
    up, front : (x, y, z)
        The spin axis (screen up) and the direction from the centre to the first eye position;
        ``front`` need not be perpendicular to ``up`` (its perpendicular part is used).
    elevation : float
        Degrees the eye is raised towards ``up`` (-89..89).
    distance : float, optional
        Eye distance from the centre; default: the whole volume fits.
    fit : array (n, 3), optional
        Frame these world points instead of the volume, as :func:`orbit` does.
    azimuth : float
        Degrees the first view is turned from ``front`` (right-handed about ``up``).
    mirror : bool
        The array axes mirror the world (see ``_basis``): turn right-handed in the world.

    Yields
    ------
    (Camera, ndarray)
        The camera and the centre of interest (the volume centre, or the middle of ``fit``).
    """
    n, size = _check_orbit(frames, size, elevation)
    if not np.isfinite(float(azimuth)):
        raise ParameterError(f"azimuth: expected a finite angle in degrees, got {azimuth!r}")
    u, f, side = _basis(up, front, mirror)  # side: f rotated by +90 degrees about u
    el = np.radians(float(elevation))
    dirs = []
    for k in range(n):
        a = 2.0 * np.pi * k / n + np.radians(float(azimuth))
        horiz = np.cos(a) * f + np.sin(a) * side
        dirs.append(np.cos(el) * horiz + np.sin(el) * u)
    c, d = _centre_distance(pyramid, fit, distance, fov_y, size, dirs, u)
    for k in range(n):
        yield _perspective(c + d * dirs[k], c, fov_y, size, pyramid, up=u), c.copy()


def _fly_points(pyramid: Pyramid, t: np.ndarray, up=UP, front=(0.0, 0.0, -1.0), mirror: bool = False) -> np.ndarray:
    """A closed, smooth curve inside the volume box: an ellipse in the plane across ``up`` (through
    ``front`` and ``side``, at 0.6 of the box's reach along each) with a wobble along ``up``."""
    lo, hi = pyramid.volume_box()
    c = (lo + hi) / 2.0
    half = (hi - lo) / 2.0
    u, f, side = _basis(up, front, mirror)
    a = 2 * np.pi * np.asarray(t, dtype=np.float64)[..., None]
    return (c + 0.6 * _reach(half, side) * np.sin(a) * side + 0.6 * _reach(half, f) * np.cos(a) * f
            - 0.25 * _reach(half, u) * np.sin(2 * a) * u)


def fly(
    pyramid: Pyramid,
    frames: int = 60,
    *,
    size=(256, 256),
    fov_y: float = 60.0,
    look_ahead: float = 0.08,
    points=None,
    up=UP,
    front=(0.0, 0.0, -1.0),
    mirror: bool = False,
) -> Iterator[tuple[object, np.ndarray]]:
    """Fly *through* the volume along a smooth closed curve, looking where the path goes.

    The centre of interest is the point the camera looks at, ``look_ahead`` of the path ahead
    (as a fraction of the path), so the clip-texture's windows move with the camera and load
    ahead of it.

    Parameters
    ----------
    pyramid : Pyramid
        The data's pyramid.
    frames : int
        Number of views along the path.
    size : (int, int)
        Image ``(width, height)``.
    fov_y : float
        Vertical field of view in degrees (wide: the camera is inside the data).
    look_ahead : float
        Fraction of the path (``0 < look_ahead < 0.5``) between the eye and the point looked at.
    points : array_like, optional
        ``(m, 3)`` world ``(x, y, z)`` way-points (``m >= 2``) to fly through instead of the default
        loop; the path is then a Catmull-Rom spline through them and the camera looks along it.
    up, front : (x, y, z)
        The camera's up (the loop lies across it) and the side of the centre the loop starts on;
        for a patient-frame store: superior and anterior (head up, an axial loop).
    mirror : bool
        The array axes mirror the world (see ``_basis``): the loop turns the world's way.

    Yields
    ------
    (Camera, ndarray)
        The camera and the centre of interest (inside the volume box).
    """
    n = _check_frames(frames)
    size = _check_size(size)
    if not 0.0 < float(look_ahead) < 0.5:
        raise ParameterError(f"look_ahead: expected a fraction in (0, 0.5), got {look_ahead!r}")
    lo, hi = pyramid.volume_box()
    u = _basis(up, front)[0]
    if points is None:
        curve = lambda t: _fly_points(pyramid, np.asarray(t, dtype=np.float64) % 1.0, up, front, mirror)  # noqa: E731
    else:
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2 or not np.all(np.isfinite(pts)):
            raise ParameterError(f"points: expected (m, 3) finite (x, y, z) way-points with m >= 2, got shape {pts.shape}")
        curve = lambda t: _catmull_rom(pts, np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0))  # noqa: E731
    for k in range(n):
        t = k / n if points is None else (k / max(n - 1, 1)) * (1.0 - look_ahead)
        eye = curve(t)
        ahead = curve(t + look_ahead)
        if np.linalg.norm(ahead - eye) < 1e-9 * max(1.0, volume_radius(pyramid)):
            ahead = eye + _basis(up, front)[1] * (1e-3 * volume_radius(pyramid) + 1e-9)
        target = np.clip(ahead, lo, hi)
        fwd = (ahead - eye) / np.linalg.norm(ahead - eye)
        cam_up = u if abs(float(fwd @ u)) < 0.99 else _basis(up, front)[1]  # straight along up: front is up
        yield _perspective(eye, ahead, fov_y, size, pyramid, cam_up), target


def _catmull_rom(pts: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Uniform Catmull-Rom spline through ``pts`` at parameters ``t`` in [0, 1] (ends clamped)."""
    m = len(pts)
    ext = np.concatenate([pts[:1], pts, pts[-1:]])
    s = np.asarray(t) * (m - 1)
    i = np.clip(np.floor(s).astype(int), 0, m - 2)
    u = (s - i)[..., None]
    p0, p1, p2, p3 = ext[i], ext[i + 1], ext[i + 2], ext[i + 3]
    return 0.5 * (2 * p1 + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2 + (-p0 + 3 * p1 - 3 * p2 + p3) * u**3)


def zoom(
    pyramid: Pyramid,
    frames: int = 40,
    *,
    size=(256, 256),
    fov_y: float = 35.0,
    target=None,
    azimuth: float = 30.0,
    elevation: float = 25.0,
    end_distance: float | None = None,
    up=UP,
    front=(0.0, 0.0, -1.0),
    mirror: bool = False,
) -> Iterator[tuple[object, np.ndarray]]:
    """Zoom from the whole view to a close-up of ``target`` (geometric steps in distance).

    The view direction is fixed; the eye moves from the distance at which the whole volume fits to
    ``end_distance`` from ``target``, and the looked-at point slides from the volume centre to
    ``target``. The centre of interest is the looked-at point.

    Parameters
    ----------
    pyramid : Pyramid
        The data's pyramid.
    frames : int
        Number of views (the first is the whole view, the last the close-up).
    size : (int, int)
        Image ``(width, height)``.
    fov_y : float
        Vertical field of view in degrees.
    target : array_like, optional
        ``(x, y, z)`` world point to zoom onto; default: a point a third of the way from the
        centre towards the box's reach along ``-side + front + up`` (off-centre, so the windows must
        move; with the default ``up`` and ``front`` the ``(lo.x, lo.y, lo.z)`` corner).
    azimuth, elevation : float
        View direction, degrees: azimuth about ``up`` from ``front`` (right-handed), elevation
        towards ``up`` (as in :func:`orbit` with the defaults).
    up, front : (x, y, z)
        The camera's up and the side the azimuth counts from; for a patient-frame store superior
        and anterior (head up, seen from anterior-left-superior).
    mirror : bool
        The array axes mirror the world (see ``_basis``): the azimuth turns the world's way.
    end_distance : float, optional
        Final distance from ``target``; default: where a level-0 voxel near ``target`` spans about
        two pixels (so level 0 is wanted there at ``lod_threshold`` 1), but at most a fifth of the
        starting distance.

    Yields
    ------
    (Camera, ndarray)
        The camera and the centre of interest.
    """
    n = _check_frames(frames)
    size = _check_size(size)
    lo, hi = pyramid.volume_box()
    c = volume_center(pyramid)
    u, f, side = _basis(up, front, mirror)
    if target is None:
        half = (hi - lo) / 2.0
        p = c + (-_reach(half, side) * side + _reach(half, f) * f + _reach(half, u) * u) / 3.0
    else:
        p = np.asarray(target, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ParameterError(f"target: expected a finite (x, y, z) point, got {target!r}")
        if np.any(p < lo) or np.any(p > hi):
            raise ParameterError(f"target: expected a point inside the volume box {lo.tolist()}..{hi.tolist()}, got {p.tolist()}")
    d0 = fit_distance(pyramid, fov_y, size)
    if end_distance is None:
        d1 = 0.5 * max(pyramid.spacing) * min(size) / (2 * np.tan(np.radians(fov_y) / 2))
        d1 = min(max(d1, 2.0 * max(pyramid.spacing)), 0.2 * d0)
    else:
        d1 = float(end_distance)
        if not (np.isfinite(d1) and 0 < d1):
            raise ParameterError(f"end_distance: expected a finite value > 0, got {end_distance!r}")
    direction = np.cos(np.radians(elevation)) * (np.cos(np.radians(azimuth)) * f + np.sin(np.radians(azimuth)) * side) \
        + np.sin(np.radians(elevation)) * u
    for k in range(n):
        s = k / (n - 1) if n > 1 else 1.0
        d = d0 * (d1 / d0) ** s
        look = c + (p - c) * s
        eye = look + d * direction
        yield _perspective(eye, look, fov_y, size, pyramid, u), np.clip(look, lo, hi)


PATHS = {"orbit": orbit, "turntable": turntable, "fly": fly, "zoom": zoom}


def make_path(name: str, pyramid: Pyramid, frames: int, *, size=(256, 256), **kwargs) -> Iterator[tuple[object, np.ndarray]]:
    """The path called ``name`` (``orbit``, ``turntable``, ``fly`` or ``zoom``) with ``frames`` views of ``size``."""
    if name not in PATHS:
        raise ParameterError(f"path: expected one of {', '.join(PATHS)}, got {name!r}")
    return PATHS[name](pyramid, frames, size=size, **kwargs)
