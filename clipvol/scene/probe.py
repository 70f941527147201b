"""Probe and measure: the first visible sample under a pixel, and the distance between two picks.

A user who points at a structure wants its value, where it is in the store's world (millimetres
of the patient, micrometres of the sample) and how far it is from another one. What the user
sees under a pixel is the first place along the pixel's ray where the transfer function makes the
data visible, so :func:`pick` marches the ray front to back through the volume (inside the crop
box and clip planes, if any) and returns the first sample whose opacity — the transfer function's
alpha at the sample's value — reaches a threshold, as iso-surface picking does in volume viewers
(Levoy, *Display of surfaces from volume data*, 1988: the surface is where opacity rises).

Samples take the value of the voxel they fall in (nearest, not interpolated), so the reported
value is a value of the data, at a voxel the report names. Bricks are read through the loader
(``read_brick``) one at a time along the ray and kept in a small cache, so hovering reads only the
bricks under the cursor once. Pure numpy, no GL.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .cut import render_to_world

__all__ = ["Probe", "Prober", "pixel_ray", "pick", "Ruler", "opacity_of"]

#: default opacity (transfer-function alpha) a sample needs to count as visible
THRESHOLD = 0.05
#: samples of a ray taken at a time (front to back; the march stops at the first visible one)
SAMPLES_PER_CHUNK = 4096


@dataclass(frozen=True)
class Probe:
    """The first visible sample along a ray.

    Attributes
    ----------
    value : float
        The data value of :attr:`voxel` (level :attr:`level`).
    level : int
        The pyramid level read.
    voxel : tuple of int
        ``(z, y, x)`` index of the voxel at that level.
    position : ndarray
        ``(x, y, z)`` of the sample in the render frame (array axes, world units).
    world : ndarray
        ``(x, y, z)`` of the sample in the store's world frame (what ``clipvol info`` prints).
    opacity : float
        The transfer function's alpha at :attr:`value`.
    distance : float
        The ray parameter of the sample (from the eye, or the view plane for an orthographic camera).
    """

    value: float
    level: int
    voxel: tuple[int, int, int]
    position: np.ndarray
    world: np.ndarray
    opacity: float
    distance: float

    def describe(self, unit: str = "") -> str:
        """One HUD line: value, level, voxel and world position."""
        u = f" {unit}" if unit else ""
        w = ", ".join(f"{v:.4g}" for v in self.world)
        return f"probe {self.value:.6g} at ({w}){u}, L{self.level} voxel {self.voxel}"


def pixel_ray(camera, x: float, y: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``(origin, unit direction, smallest t)`` of the ray through pixel ``(x, y)`` (row 0 at the top).

    The same rays as :meth:`clipvol.scene.camera.Camera.rays` at pixel centres; ``x, y`` may be
    fractional (``x = 10.5`` is the centre of column 10). Perspective rays start at the eye
    (``t >= 0``); orthographic rays start anywhere on their line.
    """
    w, h = camera.size
    if not (0 <= x <= w and 0 <= y <= h):
        raise ParameterError(f"pixel: expected 0 <= x <= {w} and 0 <= y <= {h}, got ({x}, {y})")
    f, u, r = (np.asarray(v, dtype=np.float64) for v in camera._fur)
    sx, sy = camera._half_extents()
    nx = x / w * 2.0 - 1.0
    ny = 1.0 - y / h * 2.0
    off = nx * sx * r + ny * sy * u
    if camera.ortho:
        return np.asarray(camera.eye, dtype=np.float64) + off, f, -np.inf
    d = f + off
    return np.asarray(camera.eye, dtype=np.float64), d / np.linalg.norm(d), 0.0


def opacity_of(tf, values: np.ndarray, window) -> np.ndarray:
    """The transfer function's alpha at ``values`` as its 1-D texture gives it (linear between texel
    centres, clamped to the ends), ``values`` mapped to ``[0, 1]`` by ``window = (lo, hi)``."""
    table = np.asarray(tf.table, dtype=np.float64)
    lo, hi = (float(v) for v in window)
    t = (np.asarray(values, dtype=np.float64) - lo) / (hi - lo if hi != lo else 1.0)
    n = len(table)
    centres = (np.arange(n) + 0.5) / n
    return np.interp(np.clip(t, 0.0, 1.0), centres, table[:, 3])


