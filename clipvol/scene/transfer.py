"""Transfer functions: data value -> straight (non-premultiplied) RGBA, as a table.

Why a table: the renderer uploads it as a 1-D texture sampled with ``GL_LINEAR`` and
``CLAMP_TO_EDGE``, and everything on the CPU side that must agree with the picture - the numpy
references in the tests, and above all the empty-space test that lets the renderer skip bricks
the transfer function makes fully transparent without loading them - evaluates *that very
texture* (:meth:`TransferFunction.lookup`, :meth:`TransferFunction.transparent_mask`). A brick
is skipped only when no value in its ``[min, max]`` can reach a table entry with alpha > 0, even
through interpolation, so skipping never changes an image.

Values are normalised over the transfer function's window ``value_range`` (``None``: the data's
range, ``pyramid.value_range``): ``t = clip((v - lo) / (hi - lo), 0, 1)``; a zero-width window is a
step (``t = 0`` below, ``0.5`` at, ``1`` above it); NaN maps to ``t = 0``.

:func:`correct_opacity` adapts an opacity defined for a unit sample spacing to a spacing
``ratio`` times as long, in a form stable near alpha 0 and 1.

Presets are a colour map times an opacity curve (``ramp``, ``flat`` or ``step``, see
:data:`OPACITY_CURVES`) whose first table entry has alpha exactly 0: every value at or below the
window's low end - and NaN - is fully transparent, so a window set with ``--tf-range`` or
``--window`` leaves nothing of the background behind. The one exception is ``diverging`` (for
signed data): it is transparent in a band around the window's centre and keeps its end colours
beyond both ends, because strongly negative values are data, not background.

A transfer function is saved as a small JSON document (:meth:`TransferFunction.to_json`,
:meth:`TransferFunction.save` / :meth:`TransferFunction.load`; the format is described in
``docs/guide.md``) that ``clipvol tf``, the viewer's ``S`` key and the Python API share.

Why one module of this size: presets, windows, JSON files and the opacity correction all make
the one table the renderer and the references sample, and must agree to the entry.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..bricking.pyramid import NEIGHBOUR_OFFSETS
from ..choices import TF_PRESETS
from ..errors import ParameterError
from ..rows import unique_rows

__all__ = ["TransferFunction", "OPACITY_CURVES", "TF_FORMAT", "correct_opacity", "corrected_tables", "fine_table",
           "footprint_ranges", "opacity_curve", "transparency_filter", "window_range"]

# 17 samples (t = 0, 1/16, ..., 1) of matplotlib's perceptually uniform colormaps (CC0 data by
# van der Walt & Smith), tabulated here so that matplotlib is not needed at run time.
_CMAPS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "viridis": ((0.2670, 0.0049, 0.3294), (0.2823, 0.0950, 0.4173), (0.2788, 0.1755, 0.4834), (0.2590, 0.2515, 0.5247), (0.2297, 0.3224, 0.5457), (0.1994, 0.3876, 0.5546), (0.1727, 0.4488, 0.5579), (0.1490, 0.5081, 0.5573), (0.1276, 0.5669, 0.5506), (0.1206, 0.6258, 0.5335), (0.1579, 0.6838, 0.5017), (0.2461, 0.7389, 0.4520), (0.3692, 0.7889, 0.3829), (0.5160, 0.8312, 0.2943), (0.6785, 0.8637, 0.1895), (0.8456, 0.8873, 0.0997), (0.9932, 0.9062, 0.1439)),
    "magma": ((0.0015, 0.0005, 0.0139), (0.0396, 0.0311, 0.1335), (0.1131, 0.0655, 0.2768), (0.2117, 0.0620, 0.4186), (0.3167, 0.0717, 0.4854), (0.4147, 0.1104, 0.5047), (0.5128, 0.1482, 0.5076), (0.6136, 0.1818, 0.4985), (0.7164, 0.2150, 0.4753), (0.8169, 0.2559, 0.4365), (0.9043, 0.3196, 0.3881), (0.9609, 0.4183, 0.3596), (0.9867, 0.5356, 0.3822), (0.9961, 0.6537, 0.4462), (0.9969, 0.7696, 0.5349), (0.9924, 0.8843, 0.6401), (0.9871, 0.9914, 0.7495)),
    "inferno": ((0.0015, 0.0005, 0.0139), (0.0423, 0.0281, 0.1411), (0.1293, 0.0473, 0.2908), (0.2383, 0.0366, 0.3964), (0.3415, 0.0623, 0.4294), (0.4412, 0.0993, 0.4316), (0.5409, 0.1347, 0.4151), (0.6401, 0.1714, 0.3811), (0.7357, 0.2159, 0.3302), (0.8224, 0.2752, 0.2661), (0.8943, 0.3534, 0.1936), (0.9470, 0.4492, 0.1153), (0.9784, 0.5579, 0.0349), (0.9879, 0.6753, 0.0653), (0.9746, 0.7977, 0.2063), (0.9476, 0.9174, 0.4107), (0.9884, 0.9984, 0.6449)),
    "plasma": ((0.0504, 0.0298, 0.5280), (0.1934, 0.0184, 0.5903), (0.2999, 0.0096, 0.6316), (0.3994, 0.0009, 0.6561), (0.4949, 0.0120, 0.6579), (0.5844, 0.0686, 0.6328), (0.6651, 0.1386, 0.5856), (0.7360, 0.2094, 0.5279), (0.7982, 0.2802, 0.4695), (0.8533, 0.3516, 0.4137), (0.9018, 0.4251, 0.3597), (0.9426, 0.5026, 0.3058), (0.9734, 0.5858, 0.2515), (0.9914, 0.6754, 0.1985), (0.9930, 0.7717, 0.1548), (0.9744, 0.8746, 0.1441), (0.9400, 0.9752, 0.1313)),
}

# CT-like: air and fat transparent, a faint translucent skin-coloured band for soft tissue, then
# opacity rising to opaque white bone at the top of the range.
_BONE = (
    (0.00, (0.0, 0.0, 0.0, 0.0)),
    (0.25, (0.0, 0.0, 0.0, 0.0)),
    (0.30, (0.85, 0.45, 0.30, 0.08)),
    (0.42, (0.95, 0.65, 0.45, 0.12)),
    (0.50, (0.95, 0.70, 0.50, 0.02)),
    (0.60, (0.90, 0.85, 0.75, 0.25)),
    (0.80, (0.97, 0.95, 0.90, 0.80)),
    (1.00, (1.00, 1.00, 1.00, 1.00)),
)

# The demo's: transparent below 60 % of the range, embers to white-hot above.
_DEMO = (
    (0.0, (0.0, 0.0, 0.0, 0.0)),
    (0.60, (0.2, 0.1, 0.5, 0.0)),
    (0.68, (0.9, 0.3, 0.2, 0.35)),
    (0.80, (1.0, 0.8, 0.4, 0.9)),
    (1.0, (1.0, 1.0, 1.0, 1.0)),
)

# Diverging blue - light grey - red (after Moreland's "cool to warm"), for signed data around 0.
_DIVERGING_RGB = ((0.230, 0.299, 0.754), (0.553, 0.690, 0.996), (0.865, 0.865, 0.865), (0.958, 0.603, 0.482), (0.706, 0.016, 0.150))

#: the highest opacity of the colour-map presets' curves (per unit sample spacing)
MAX_ALPHA = 0.6

#: opacity curves over the window, t in [0, 1] -> alpha; all are 0 at t = 0
OPACITY_CURVES = {
    # a gentle ramp: quadratic, so the low end of the window (where most foreground voxels of a
    # CT or a fluorescence stack sit) stays see-through and the bright structure shows
    "ramp": lambda t: MAX_ALPHA * t * t,
    # constant inside the window (thresholding), zero below it
    "flat": lambda t: np.where(t > 0, 0.25 * MAX_ALPHA, 0.0),
    # an iso-surface-like step: transparent in the lower half, opaque above
    "step": lambda t: np.where(t >= 0.5, 1.0, 0.0),
}

#: the presets' names (:mod:`clipvol.choices`, where the command line reads them without numpy)
_PRESETS = TF_PRESETS

#: the ``format`` field of a saved transfer function
TF_FORMAT = "clipvol-transfer-function"


def opacity_curve(kind: str, n: int = 256) -> np.ndarray:
    """``(n,)`` alpha of the opacity curve ``kind`` at the texel centres, entry 0 exactly 0."""
    if kind not in OPACITY_CURVES:
        raise ParameterError(f"opacity: expected one of {', '.join(OPACITY_CURVES)}, got {kind!r}")
    x = (np.arange(int(n)) + 0.5) / int(n)
    a = np.clip(np.asarray(OPACITY_CURVES[kind](x), dtype=np.float64), 0.0, 1.0)
    a[0] = 0.0
    return a


def window_range(center: float, width: float) -> tuple[float, float]:
    """``(lo, hi)`` of a window/level pair: ``center -/+ width / 2`` (width >= 0)."""
    c, w = float(center), float(width)
    if not (math.isfinite(c) and math.isfinite(w) and w >= 0):
        raise ParameterError(f"window: expected a finite centre and width >= 0, got {center!r}, {width!r}")
    return (c - w / 2.0, c + w / 2.0)


def _check_range(value_range, name: str = "value_range") -> tuple[float, float] | None:
    if value_range is None:
        return None
    try:
        lo, hi = (float(v) for v in value_range)
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected (low, high) numbers or None, got {value_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ParameterError(f"{name}: expected finite (low, high) with low <= high, got {value_range!r}")
    return (lo, hi)


def correct_opacity(alpha, ratio):
    """Opacity of a sample ``ratio`` times as long as the one ``alpha`` is defined for.

    ``1 - (1 - alpha) ** ratio``, computed as ``-expm1(ratio * log1p(-alpha))``: exact to float
    rounding at alpha near 0 (no cancellation) and alpha near 1 (``alpha = 1`` gives 1 for any
    ``ratio > 0``). ``alpha`` is clipped to ``[0, 1]``; ``ratio`` must be >= 0 (0 gives 0).
    Works on scalars and arrays (float64 out).
    """
    a = np.clip(np.asarray(alpha, dtype=np.float64), 0.0, 1.0)
    r = np.asarray(ratio, dtype=np.float64)
    if np.any(r < 0) or np.any(np.isnan(r)):
        raise ParameterError(f"ratio: expected values >= 0, got {ratio!r}")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = -np.expm1(r * np.log1p(-a))
    out = np.where(a >= 1.0, np.where(r > 0, 1.0, 0.0), out)
    out = np.where(r == 0, 0.0, out)
    out = np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0)
    return out if out.ndim else float(out)


class TransferFunction:
    """A straight-alpha RGBA table of ``n`` entries over the normalised value ``t`` in ``[0, 1]``.

    Entry ``i`` sits at ``t = (i + 0.5) / n`` (a texel centre); between entries the colour is
    interpolated linearly and it is clamped beyond the first and last centre, exactly like a
    ``GL_LINEAR``/``CLAMP_TO_EDGE`` 1-D texture of :attr:`table`.

    Parameters
    ----------
    table : array_like
        ``(n, 4)`` RGBA in ``[0, 1]``, ``n >= 1``.
    value_range : tuple or None
        The window ``(lo, hi)`` of data values mapped to ``t = 0 .. 1``; None uses the data's range.
    """

    __slots__ = ("_table", "_value_range", "_name")

    def __init__(self, table, value_range=None, name: str | None = None) -> None:
        t = np.asarray(table, dtype=np.float64)
        if t.ndim != 2 or t.shape[1] != 4 or t.shape[0] < 1:
            raise ParameterError(f"table: expected an (n, 4) RGBA array with n >= 1, got shape {t.shape}")
        if not np.all(np.isfinite(t)) or t.min() < 0 or t.max() > 1:
            raise ParameterError("table: expected RGBA values in [0, 1]")
        self._table = np.ascontiguousarray(t, dtype=np.float32)
        self._table.setflags(write=False)
        self._value_range = _check_range(value_range)
        self._name = None if name is None else str(name)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Names accepted by :meth:`preset`."""
        return _PRESETS

    @classmethod
    def from_points(cls, points: Sequence, value_range=None, n: int = 256, name: str | None = None) -> "TransferFunction":
        """Piecewise-linear RGBA through control points ``[(t, (r, g, b, a)), ...]``, ``t`` ascending in ``[0, 1]``.

        The table holds the curve evaluated at the texel centres ``(i + 0.5) / n``; the curve is
        constant beyond the first and last point.
        """
        n = int(n)
        if n < 1:
            raise ParameterError(f"n: expected a table size >= 1, got {n}")
        try:
            ts = np.array([float(p[0]) for p in points])
            cs = np.array([[float(c) for c in p[1]] for p in points])
        except (TypeError, ValueError, IndexError):
            raise ParameterError(f"points: expected a sequence of (t, (r, g, b, a)), got {points!r}") from None
        if ts.size == 0 or cs.shape != (ts.size, 4):
            raise ParameterError(f"points: expected at least one (t, (r, g, b, a)), got {points!r}")
        if not np.all(np.isfinite(ts)) or ts.min() < 0 or ts.max() > 1 or np.any(np.diff(ts) < 0):
            raise ParameterError(f"points: expected t ascending in [0, 1], got {ts.tolist()}")
        if not np.all(np.isfinite(cs)) or cs.min() < 0 or cs.max() > 1:
            raise ParameterError("points: expected RGBA values in [0, 1]")
        x = (np.arange(n) + 0.5) / n
        table = np.stack([np.interp(x, ts, cs[:, k]) for k in range(4)], axis=1)
        return cls(table, value_range, name)

    @classmethod
    def from_value_points(cls, points: Sequence, n: int = 256, name: str | None = "points") -> "TransferFunction":
        """Piecewise-linear RGBA through control points in *data values* ``[(v, (r, g, b, a)), ...]``.

        The window is ``(first v, last v)``: below the first point the colour and opacity are
        the first point's, above the last the last point's (give the first point alpha 0 for a
        transparent background). One point is a step at that value.
        """
        try:
            vs = np.array([float(p[0]) for p in points])
        except (TypeError, ValueError, IndexError):
            raise ParameterError(f"points: expected a sequence of (value, (r, g, b, a)), got {points!r}") from None
        if vs.size == 0 or not np.all(np.isfinite(vs)) or np.any(np.diff(vs) <= 0):
            raise ParameterError(f"points: expected at least one finite value, strictly ascending, got {vs.tolist()}")
        lo, hi = float(vs[0]), float(vs[-1])
        ts = np.zeros(1) if hi == lo else (vs - lo) / (hi - lo)
        ts = np.clip(ts, 0.0, 1.0)
        tf = cls.from_points([(float(t), p[1]) for t, p in zip(ts, points)], (lo, hi), n, name)
        # the end texels hold the end points exactly, so what lies beyond the window is what the
        # user wrote (alpha 0 below a first point of alpha 0), not half a texel of interpolation
        table = tf.table.copy()
        table[0] = [float(c) for c in points[0][1]]
        table[-1] = [float(c) for c in points[-1][1]]
        return cls(table, (lo, hi), name)

    @classmethod
    def parse_points(cls, text: str, n: int = 256) -> "TransferFunction":
        """:meth:`from_value_points` of the command-line form ``"v:r,g,b,a;v:r,g,b,a;..."``."""
        pts = []
        for item in str(text).split(";"):
            if not item.strip():
                continue
            try:
                v, rgba = item.split(":")
                c = tuple(float(x) for x in rgba.split(","))
                if len(c) != 4:
                    raise ValueError
                pts.append((float(v), c))
            except ValueError:
                raise ParameterError(f"--tf-points: expected 'value:r,g,b,a' items separated by ';', got {item.strip()!r}") from None
        return cls.from_value_points(pts, n)

    @classmethod
    def preset(cls, name: str, value_range=None, n: int = 256, opacity: str | None = None) -> "TransferFunction":
        """A named transfer function (see :meth:`names`) over the window ``value_range``.

        ``grey``: rgb = t. ``viridis``/``magma``/``inferno``/``plasma``: matplotlib's colours.
        These four and ``grey`` take the opacity curve ``opacity`` (default ``ramp``, see
        :data:`OPACITY_CURVES`). ``bone``: CT-like (transparent below soft tissue, a translucent
        skin-coloured band, opaque white bone at the top). ``demo``: the demo's embers.
        ``diverging``: blue - grey - red for signed data, transparent within 20 % of the
        half-width around the window's centre (centre the window on 0). Giving ``opacity``
        replaces a preset's own alpha with that curve. Alpha is exactly 0 at and below the low
        end of the window for every preset but ``diverging``.
        """
        x = (np.arange(int(n)) + 0.5) / max(int(n), 1)
        given = opacity
        if name == "grey" or name == "gray":
            tf = cls.from_points([(0.0, (0, 0, 0, 0)), (1.0, (1, 1, 1, 1))], value_range, n)
            opacity = opacity or "ramp"
        elif name in _CMAPS:
            cols = _CMAPS[name]
            k = len(cols) - 1
            tf = cls.from_points([(i / k, (*c, 0.0)) for i, c in enumerate(cols)], value_range, n)
            opacity = opacity or "ramp"
        elif name == "bone":
            tf = cls.from_points(_BONE, value_range, n)
        elif name == "demo":
            tf = cls.from_points(_DEMO, value_range, n)
        elif name == "diverging":
            k = len(_DIVERGING_RGB) - 1
            tf = cls.from_points([(i / k, (*c, 0.0)) for i, c in enumerate(_DIVERGING_RGB)], value_range, n)
            d = np.abs(x - 0.5) * 2.0  # 0 at the centre, 1 at either end
            thr = 0.2
            a = np.clip((d - thr) / (1.0 - thr), 0.0, 1.0)
            table = tf.table.astype(np.float64)
            table[:, 3] = np.where(d > thr, 0.05 + (MAX_ALPHA - 0.05) * a, 0.0)
            if opacity is not None:
                raise ParameterError("opacity: the diverging preset has its own (transparent around the centre); "
                                     f"expected no opacity curve, got {opacity!r}")
            return cls(table, value_range, "diverging")
        else:
            raise ParameterError(f"transfer function preset: expected one of {', '.join(_PRESETS)}, got {name!r}")
        table = tf.table.astype(np.float64)
        if opacity is not None:
            table[:, 3] = opacity_curve(opacity, n)
        table[0, 3] = 0.0  # nothing at or below the window's low end
        label = "grey" if name == "gray" else name
        return cls(table, value_range, label if given in (None, "ramp") and opacity in (None, "ramp") else f"{label} ({opacity})")

    # -- saving -------------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The JSON document of this transfer function (see ``docs/guide.md``, "Transfer functions").

        ``points`` holds every table entry as ``[t, r, g, b, a]`` at its texel centre, so that
        :meth:`from_json` rebuilds the identical table.
        """
        n = len(self._table)
        x = (np.arange(n) + 0.5) / n
        return {
            "format": TF_FORMAT,
            "version": 1,
            "name": self._name,
            "value_range": None if self._value_range is None else list(self._value_range),
            "size": n,
            "points": [[float(t), *(float(c) for c in row)] for t, row in zip(x, self._table)],
        }

    @classmethod
    def from_json(cls, doc, where: str = "transfer function") -> "TransferFunction":
        """A transfer function from a JSON document: ``points`` (``[t, r, g, b, a]``, t in the
        window ``value_range``) or ``value_points`` (``[value, r, g, b, a]`` in data values)."""
        if not isinstance(doc, dict) or doc.get("format", TF_FORMAT) != TF_FORMAT:
            raise ParameterError(f"{where}: expected a JSON object with format {TF_FORMAT!r}")
        n = doc.get("size", 256)
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 65536:
            raise ParameterError(f"{where}: size: expected an integer 1..65536, got {n!r}")
        name = doc.get("name")
        try:
            if "value_points" in doc:
                pts = [(p[0], p[1:5]) for p in doc["value_points"]]
                if any(len(p[1]) != 4 for p in pts):
                    raise TypeError
                return cls.from_value_points(pts, n, name)
            pts = [(p[0], p[1:5]) for p in doc["points"]]
            if any(len(p[1]) != 4 for p in pts):
                raise TypeError
        except (KeyError, TypeError, IndexError):
            raise ParameterError(f"{where}: expected 'points' (or 'value_points') as a list of [t, r, g, b, a]") from None
        try:
            return cls.from_points(pts, _check_range(doc.get("value_range")), n, name)
        except ParameterError as e:
            raise ParameterError(f"{where}: {e}") from None

    def save(self, path) -> Path:
        """Write :meth:`to_json` to ``path`` (its folder must exist); returns the path."""
        path = Path(path)
        if not path.parent.is_dir():
            raise ParameterError(f"{path}: expected an existing folder {str(path.parent)!r} to save the transfer function in")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path) -> "TransferFunction":
        """Read a transfer function saved by :meth:`save` (or written by hand, see :meth:`from_json`)."""
        path = Path(path)
        try:
            doc = json.loads(path.read_text())
        except FileNotFoundError:
            raise ParameterError(f"{path}: no such transfer-function file") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise ParameterError(f"{path}: expected a JSON transfer function, could not read it ({e})") from None
        return cls.from_json(doc, str(path))

    # -- properties ---------------------------------------------------------------------------
    @property
    def table(self) -> np.ndarray:
        """``(n, 4)`` float32 straight RGBA (read-only)."""
        return self._table

    @property
    def value_range(self) -> tuple[float, float] | None:
        """The window of data values mapped to ``t = 0 .. 1``, or None for the data's range."""
        return self._value_range

    @property
    def name(self) -> str | None:
        """A label for the HUD and the report (the preset's name, ``auto``, ``points``...), or None."""
        return self._name

    def with_value_range(self, value_range) -> "TransferFunction":
        """The same table over another window."""
        return TransferFunction(self._table, value_range, self._name)

    def with_name(self, name: str | None) -> "TransferFunction":
        """The same table and window under another label."""
        return TransferFunction(self._table, self._value_range, name)

    def with_opacity(self, kind: str) -> "TransferFunction":
        """The same colours with the opacity curve ``kind`` (alpha 0 at and below the window)."""
        table = self._table.astype(np.float64)
        table[:, 3] = opacity_curve(kind, len(table))
        return TransferFunction(table, self._value_range, f"{self._name or 'custom'} ({kind})")

    def __repr__(self) -> str:
        return f"TransferFunction(n={len(self._table)}, value_range={self._value_range}, name={self._name!r})"

    # -- evaluation ---------------------------------------------------------------------------
    def window(self, data_range) -> tuple[float, float]:
        """The ``(lo, hi)`` in effect: :attr:`value_range`, else ``data_range``."""
        if self._value_range is not None:
            return self._value_range
        r = _check_range(data_range, "data_range")
        if r is None:
            raise ParameterError("data_range: expected (low, high) when the transfer function has no value_range, got None")
        return r

    def normalise(self, values, data_range=None) -> np.ndarray:
        """``t = clip((v - lo) / (hi - lo), 0, 1)`` in float64 (zero-width window: a step; NaN: 0)."""
        lo, hi = self.window(data_range)
        v = np.asarray(values, dtype=np.float64)
        if hi > lo:
            with np.errstate(invalid="ignore", over="ignore"):
                t = np.clip((v - lo) / (hi - lo), 0.0, 1.0)
        else:
            t = np.where(v < lo, 0.0, np.where(v > hi, 1.0, 0.5))
        return np.where(np.isnan(v), 0.0, t)

    def _texcoord(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(self._table)
        u = t * n - 0.5
        i0 = np.floor(u)
        f = u - i0
        i0 = i0.astype(np.int64)
        return np.clip(i0, 0, n - 1), np.clip(i0 + 1, 0, n - 1), f

    def lookup(self, values, data_range=None) -> np.ndarray:
        """``(..., 4)`` float64 straight RGBA of ``values``, as the ``GL_LINEAR`` texture gives it."""
        t = self.normalise(values, data_range)
        i0, i1, f = self._texcoord(t)
        tab = self._table.astype(np.float64)
        return tab[i0] * (1.0 - f)[..., None] + tab[i1] * f[..., None]

    def transparent_mask(self, ranges, data_range=None) -> np.ndarray:
        """``(n,)`` bool: True where alpha is 0 for every value in ``[min, max]`` of each row of ``ranges``.

        Exact with respect to :meth:`lookup` and conservative: every table entry that any value of
        the range reaches with a non-zero interpolation weight must have alpha 0. A NaN bound
        gives False (unknown data may be visible).
        """
        r = np.asarray(ranges, dtype=np.float64).reshape(-1, 2)
        bad = np.isnan(r).any(axis=1)
        t0 = self.normalise(np.where(bad, 0.0, r[:, 0]), data_range)
        t1 = self.normalise(np.where(bad, 0.0, r[:, 1]), data_range)
        t0, t1 = np.minimum(t0, t1), np.maximum(t0, t1)
        n = len(self._table)
        first = np.clip(np.floor(t0 * n - 0.5).astype(np.int64), 0, n - 1)
        last = np.clip(np.ceil(t1 * n - 0.5).astype(np.int64), 0, n - 1)
        visible = np.concatenate([[0], np.cumsum(self._table[:, 3] > 0)])
        hits = visible[last + 1] - visible[first]
        return (hits == 0) & ~bad



def footprint_ranges(ranges_fn, grid, level: int, idx) -> np.ndarray | None:
    """``(n, 2)`` bounds of every value the samples inside each brick's box can read.

    Why not the brick's own range: a sample within half a voxel of a face of the node box is
    trilinear between the brick's last voxel and the neighbour's first, so a brick whose own
    values are all transparent still shows a visible neighbour's edge there. Skipping it drew
    those samples nowhere (up to 44 LSB on an opaque transfer function at faces between a bone
    brick and a culled air brick). The bounds here span the brick and its 26 neighbours (inside
    the ``grid``); a NaN bound anywhere gives NaN (unknown). None when ``ranges_fn`` answers None.
    """
    idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
    if len(idx) == 0:
        return np.zeros((0, 2))
    g = np.asarray(grid, dtype=np.int64)
    nb = np.clip(idx[:, None, :] + NEIGHBOUR_OFFSETS[None], 0, g - 1).reshape(-1, 3)
    uniq, inv = unique_rows(nb, return_inverse=True)  # the distinct neighbours (clipvol/rows.py: why not np.unique)
    r = ranges_fn(level, uniq)
    if r is None:
        return None
    r = np.asarray(r, dtype=np.float64).reshape(-1, 2)[np.asarray(inv).reshape(-1)].reshape(len(idx), 27, 2)
    return np.stack([r[:, :, 0].min(axis=1), r[:, :, 1].max(axis=1)], axis=1)  # NaN propagates


#: levels of at most this many bricks are answered whole by :func:`transparency_filter`
WHOLE_LEVEL_BRICKS = 1 << 18


def transparency_filter(tf: TransferFunction, loader):
    """A ``transparent(level, idx) -> (n,) bool`` callback for :func:`clipvol.scene.selection.select`.

    Uses the loader's :class:`~clipvol.paging.loader.HasBrickRanges` bounds (no brick is read)
    over each brick's sampling footprint (:func:`footprint_ranges`: the brick and its
    neighbours) and :meth:`TransferFunction.transparent_mask` over the loader's
    ``pyramid.value_range``. Returns None when the loader has no ``brick_ranges``; where it answers
    None for a level, nothing is reported transparent.

    The answer for a brick depends only on ``tf`` and the store's recorded ranges, never on the
    view, so a level of at most :data:`WHOLE_LEVEL_BRICKS` bricks is answered for all its bricks at
    its first question and looked up after that (a caller that keeps the callback for a transfer
    function, as the render action does, pays it once, not every frame).
    """
    ranges_fn = getattr(loader, "brick_ranges", None)
    if ranges_fn is None:
        return None
    pyr = loader.pyramid
    data_range = pyr.value_range
    whole: dict[int, np.ndarray] = {}  # level -> transparent mask over its whole grid

    def transparent(level: int, idx: np.ndarray) -> np.ndarray:
        idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
        grid = tuple(int(v) for v in pyr.grid(level))
        mask = whole.get(level)
        if mask is None and int(np.prod(grid)) <= WHOLE_LEVEL_BRICKS:
            every = np.indices(grid).reshape(3, -1).T
            r = footprint_ranges(ranges_fn, grid, level, every)
            if r is not None:  # (a remote store's statistics may come later: not kept until they do)
                mask = whole[level] = tf.transparent_mask(r, data_range).reshape(grid)
        if mask is not None:
            return mask[idx[:, 0], idx[:, 1], idx[:, 2]]
        r = footprint_ranges(ranges_fn, grid, level, idx)
        if r is None:
            return np.zeros(len(idx), dtype=bool)
        return tf.transparent_mask(r, data_range)

    return transparent


def fine_table(table: np.ndarray, oversample: int = 16) -> np.ndarray:
    """``(n * k, 4)`` float64: ``table`` as ``GL_LINEAR`` reads it at the centres of a table ``k``
    times finer (``k = oversample``, capped so the result stays within 8192 entries); see
    :func:`corrected_tables`."""
    tab = np.asarray(table, dtype=np.float64)
    n = len(tab)
    k = max(1, min(int(oversample), 8192 // max(n, 1)))
    x = (np.arange(n * k) + 0.5) / k - 0.5  # fine texel centres in coarse texel units
    i = np.floor(x)
    f = (x - i)[:, None]
    return tab[np.clip(i, 0, n - 1).astype(np.int64)] * (1.0 - f) + tab[np.clip(i + 1, 0, n - 1).astype(np.int64)] * f


def corrected_tables(table: np.ndarray, ratios, oversample: int = 16) -> np.ndarray:
    """``(len(ratios), n * k, 4)`` float64: ``table`` (straight RGBA, ``n`` entries) resampled ``k``
    times finer, with its opacity corrected by each ratio (:func:`correct_opacity`:
    ``1 - (1 - a) ** ratio``, in the stable log1p/expm1 form), one row per level. Computed on the
    CPU when the table or the step changes, so the shader does one lookup per sample and no log/exp.

    Why resample: the shader interpolates the *corrected* table linearly, while the exact result is
    the correction of the *interpolated* opacity; the correction is strongly non-linear for large
    ratios (coarse levels, anisotropic voxels), so between two coarse entries the two differ by
    many 8-bit steps. Entry ``j`` of the fine table is the coarse table as ``GL_LINEAR`` reads it at
    the fine texel's centre (the same texture coordinate convention), so the error shrinks with
    ``k**2``; ``k`` is capped so the row stays within 8192 texels.
    """
    fine = fine_table(table, oversample)
    rows = np.repeat(fine[None], len(ratios), axis=0)
    for r_i, r in enumerate(ratios):
        rows[r_i, :, 3] = correct_opacity(fine[:, 3], float(r))
    return rows
