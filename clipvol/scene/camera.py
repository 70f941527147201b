"""The camera: view and projection, frustum culling, projected size and per-pixel rays.

Why a module of its own, free of GL: the selection (which bricks to draw, at which level, in which
order) and the tests' numpy references need the very same camera math as the shaders. Everything
is float64 numpy and relative to the eye where it matters, so a camera a million voxels from the
origin (a huge virtual volume) is as precise as one at the origin.

Conventions (see ``docs/rendering-math.md``):

* world vectors are ``(x, y, z)``; the camera is right-handed: ``right = forward x up``;
* image row 0 is at the *top* (the ``up`` side), column 0 on the left. Looking along ``+z`` with
  ``up = (0, -1, 0)`` gives ``right = +x`` and rows growing with ``y``, like ``vol.max(axis=0)``;
* matrices follow OpenGL: eye space looks down ``-z``, clip ``z`` in ``[-w, w]``;
* perspective: ``eye`` is the centre of projection, ``near``/``far`` are depths along ``forward``
  (``0 < near < far``); orthographic: ``eye`` is ``center`` and ``near``/``far`` are signed
  distances along ``forward`` from the plane through ``center`` (they may be negative).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import ParameterError

__all__ = ["Camera"]


def _vec3(value, name: str) -> tuple[float, float, float]:
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected three finite numbers (x, y, z), got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ParameterError(f"{name}: expected three finite numbers (x, y, z), got {value!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


def _size(value) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in value)
    except (TypeError, ValueError):
        raise ParameterError(f"size: expected (width, height) in pixels, got {value!r}") from None
    if w < 1 or h < 1:
        raise ParameterError(f"size: expected width and height >= 1 pixel, got {value!r}")
    return (w, h)


def _basis(forward, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    u = np.asarray(up, dtype=np.float64)
    nu = np.linalg.norm(u)
    if nu == 0:
        raise ParameterError(f"up: expected a non-zero vector, got {tuple(u)}")
    r = np.cross(f, u / nu)
    nr = np.linalg.norm(r)
    if nr < 1e-9:
        raise ParameterError(f"up: expected a vector not parallel to the view direction {tuple(f)}, got {tuple(u)}")
    r = r / nr
    u = np.cross(r, f)
    return f, u / np.linalg.norm(u), r


class _class_or_instance:
    """``Camera.orthographic(...)`` builds a camera; ``cam.orthographic`` is the instance's flag."""

    def __init__(self, func) -> None:
        self.func = func
        self.__doc__ = func.__doc__

    def __get__(self, obj, cls):
        if obj is None:
            return self.func.__get__(cls, type(cls))
        return obj.ortho