class Prober:
    """Picks along rays through one loader's bricks, with a small cache of the bricks it read.

    Parameters
    ----------
    loader : Loader
        Anything with ``pyramid`` and ``read_brick(level, index)``; its ``frame`` (if any) gives the
        world positions.
    cache_bricks : int
        Bricks kept between picks (hovering over one structure reads its bricks once).
    """

    def __init__(self, loader, cache_bricks: int = 64) -> None:
        self.loader = loader
        self.pyramid = loader.pyramid
        self.to_world = render_to_world(self.pyramid, getattr(loader, "frame", None))
        self._cache: OrderedDict = OrderedDict()
        self.cache_bricks = int(cache_bricks)
        #: bricks read from the loader so far (cache misses)
        self.bricks_read = 0

    def _brick(self, level: int, index: tuple[int, int, int]) -> np.ndarray:
        key = (level, index)
        b = self._cache.get(key)
        if b is None:
            b = np.asarray(self.loader.read_brick(level, index))
            self.bricks_read += 1
            self._cache[key] = b
            while len(self._cache) > self.cache_bricks:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return b

    def pick(self, origin, direction, tf, *, level: int = 0, window=None, threshold: float = THRESHOLD,
             step: float = 0.5, shape=None, t_min: float = 0.0) -> Probe | None:
        """The first sample along ``origin + t * direction`` (render frame, ``t >= t_min``) whose
        opacity reaches ``threshold``, or None when the ray sees nothing.

        ``window`` maps values to the transfer function (default ``tf.window(value_range)``);
        ``step`` is the sample spacing in voxels of ``level``; ``shape`` (a
        :class:`~clipvol.scene.geometry.Shape`) leaves out samples outside the cut.
        """
        pyr = self.pyramid
        if not 0 <= int(level) < pyr.num_levels:
            raise ParameterError(f"level: expected 0..{pyr.num_levels - 1}, got {level}")
        if not (0.0 <= threshold <= 1.0):
            raise ParameterError(f"threshold: expected an opacity in [0, 1], got {threshold}")
        if not step > 0:
            raise ParameterError(f"step: expected voxels > 0, got {step}")
        level = int(level)
        o = np.asarray(origin, dtype=np.float64)
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        lo, hi = pyr.volume_box()
        if shape is not None and shape.box is not None:
            lo, hi = np.maximum(lo, shape.box[0]), np.minimum(hi, shape.box[1])
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (lo - o) / d, (hi - o) / d
        ta = np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), ta)
        tb = np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), tb)
        t0 = max(float(np.max(np.minimum(ta, tb))), float(t_min))
        t1 = float(np.min(np.maximum(ta, tb)))
        if not t1 > t0:
            return None
        info = pyr.levels[level]
        scale = np.array(info.scale[::-1], dtype=np.float64)  # x, y, z
        trans = np.array(info.translation[::-1], dtype=np.float64)
        dt = step * float(scale.min())
        n_samples = int(np.ceil((t1 - t0) / dt))
        n = np.array(info.shape[::-1])
        bshape = np.array(pyr.brick_shape)
        if window is None:
            window = tf.window(pyr.value_range)
        # front to back in chunks (a long ray through a huge level need not be held whole), and
        # within a chunk brick by brick: a ray crosses a box once, so a brick's samples are consecutive
        for k0 in range(0, n_samples, SAMPLES_PER_CHUNK):
            ts = t0 + (np.arange(k0, min(k0 + SAMPLES_PER_CHUNK, n_samples)) + 0.5) * dt
            pts = o + ts[:, None] * d
            if shape is not None:
                keep = shape.contains(pts)
                ts, pts = ts[keep], pts[keep]
            if not len(ts):
                continue
            vox = np.clip(np.floor((pts - trans) / scale + 0.5).astype(np.int64), 0, n - 1)[:, ::-1]  # z, y, x
            bricks = vox // bshape
            change = np.flatnonzero(np.any(np.diff(bricks, axis=0) != 0, axis=1)) + 1
            for a, b in zip(np.r_[0, change], np.r_[change, len(ts)]):
                index = tuple(int(v) for v in bricks[a])
                data = self._brick(level, index)
                local = vox[a:b] - bricks[a] * bshape
                vals = data[local[:, 0], local[:, 1], local[:, 2]].astype(np.float64)
                alpha = np.where(np.isfinite(vals), opacity_of(tf, np.nan_to_num(vals), window), 0.0)
                hit = np.flatnonzero(alpha >= threshold) if threshold > 0 else np.flatnonzero(np.isfinite(vals))
                if len(hit):
                    k = int(hit[0])
                    p = pts[a + k]
                    world = p @ self.to_world[:3, :3].T + self.to_world[:3, 3]
                    return Probe(float(vals[k]), level, tuple(int(v) for v in vox[a + k]), p, world, float(alpha[k]),
                                 float(ts[a + k]))
        return None

    def pick_pixel(self, camera, x: float, y: float, tf, **kwargs) -> Probe | None:
        """:meth:`pick` along the ray through pixel ``(x, y)`` of ``camera`` (the frame as rendered,
        before any left-right flip for display)."""
        o, d, t_min = pixel_ray(camera, x, y)
        return self.pick(o, d, tf, t_min=t_min, **kwargs)


def pick(loader, origin, direction, tf, **kwargs) -> Probe | None:
    """One :meth:`Prober.pick` on ``loader`` (no cache kept)."""
    return Prober(loader, cache_bricks=8).pick(origin, direction, tf, **kwargs)


class Ruler:
    """A distance between two picked points, in the store's world unit.

    :meth:`add` takes world points: the first sets one end, the second the other, a third starts a
    new ruler. :attr:`length` is the Euclidean distance of the ends in the world frame (None until
    both are set).
    """

    def __init__(self) -> None:
        self.ends: list[np.ndarray] = []

    def add(self, world) -> None:
        p = np.asarray(world, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ParameterError(f"ruler: expected a finite world point x,y,z, got {world!r}")
        if len(self.ends) == 2:
            self.ends = []
        self.ends.append(p)

    def clear(self) -> None:
        self.ends = []

    @property
    def length(self) -> float | None:
        if len(self.ends) < 2:
            return None
        return float(np.linalg.norm(self.ends[1] - self.ends[0]))

    def describe(self, unit: str = "") -> str:
        """One HUD line."""
        u = f" {unit}" if unit else ""
        if not self.ends:
            return "ruler: -"
        fmt = lambda p: "(" + ", ".join(f"{v:.4g}" for v in p) + ")"  # noqa: E731
        if len(self.ends) == 1:
            return f"ruler: from {fmt(self.ends[0])}{u}, pick the other end"
        return f"ruler: {self.length:.4g}{u} from {fmt(self.ends[0])} to {fmt(self.ends[1])}"
