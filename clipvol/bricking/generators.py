"""Procedural volumes: synthetic data of any size, evaluated region by region at any level.

Two generators, both *linear* in simple primitives so that every pyramid level can be evaluated
directly - no level-0 voxel is ever touched for a coarse level - and still equals what
``clipvol brick --filter mean`` computes from level 0:

* ``fractal`` - a sum of plane waves, a few per octave from the volume's size down to two voxels,
  amplitude falling as ``2**(-0.6 * octave)``: detail at every scale. The mean of a plane wave over
  a block of voxels is the wave at the block centre times a Dirichlet factor per axis, a
  closed form.
* ``sparse`` - a few dozen clusters of nested axis-aligned boxes in empty space; at default
  settings well over 95 % of 64^3 bricks are exactly empty. The mean of a box indicator over a
  block is its overlap fraction.

Consistency with the mean filter is exact (up to float rounding), odd sizes included: along each
axis every voxel but the last of a level is the flat mean of its ``2**L`` level-0 voxels, and the
last one follows the edge-replication recursion of :func:`clipvol.bricking.pyramid.downsample`.

URLs: ``procedural:NAME?size=N`` (a cube) or ``size=ZxYxX``, plus ``seed=S`` and, for ``sparse``,
``count=K`` (clusters). Values are float32 in ``[0, 1]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable
from urllib.parse import parse_qsl

import numpy as np

from ..errors import ParameterError

__all__ = ["GENERATORS", "Generator", "Fractal", "Sparse", "parse_procedural", "ct_head"]

MAX_AXIS = 2**40  # keeps float64 voxel coordinates exact


def _axis_means(n0: int, level: int, start: int, stop: int, flat: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Per-axis level-``level`` means of a 1-D primitive for voxels ``start..stop-1``.

    ``flat(lo, hi)`` returns the plain mean of the primitive over level-0 voxels ``[lo, hi)`` for
    arrays ``lo``, ``hi`` (last axis of the result indexes the voxels). The last voxel of the level
    is recomputed by the edge-replication recursion so that odd sizes match ``downsample``.
    """
    f = 1 << level
    j = np.arange(start, stop, dtype=np.int64)
    out = flat(j * f, (j + 1) * f)
    sizes = [n0]
    for _ in range(level):
        sizes.append((sizes[-1] + 1) // 2)
    n_l = sizes[level]
    if level > 0 and stop == n_l and (n0 % f):
        # recursion for the last voxel: last_L = last_{L-1} if n_{L-1} is odd, else the mean of
        # the flat voxel n_{L-1}-2 and last_{L-1}.
        last = flat(np.array([n0 - 1]), np.array([n0]))[..., 0]
        for L in range(1, level + 1):
            n_prev = sizes[L - 1]
            if n_prev % 2 == 0:
                g = 1 << (L - 1)
                lo = np.array([(n_prev - 2) * g])
                other = flat(lo, lo + g)[..., 0]
                last = 0.5 * (other + last)
        out[..., -1] = last
    return out


@dataclass(frozen=True)
class Generator:
    """Base of the procedural generators: shape ``(z, y, x)``, seed, float32 values in ``[0, 1]``."""

    shape: tuple[int, int, int]
    seed: int = 0

    #: a bound of the values at every level (for transfer-function normalisation)
    name = "generator"
    dtype = np.dtype("float32")
    value_range = (0.0, 1.0)

    def __post_init__(self) -> None:
        if len(self.shape) != 3 or any(int(s) < 1 or int(s) > MAX_AXIS for s in self.shape):
            raise ParameterError(f"procedural:{self.name}: size must be 1..2**40 per axis, got {self.shape}")
        object.__setattr__(self, "shape", tuple(int(s) for s in self.shape))

    def level_shape(self, level: int) -> tuple[int, int, int]:
        s = self.shape
        for _ in range(level):
            s = tuple((v + 1) // 2 for v in s)
        return s  # type: ignore[return-value]

    def region(self, level: int, start, stop) -> np.ndarray:
        """Voxels ``start..stop`` (``(z, y, x)``, stop exclusive) of ``level`` as float32."""
        shp = self.level_shape(level)
        start = tuple(int(v) for v in start)
        stop = tuple(int(v) for v in stop)
        if any(not (0 <= a < b <= n) for a, b, n in zip(start, stop, shp)):
            raise ParameterError(f"procedural:{self.name}: region {start}..{stop} is outside level {level} of shape {shp}")
        return self._region(level, start, stop)

    def _region(self, level, start, stop) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def url(self) -> str:
        z, y, x = self.shape
        size = str(z) if z == y == x else f"{z}x{y}x{x}"
        return f"procedural:{self.name}?size={size}&seed={self.seed}"


@dataclass(frozen=True)
class Fractal(Generator):
    """Sum of plane waves with detail at every scale (see module docstring)."""

    name = "fractal"
    waves_per_octave: int = 3

    def __post_init__(self) -> None:
        Generator.__post_init__(self)
        rng = np.random.default_rng(self.seed)
        n = max(self.shape)
        octaves = max(1, int(np.ceil(np.log2(max(n, 2)))))
        ks, amps, phases = [], [], []
        for o in range(octaves):
            wavelength = n / 2.0**o * 1.5
            wavelength = max(wavelength, 2.2)
            for _ in range(self.waves_per_octave):
                d = rng.normal(size=3)
                d /= np.linalg.norm(d)
                ks.append(2 * np.pi / wavelength * d)  # (kz, ky, kx) rad / voxel, |k_a| < pi
                amps.append(2.0 ** (-0.6 * o))
                phases.append(rng.uniform(0, 2 * np.pi))
        amps = np.array(amps)
        # sum |a| = 0.5 keeps every value, at every level, inside [0, 1] without clipping
        # (clipping would break the exact consistency with the mean filter).
        amps *= 0.5 / np.sum(amps)
        object.__setattr__(self, "_k", np.array(ks))
        object.__setattr__(self, "_a", amps)
        object.__setattr__(self, "_phi", np.array(phases))

    def _axis_terms(self, axis: int, level: int, start: int, stop: int) -> np.ndarray:
        k = self._k[:, axis][:, None]  # (J, 1)

        def flat(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
            # mean of exp(i k i) over i in [lo, hi): geometric series in its symmetric form
            n = (hi - lo).astype(np.float64)[None, :]
            centre = (lo + hi - 1).astype(np.float64)[None, :] / 2.0
            s_half = np.sin(k / 2.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                dirichlet = np.where(np.abs(s_half) < 1e-12, 1.0, np.sin(k * n / 2.0) / (n * s_half))
            return np.exp(1j * k * centre) * dirichlet

        return _axis_means(self.shape[axis], level, start, stop, flat)

    def _region(self, level, start, stop) -> np.ndarray:
        ez = self._axis_terms(0, level, start[0], stop[0])  # (J, nz)
        ey = self._axis_terms(1, level, start[1], stop[1])
        ex = self._axis_terms(2, level, start[2], stop[2])
        c = self._a * np.exp(1j * self._phi)
        # sum_j Im(c_j ez[j,z] ey[j,y] ex[j,x]) as one complex matrix product (BLAS, GIL released)
        zy = (c[:, None, None] * ez[:, :, None] * ey[:, None, :]).reshape(len(c), -1)
        v = (zy.T @ ex).imag.reshape(stop[0] - start[0], stop[1] - start[1], stop[2] - start[2])
        return (0.5 + v).astype(np.float32)


@dataclass(frozen=True)
class Sparse(Generator):
    """Clusters of nested boxes in empty space (see module docstring)."""

    name = "sparse"
    count: int = 24

    def __post_init__(self) -> None:
        Generator.__post_init__(self)
        if not (1 <= int(self.count) <= 10_000):
            raise ParameterError(f"procedural:sparse: count must be 1..10000, got {self.count}")
        rng = np.random.default_rng(self.seed)
        shp = np.array(self.shape, dtype=np.float64)
        lo_l, hi_l, val_l = [], [], []
        placed: list[tuple[np.ndarray, np.ndarray]] = []
        for _ in range(int(self.count)):
            # clusters never overlap, so no value exceeds 1
            for _try in range(100):
                centre = rng.uniform(0.1, 0.9, size=3) * shp
                half = np.maximum(rng.uniform(0.008, 0.03, size=3) * shp, 0.5)
                lo = np.floor(centre - half) - 1
                hi = np.ceil(centre + half) + 1
                if all(np.any(hi <= plo) or np.any(lo >= phi) for plo, phi in placed):
                    break
            else:
                continue
            placed.append((lo, hi))
            for shell, value in ((1.0, 0.35), (0.55, 0.35), (0.25, 0.3)):
                lo = np.clip(np.floor(centre - half * shell), 0, shp - 1)
                hi = np.clip(np.ceil(centre + half * shell), lo + 1, shp)
                lo_l.append(lo)
                hi_l.append(hi)
                val_l.append(value * rng.uniform(0.7, 1.0))
        object.__setattr__(self, "_lo", np.array(lo_l, dtype=np.int64))
        object.__setattr__(self, "_hi", np.array(hi_l, dtype=np.int64))
        object.__setattr__(self, "_v", np.array(val_l))

    def _axis_terms(self, axis: int, level: int, start: int, stop: int, boxes: np.ndarray) -> np.ndarray:
        blo = self._lo[boxes, axis][:, None]
        bhi = self._hi[boxes, axis][:, None]

        def flat(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
            overlap = np.clip(np.minimum(hi[None, :], bhi) - np.maximum(lo[None, :], blo), 0, None)
            return overlap / (hi - lo)[None, :].astype(np.float64)

        return _axis_means(self.shape[axis], level, start, stop, flat)

    def _boxes_touching(self, level: int, start, stop) -> np.ndarray:
        f = 1 << level
        lo0 = np.array(start, dtype=np.int64) * f
        hi0 = np.array(stop, dtype=np.int64) * f
        hit = np.all((self._lo < hi0) & (self._hi > lo0), axis=1)
        return np.nonzero(hit)[0]

    def _region(self, level, start, stop) -> np.ndarray:
        shape = tuple(b - a for a, b in zip(start, stop))
        boxes = self._boxes_touching(level, start, stop)
        if boxes.size == 0:
            return np.zeros(shape, dtype=np.float32)
        mz = self._axis_terms(0, level, start[0], stop[0], boxes)
        my = self._axis_terms(1, level, start[1], stop[1], boxes)
        mx = self._axis_terms(2, level, start[2], stop[2], boxes)
        zy = (self._v[boxes, None, None] * mz[:, :, None] * my[:, None, :]).reshape(len(boxes), -1)
        return (zy.T @ mx).reshape(shape).astype(np.float32)

    def region_bounds(self, level: int, start, stop) -> tuple[float, float]:
        """Loose ``(min, max)`` of a region without evaluating it: ``(0, 0)`` where no box reaches."""
        boxes = self._boxes_touching(level, start, stop)
        return (0.0, float(self._v[boxes].sum()) if boxes.size else 0.0)


GENERATORS: dict[str, type[Generator]] = {"fractal": Fractal, "sparse": Sparse}


def parse_procedural(url: str) -> Generator:
    """Build the generator a ``procedural:NAME?size=...`` URL names; errors name the bad part."""
    if not url.startswith("procedural:"):
        raise ParameterError(f"expected a URL like 'procedural:fractal?size=256', got {url!r}")
    rest = url[len("procedural:"):]
    name, _, query = rest.partition("?")
    if name not in GENERATORS:
        raise ParameterError(f"{url}: unknown procedural dataset {name!r}; expected one of {', '.join(sorted(GENERATORS))}")
    params = dict(parse_qsl(query, keep_blank_values=True))
    kwargs: dict = {}
    size = params.pop("size", "256")
    try:
        parts = [int(p) for p in size.lower().split("x")]
        if len(parts) == 1:
            parts *= 3
        if len(parts) != 3:
            raise ValueError
    except ValueError:
        raise ParameterError(f"{url}: size must be N or ZxYxX, got {size!r}") from None
    kwargs["shape"] = tuple(parts)
    for key in ("seed", "count"):
        if key in params:
            try:
                kwargs[key] = int(params.pop(key))
            except ValueError:
                raise ParameterError(f"{url}: {key} must be an integer") from None
    if "count" in kwargs and name != "sparse":
        raise ParameterError(f"{url}: 'count' applies to procedural:sparse only")
    if params:
        raise ParameterError(f"{url}: unknown parameter(s) {', '.join(sorted(params))}; expected size, seed" + (", count" if name == "sparse" else ""))
    return GENERATORS[name](**kwargs)


def ct_head(shape=(192, 192, 192), seed: int = 0) -> np.ndarray:
    """A CT-like head as ``uint8`` ``(z, y, x)``: flat air, skin, a bone skull shell, brain, ventricles.

    A procedural stand-in for real CT (benchmarks of image-based level of detail need what real
    heads have: an opaque shell that hides most of the interior, soft tissue with low-contrast
    texture, fine relief on the face (``z < -0.25``) and a smooth back of the head, and a large flat
    background). Values: air 0, skin ~70, skull ~215 with a spongier
    diploe (~170), brain ~100 with a gyrus-like texture (+-12), ventricles ~35, edges blurred over
    about 1.5 voxels as a scanner's point spread does (hard steps would alias into voxel-scale
    patterns no real scan has), and a little deterministic noise (``seed``) inside the head only
    (the background stays exactly 0).
    """
    shp = tuple(int(v) for v in shape)
    if len(shp) != 3 or min(shp) < 8:
        raise ParameterError(f"shape: expected three sizes >= 8 (z, y, x), got {shape!r}")
    rng = np.random.default_rng(seed)
    out = np.empty(shp, dtype=np.uint8)
    Z, Y, X = shp
    y = (np.arange(Y) + 0.5) / Y * 2.0 - 1.0
    x = (np.arange(X) + 0.5) / X * 2.0 - 1.0
    yy, xx = np.meshgrid(y, x, indexing="ij")
    w = 1.5 * 2.0 / min(shp)  # edges blur over ~1.5 voxels, like a scanner's point spread

    def step(d):  # 0 -> 1 across an edge at d = 0
        return 0.5 * (1.0 + np.tanh(d / w))

    for z0 in range(0, Z, 16):
        z1 = min(Z, z0 + 16)
        z = ((np.arange(z0, z1) + 0.5) / Z * 2.0 - 1.0)[:, None, None]
        # normalised ellipsoid radius (the head slightly longer front to back)
        r = np.sqrt((xx / 0.78) ** 2 + (yy / 0.88) ** 2 + ((z + 0.05) / 0.86) ** 2)
        # the face (front, z < -0.25) has fine relief on a few-voxel scale; the back of the head is smooth
        face = np.clip((-0.25 - z) / 0.2, 0.0, 1.0)
        r = r + face * 0.015 * np.sin(70.0 * xx + 9.0 * yy) * np.sin(63.0 * yy - 7.0 * xx)
        skin = step(1.0 - r)
        bone = step(0.95 - r) * step(r - 0.83)
        diploe = step(0.90 - r) * step(r - 0.86)  # the spongy layer between the tables
        brain = step(0.81 - r)
        gyri = 12.0 * np.sin(23.0 * xx + 3.0 * z) * np.sin(19.0 * yy - 2.0 * z) * np.cos(17.0 * z + 5.0 * xx)
        q = np.sqrt(((np.abs(xx) - 0.12) / 0.07) ** 2 + ((yy + 0.05) / 0.22) ** 2 + ((z - 0.1) / 0.18) ** 2)
        vent = step((1.0 - q) * 0.07) * brain
        v = 70.0 * skin + 145.0 * bone - 45.0 * diploe + (30.0 + gyri) * brain - (65.0 + gyri) * vent
        inside = skin > 0.5
        v[inside] += rng.normal(0.0, 2.0, size=int(inside.sum()))
        out[z0:z1] = np.clip(np.rint(v), 0, 255).astype(np.uint8)
    return out