@dataclass(frozen=True, slots=True)
class Camera:
    """A perspective or orthographic camera (immutable; build with :meth:`perspective` / :meth:`orthographic`).

    Parameters
    ----------
    ortho : bool
        Orthographic (parallel) projection if True (also readable as ``cam.orthographic``).
    position : tuple
        Perspective: the eye. Orthographic: the centre of the view (``center``).
    aim : tuple
        The focus point (perspective) or a point along the view direction from ``center``
        (orthographic); read :attr:`target` / :attr:`forward` instead.
    up_hint : tuple
        The requested up vector; :attr:`up` is its part orthogonal to the view direction.
    fov_y : float
        Vertical field of view in degrees (perspective), in ``[1, 170]``.
    width, height : float
        Extent of the view in world units (orthographic).
    size : tuple
        ``(width, height)`` of the image in pixels.
    near, far : float
        Depth range (see the module docstring).
    """

    ortho: bool
    position: tuple[float, float, float]
    aim: tuple[float, float, float]
    up_hint: tuple[float, float, float]
    fov_y: float
    width: float
    height: float
    size: tuple[int, int]
    near: float
    far: float
    # (forward, up, right), computed once: a frame's selection asks for them thousands of times
    _fur: tuple = field(default=(), init=False, repr=False, compare=False)
    # the six frustum planes relative to the eye, made on first use (culling and the merge ask often)
    _planes: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ortho", bool(self.ortho))
        object.__setattr__(self, "position", _vec3(self.position, "eye" if not self.ortho else "center"))
        object.__setattr__(self, "aim", _vec3(self.aim, "target"))
        object.__setattr__(self, "up_hint", _vec3(self.up_hint, "up"))
        object.__setattr__(self, "size", _size(self.size))
        d = np.subtract(self.aim, self.position)
        if not np.any(d) or not np.isfinite(np.linalg.norm(d)) or np.linalg.norm(d) == 0:
            name = "direction" if self.ortho else "target"
            raise ParameterError(f"{name}: expected a view direction of non-zero length, got eye == target {self.position}")
        object.__setattr__(self, "_fur", _basis(d, self.up_hint))  # validates up
        fov = float(self.fov_y)
        if not self.ortho and not (1.0 <= fov <= 170.0):
            raise ParameterError(f"fov_y: expected degrees in [1, 170], got {self.fov_y!r}")
        object.__setattr__(self, "fov_y", fov)
        w, h = float(self.width), float(self.height)
        if self.ortho and not (math.isfinite(w) and math.isfinite(h) and w > 0 and h > 0):
            raise ParameterError(f"width/height: expected finite world extents > 0, got {self.width!r}, {self.height!r}")
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)
        n, f = float(self.near), float(self.far)
        if not (math.isfinite(n) and math.isfinite(f) and n < f):
            raise ParameterError(f"near/far: expected finite near < far, got {self.near!r}, {self.far!r}")
        if not self.ortho and n <= 0:
            raise ParameterError(f"near: expected > 0 for a perspective camera, got {self.near!r}")
        object.__setattr__(self, "near", n)
        object.__setattr__(self, "far", f)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def perspective(cls, eye, target, up=(0.0, 1.0, 0.0), fov_y: float = 45.0, size=(256, 256),
                    near: float | None = None, far: float | None = None) -> "Camera":
        """A perspective camera at ``eye`` looking at ``target``.

        ``near``/``far`` default to 1/1000 and 1000 times the eye-target distance; call
        :meth:`fit_depth` to enclose a box tightly.
        """
        e, t = _vec3(eye, "eye"), _vec3(target, "target")
        dist = float(np.linalg.norm(np.subtract(t, e)))
        if dist == 0:
            raise ParameterError(f"target: expected a point different from eye, got eye == target == {e}")
        near = dist * 1e-3 if near is None else near
        far = dist * 1e3 if far is None else far
        return cls(False, e, t, up, fov_y, 1.0, 1.0, size, near, far)

    @_class_or_instance
    def orthographic(cls, center, direction, up, width: float, height: float, size=(256, 256),
                     near: float | None = None, far: float | None = None) -> "Camera":
        """An orthographic camera centred on ``center`` looking along ``direction``.

        ``width`` x ``height`` world units are seen; ``near``/``far`` default to
        ``-/+ 1000 * max(width, height)`` around ``center``.
        """
        c = _vec3(center, "center")
        d = np.asarray(_vec3(direction, "direction"))
        nd = np.linalg.norm(d)
        if nd == 0:
            raise ParameterError(f"direction: expected a non-zero vector, got {tuple(d)}")
        ext = 1e3 * max(float(width), float(height)) if np.isfinite([width, height]).all() else 1.0
        near = -ext if near is None else near
        far = ext if far is None else far
        # a point along the direction, far enough from the centre to differ from it in float64
        step = max(1.0, float(np.max(np.abs(c)))) * 1e-3
        return cls(True, c, tuple(np.asarray(c) + d / nd * step), up, 45.0, width, height, size, near, far)

    def with_depth_range(self, near: float, far: float) -> "Camera":
        """The same camera with another ``near``/``far``."""
        return replace(self, near=near, far=far)

    def fit_depth(self, box_lo, box_hi) -> "Camera":
        """The same camera with ``near``/``far`` enclosing the box ``[box_lo, box_hi]`` (``(x, y, z)``).

        Perspective: ``near`` is the box's smallest depth, but at least ``far * 1e-5`` (so it is
        > 0 even with the eye inside the box). Orthographic: signed distances, with a small margin.
        """
        lo, hi = np.asarray(_vec3(box_lo, "box_lo")), np.asarray(_vec3(box_hi, "box_hi"))
        corners = np.array([[a[0], b[1], c[2]] for a in (lo, hi) for b in (lo, hi) for c in (lo, hi)])
        depth = (corners - self.eye) @ self.forward
        dmin, dmax = float(depth.min()), float(depth.max())
        span = max(dmax - dmin, float(np.linalg.norm(hi - lo)), 1e-12)
        if self.ortho:
            return self.with_depth_range(dmin - 1e-3 * span, dmax + 1e-3 * span)
        far = dmax * (1 + 1e-6) + 1e-6 * span
        if far <= 0:
            far = span  # the box is behind the eye; any valid range will cull it
        near = max(dmin * (1 - 1e-6), far * 1e-5)
        if near >= far:
            near = far * 1e-5
        return self.with_depth_range(near, far)

    # -- basis --------------------------------------------------------------------------------
    @property
    def eye(self) -> np.ndarray:
        """Centre of projection (perspective) or the view centre (orthographic), ``(x, y, z)``."""
        return np.array(self.position)

    @property
    def center(self) -> np.ndarray:
        """Focus point: ``target`` (perspective) or the view centre (orthographic)."""
        return np.array(self.position if self.ortho else self.aim)

    @property
    def target(self) -> np.ndarray:
        """Focus point, the same as :attr:`center` (for an orthographic camera, the view centre)."""
        return self.center

    @property
    def forward(self) -> np.ndarray:
        """Unit view direction."""
        return self._fur[0].copy()

    @property
    def up(self) -> np.ndarray:
        """Unit up vector, orthogonal to :attr:`forward` (towards image row 0)."""
        return self._fur[1].copy()

    @property
    def right(self) -> np.ndarray:
        """Unit right vector ``forward x up`` (towards the last image column)."""
        return self._fur[2].copy()

    @property
    def aspect(self) -> float:
        """Pixel width / pixel height of the image."""
        return self.size[0] / self.size[1]

    def _half_extents(self) -> tuple[float, float]:
        """Half extent of the view at depth 1 (perspective: tangents) or in world units (ortho)."""
        if self.ortho:
            return self.width / 2.0, self.height / 2.0
        ty = math.tan(math.radians(self.fov_y) / 2.0)
        return ty * self.aspect, ty

    # -- matrices -----------------------------------------------------------------------------
    def view_matrix(self) -> np.ndarray:
        """4x4 world -> eye matrix (eye space looks down ``-z``, ``+y`` up)."""
        f, u, r = (v.copy() for v in self._fur)
        e = self.eye
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ e
        return m

    def projection_matrix(self) -> np.ndarray:
        """4x4 eye -> clip matrix in OpenGL conventions (``glFrustum`` / ``glOrtho``)."""
        n, f = self.near, self.far
        sx, sy = self._half_extents()
        m = np.zeros((4, 4))
        if self.ortho:
            m[0, 0], m[1, 1] = 1.0 / sx, 1.0 / sy
            m[2, 2], m[2, 3] = -2.0 / (f - n), -(f + n) / (f - n)
            m[3, 3] = 1.0
        else:
            m[0, 0], m[1, 1] = 1.0 / sx, 1.0 / sy
            m[2, 2], m[2, 3] = -(f + n) / (f - n), -2.0 * f * n / (f - n)
            m[3, 2] = -1.0
        return m

    def view_projection(self) -> np.ndarray:
        """``projection_matrix() @ view_matrix()``."""
        return self.projection_matrix() @ self.view_matrix()

    # -- culling ------------------------------------------------------------------------------
    def _planes_rel(self) -> np.ndarray:
        """(6, 4) planes ``(n, d)`` with points expressed relative to the eye: inside iff ``n.(p-eye)+d >= 0``.

        Order: left, right, bottom, top, near, far.
        """
        return self._plane_table().copy()

    def _plane_table(self) -> np.ndarray:
        """:meth:`_planes_rel`'s array itself, made once per camera (read it, never write it)."""
        if self._planes:
            return self._planes[0]
        f, u, r = (v.copy() for v in self._fur)
        sx, sy = self._half_extents()
        if self.ortho:
            normals = [r, -r, u, -u, f, -f]
            ds = [sx, sx, sy, sy, -self.near, self.far]
        else:
            normals = [r + sx * f, -r + sx * f, u + sy * f, -u + sy * f, f, -f]
            ds = [0.0, 0.0, 0.0, 0.0, -self.near, self.far]
        out = np.zeros((6, 4))
        for i, (nv, d) in enumerate(zip(normals, ds)):
            k = np.linalg.norm(nv)
            out[i, :3] = nv / k
            out[i, 3] = d / k
        object.__setattr__(self, "_planes", (out,))
        return out

    def frustum_planes(self) -> np.ndarray:
        """(6, 4) unit-normal planes ``(a, b, c, d)``; a point is inside where ``a x + b y + c z + d >= 0``.

        Order: left, right, bottom, top, near, far.
        """
        p = self._planes_rel()
        p[:, 3] -= p[:, :3] @ self.eye
        return p

    def boxes_in_frustum(self, lo, hi) -> np.ndarray:
        """``(n,)`` bool: False only for boxes ``[lo, hi]`` (``(n, 3)``) wholly outside some frustum plane.

        Conservative (a box near a frustum corner may be reported inside).
        """
        return np.all(self._box_reach(lo, hi, 6) >= 0, axis=1)

    def boxes_within_frustum(self, lo, hi) -> np.ndarray:
        """``(n,)`` bool: True for boxes ``[lo, hi]`` wholly inside every frustum plane (then every
        box inside them is :meth:`boxes_in_frustum` too: one test answers for a whole cut)."""
        lo = np.atleast_2d(np.asarray(lo, dtype=np.float64)) - self.eye
        hi = np.atleast_2d(np.asarray(hi, dtype=np.float64)) - self.eye
        c, h = (lo + hi) * 0.5, (hi - lo) * 0.5
        p = self._plane_table()
        return np.all(c @ p[:, :3].T - h @ np.abs(p[:, :3]).T + p[:, 3] >= 0, axis=1)

    def boxes_beside_view(self, lo, hi) -> np.ndarray:
        """``(n,)`` bool: True for boxes wholly outside one of the four side planes of the view.

        No ray of the image passes through such a box at any depth, so nothing drawn there can
        show, whatever the box holds. (The near and far planes are left out: a box in front of the
        near plane or past the far one may still lie on a pixel's ray.)
        """
        return np.any(self._box_reach(lo, hi, 4) < 0, axis=1)

    def _box_reach(self, lo, hi, planes: int) -> np.ndarray:
        """``(n, planes)``: the largest signed distance any point of each box ``[lo, hi]`` reaches
        past each of the first ``planes`` frustum planes (< 0: the box lies wholly outside it)."""
        lo = np.atleast_2d(np.asarray(lo, dtype=np.float64)) - self.eye
        hi = np.atleast_2d(np.asarray(hi, dtype=np.float64)) - self.eye
        c, h = (lo + hi) * 0.5, (hi - lo) * 0.5
        p = self._plane_table()[:planes]
        return c @ p[:, :3].T + h @ np.abs(p[:, :3]).T + p[:, 3]

    def pixels_per_unit(self, depth=1.0) -> np.ndarray:
        """Pixels spanned by one world unit parallel to the image at ``depth`` (any depth if ortho)."""
        sx, sy = self._half_extents()
        k = max(self.size[0] / (2 * sx), self.size[1] / (2 * sy))
        if self.ortho:
            return np.full(np.shape(depth), k)
        return k / np.asarray(depth, dtype=np.float64)

    def projected_size(self, lo, hi, length) -> np.ndarray:
        """``(n,)`` pixels a world segment of ``length`` spans at each box's point nearest the eye.

        "Nearest" is in depth along :attr:`forward` (the smallest depth of the box), which makes
        the estimate an upper bound for a segment parallel to the image. ``inf`` when the box
        contains the eye or straddles the eye plane (depth <= 0 at some point: needs refinement);
        ``0`` for a box wholly behind the eye. Orthographic: independent of depth. Never NaN or
        negative (``length`` is taken by absolute value).
        """
        lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
        hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
        n = lo.shape[0]
        length = np.abs(np.broadcast_to(np.asarray(length, dtype=np.float64), (n,)))
        length = np.where(np.isnan(length), np.inf, length)
        if self.ortho:
            return length * self.pixels_per_unit()
        f = self.forward
        c, h = (lo + hi) * 0.5 - self.eye, (hi - lo) * 0.5
        dc, dh = c @ f, h @ np.abs(f)
        dmin, dmax = dc - dh, dc + dh
        out = np.full(n, np.inf)
        front = dmin > 0
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            out[front] = length[front] * self.pixels_per_unit(dmin[front])
        out[dmax <= 0] = 0.0
        return np.where(np.isnan(out), np.inf, out)

    # -- rays ---------------------------------------------------------------------------------
    def ndc_of_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, y)`` normalised device coordinates ``(h, w)`` of the pixel centres (row 0 at top: y = +1 side)."""
        w, h = self.size
        x = (np.arange(w) + 0.5) / w * 2.0 - 1.0
        y = 1.0 - (np.arange(h) + 0.5) / h * 2.0
        return np.meshgrid(x, y)

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(origins, directions)``, each ``(h, w, 3)``: one ray through every pixel centre.

        Row 0 is the top of the image. Perspective: every origin is the eye, directions are unit.
        Orthographic: origins lie on the plane through :attr:`center` perpendicular to the view
        (the ray parameter runs from ``near`` to ``far``, possibly negative), directions are
        all :attr:`forward`.
        """
        f, u, r = (v.copy() for v in self._fur)
        sx, sy = self._half_extents()
        x, y = self.ndc_of_pixels()
        off = (x * sx)[..., None] * r + (y * sy)[..., None] * u
        if self.ortho:
            origins = self.eye + off
            dirs = np.broadcast_to(f, origins.shape).copy()
        else:
            d = f + off
            dirs = d / np.linalg.norm(d, axis=-1, keepdims=True)
            origins = np.broadcast_to(self.eye, dirs.shape).copy()
        return origins, dirs
