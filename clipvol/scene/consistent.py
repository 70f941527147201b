"""Consistent coarse levels: the transfer function applied to the distribution beneath a coarse voxel.

A coarse voxel of the pyramid is the mean of the level-0 voxels beneath it. Classifying that mean -
looking it up in the transfer function - gives a colour and an opacity that none of those voxels has
where they differ: bone (bright, opaque) next to air (dark, transparent) averages to a value the
table may make transparent, or give another colour, so thin bright structures fade or thicken level
by level. What the coarse sample should show is the **expected** classification of the fine voxels it
stands for (Younesy, Möller & Carr, *Improving the quality of multi-resolution volume rendering*,
2006; Sicat, Krüger, Möller & Hadwiger, *Sparse PDF Volumes for Consistent Multi-Resolution Volume
Rendering*, 2014): the expected opacity ``E[a(x)]`` and the expected premultiplied colour
``E[a(x) c(x)]`` over the distribution of the values ``x`` beneath it.

The store keeps each coarse voxel's mean (the level) and spread (the standard deviation of the
level-0 values beneath it, :mod:`clipvol.bricking.spread`). The renderer models the distribution as a
normal one of that mean and spread, and looks the sample up in a **2-D table** (:func:`distribution_tables`)
of the transfer function pre-integrated over that distribution: entry ``(mu, sigma)`` holds

* opacity ``A = E[a]``, then corrected for the level's step like every table row
  (:func:`~clipvol.scene.transfer.correct_opacity`: ``1 - (1 - A) ** ratio``), and
* straight colour ``E[a c] / E[a]``, so the compositing ``w * rgb`` adds ``w * E[a c] / E[a]`` -
  the premultiplied expectation - unchanged from the plain table's loop.

Row ``sigma = 0`` is the plain table (the same numbers as
:func:`~clipvol.scene.transfer.corrected_tables`), so level 0, whose spread is 0, draws as before.
The expectation is a convolution of the (finely resampled) table with a normal kernel truncated at
:data:`KERNEL_SIGMAS` standard deviations, the table's ends extended (the GL lookup clamps the
coordinate the same way), done by FFT per spread row: rebuilt on the CPU when the table or the step
changes, one texture lookup per sample on the GPU.

Spread rows: ``sigma_s = SPREAD_MAX * (s / (rows - 1)) ** 2`` in units of the window (the table's
coordinate), dense near 0 where a small spread already changes a sharp table; the shader reads row
coordinate ``sqrt(sigma / SPREAD_MAX) * (rows - 1)``, linearly interpolated. A sample whose spread
exceeds the window clamps to the last row.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError
from .transfer import correct_opacity, fine_table

__all__ = ["SPREAD_ROWS", "SPREAD_MAX", "KERNEL_SIGMAS", "MODELS", "MODEL", "spread_row_sigmas", "distribution_tables",
           "DistributionRanges", "expected_colours", "expected_premultiplied", "spread_support"]

#: spread rows of the table (per level)
SPREAD_ROWS = 32
#: the largest spread of the table, in units of the transfer function's window
SPREAD_MAX = 1.0
#: the normal kernel is truncated here (its mass beyond is below 1e-4)
KERNEL_SIGMAS = 4.0


def spread_row_sigmas(rows: int = SPREAD_ROWS) -> np.ndarray:
    """``(rows,)`` float64: the spread of each row, in units of the window (quadratic spacing)."""
    s = np.arange(rows, dtype=np.float64) / (rows - 1)
    return SPREAD_MAX * s * s


#: a kernel wider than this many entries is applied to the table averaged over blocks of entries
#: (a power of two in size, at most 1/128 of a standard deviation) and read back linearly: the FFTs
#: of the wide rows span a few thousand entries instead of tens of thousands (the bone table's 5
#: levels in half the time) at an error below 1e-3 in opacity and premultiplied colour (a quarter of
#: an 8-bit step; measured against the full-width convolution)
SMOOTH_MAX_SIGMA = 256.0


def _smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """``values`` ``(N, c)`` convolved along axis 0 with a normal kernel of ``sigma`` entries,
    truncated at :data:`KERNEL_SIGMAS`, the ends extended (edge values repeated)."""
    n = len(values)
    q = 1
    while sigma / (2 * q) >= SMOOTH_MAX_SIGMA and n // (2 * q) >= 64:
        q *= 2
    if q > 1:  # block means, smoothed, read back linearly at the entries' centres
        m = -(-n // q) * q
        padded = np.concatenate([values, np.repeat(values[-1:], m - n, axis=0)]) if m > n else values
        coarse = _smooth(padded.reshape(m // q, q, -1).mean(axis=1), sigma / q)
        x = (np.arange(n) + 0.5) / q - 0.5
        j = np.arange(m // q, dtype=np.float64)
        return np.stack([np.interp(x, j, coarse[:, c]) for c in range(values.shape[1])], axis=1)
    half = int(math.ceil(KERNEL_SIGMAS * sigma))
    if half < 1:
        return values.copy()
    d = np.arange(-half, half + 1, dtype=np.float64)
    k = np.exp(-0.5 * (d / sigma) ** 2)
    k /= k.sum()
    padded = np.concatenate([np.repeat(values[:1], half, axis=0), values, np.repeat(values[-1:], half, axis=0)])
    m = len(padded) + len(k) - 1
    size = 1 << (m - 1).bit_length()
    out = np.fft.irfft(np.fft.rfft(padded, size, axis=0) * np.fft.rfft(k, size)[:, None], size, axis=0)
    return out[2 * half: 2 * half + n]


#: the distributions a (mean, spread) pair stands for: "normal" (N(mean, spread)) or "two-point" (mean -
#: spread and mean + spread, half each: what a block of two values in equal parts is, exactly)
MODELS = ("normal", "two-point")
#: the model the renderer uses (chosen by tools/bench/bench_consistent.py, docs/benchmarks.md)
MODEL = "normal"


def _two_point(values: np.ndarray, shift: float) -> np.ndarray:
    """``(values(j - shift) + values(j + shift)) / 2`` per column, linear between entries, ends extended."""
    j = np.arange(len(values), dtype=np.float64)
    out = np.empty_like(values)
    for c in range(values.shape[1]):
        out[:, c] = 0.5 * (np.interp(j - shift, j, values[:, c]) + np.interp(j + shift, j, values[:, c]))
    return out


def _expect(values: np.ndarray, sigma: float, model: str) -> np.ndarray:
    """The expectation of ``values`` (fine entries, ``(N, c)``) over the model's distribution of spread
    ``sigma`` entries around each entry."""
    return _smooth(values, sigma) if model == "normal" else _two_point(values, sigma)


def distribution_tables(table: np.ndarray, ratios, rows: int = SPREAD_ROWS, oversample: int = 16,
                        model: str | None = None) -> np.ndarray:
    """``(len(ratios), rows, n * k, 4)`` float64 straight RGBA: the transfer function ``table``
    (``n`` entries, straight RGBA) pre-integrated over a normal distribution of each spread row
    (:func:`spread_row_sigmas`), resampled ``k`` times finer like
    :func:`~clipvol.scene.transfer.corrected_tables`, opacity corrected for each level's ratio.

    Entry ``[L, s, j]``: opacity ``correct_opacity(E[a], ratios[L])``, colour ``E[a c] / E[a]``
    (the plain table's colour where ``E[a] = 0``), the expectations over ``x ~ N(t_j, sigma_s)``
    with ``t_j`` the entry's table coordinate. Row ``s = 0`` equals ``corrected_tables``' row."""
    model = MODEL if model is None else model
    if model not in MODELS:
        raise ParameterError(f"model: expected one of {', '.join(MODELS)}, got {model!r}")
    fine = fine_table(table, oversample)
    N = len(fine)
    a = fine[:, 3:4]
    prem = np.concatenate([fine[:, :3] * a, a], axis=1)
    out = np.empty((len(ratios), rows, N, 4), dtype=np.float64)
    for s, sigma in enumerate(spread_row_sigmas(rows)):
        if s == 0:
            e = fine
        else:
            sm = _expect(prem, sigma * N, model)  # sigma in window units; N entries span the window
            ea = np.clip(sm[:, 3], 0.0, 1.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                rgb = np.where(ea[:, None] > 1e-12, sm[:, :3] / np.maximum(ea[:, None], 1e-300), fine[:, :3])
            e = np.concatenate([np.clip(rgb, 0.0, 1.0), ea[:, None]], axis=1)
        for li, r in enumerate(ratios):
            out[li, s, :, :3] = e[:, :3]
            out[li, s, :, 3] = correct_opacity(e[:, 3], float(r))
    return out


def spread_support(sigma, rows: int = SPREAD_ROWS, entries: int = 4096) -> np.ndarray:
    """How far (window units) from a sample's mean the table lookup at spread ``sigma`` (window
    units) reaches: :data:`KERNEL_SIGMAS` times the spread of the row above it (the lookup blends two
    rows), plus two entries of the fine table. Empty-space tests widen value ranges by it."""
    sig = np.minimum(np.asarray(sigma, dtype=np.float64), SPREAD_MAX)
    u = np.sqrt(np.maximum(sig, 0.0) / SPREAD_MAX) * (rows - 1)
    up = np.minimum(np.ceil(u), rows - 1) / (rows - 1)
    reach = KERNEL_SIGMAS if MODEL == "normal" else 1.0
    return np.where(sig > 0, reach * SPREAD_MAX * up * up, 0.0) + 2.0 / entries


class DistributionRanges:
    """Brick value ranges for the transparency test of a frame that classifies distributions.

    A coarse brick whose means the table makes transparent can still draw: its voxels' spread
    reaches values the table shows. This wraps a loader's ``brick_ranges``
    (:class:`~clipvol.paging.loader.HasBrickRanges`) so that a brick of a spread level answers the
    range of the level-0 bricks beneath it, widened by :func:`spread_support` of the largest spread
    such values can have (half that range): a bound of every table entry its samples can read.
    Other levels answer as the loader does. ``width``: the transfer function's window width.
    """

    def __init__(self, loader, width: float, levels) -> None:
        self.pyramid = loader.pyramid
        self._fn = loader.brick_ranges
        self._levels = {int(L) for L in levels}
        self._width = max(abs(float(width)), 1e-30)
        self._pooled: dict[int, tuple[np.ndarray, np.ndarray] | None] = {}

    def _pool(self, level: int) -> tuple[np.ndarray, np.ndarray] | None:
        if level not in self._pooled:
            g0 = tuple(int(v) for v in self.pyramid.grid(0))
            r = self._fn(0, np.indices(g0).reshape(3, -1).T)
            if r is None:
                return None  # unknown (a remote store's statistics may come later): asked again
            r = np.asarray(r, dtype=np.float64)
            f = 2 ** level
            g = tuple(-(-n // f) for n in g0)
            lo = np.full(tuple(n * f for n in g), np.inf)
            hi = np.full_like(lo, -np.inf)
            lo[: g0[0], : g0[1], : g0[2]] = r[:, 0].reshape(g0)
            hi[: g0[0], : g0[1], : g0[2]] = r[:, 1].reshape(g0)
            shape = (g[0], f, g[1], f, g[2], f)
            self._pooled[level] = (lo.reshape(shape).min(axis=(1, 3, 5)), hi.reshape(shape).max(axis=(1, 3, 5)))
        return self._pooled[level]

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray | None:
        if level not in self._levels:
            return self._fn(level, indices)
        pooled = self._pool(level)
        if pooled is None:
            return None
        idx = np.asarray(indices, dtype=np.int64).reshape(-1, 3)
        lo = pooled[0][idx[:, 0], idx[:, 1], idx[:, 2]]
        hi = pooled[1][idx[:, 0], idx[:, 1], idx[:, 2]]
        with np.errstate(invalid="ignore"):
            reach = spread_support(np.maximum(hi - lo, 0.0) / 2.0 / self._width) * self._width
        return np.stack([lo - reach, hi + reach], axis=1)


def _colour_rows(table_bytes: bytes, n: int, rows: int) -> np.ndarray:
    """``(rows, N, 3)``: the fine table's straight colours averaged over ``N(t, sigma_s)`` per spread row."""
    table = np.frombuffer(table_bytes, dtype=np.float64).reshape(n, 4)
    fine = fine_table(table)
    out = np.empty((rows, len(fine), 3), dtype=np.float64)
    for s, sigma in enumerate(spread_row_sigmas(rows)):
        out[s] = fine[:, :3] if s == 0 else _expect(fine[:, :3], sigma * len(fine), MODEL)
    return out


_COLOUR_ROWS: dict[bytes, np.ndarray] = {}


def _bilinear(tab: np.ndarray, tf, values, spreads, data_range, rows: int) -> np.ndarray:
    """``tab`` ``(rows, N, c)`` (spread row, fine table entry) read at ``values`` and ``spreads`` (raw
    units): bilinear in the table coordinate and the spread row, like the volume paths' lookup."""
    lo, hi = tf.window(data_range)
    width = max(abs(float(hi) - float(lo)), 1e-300)
    t = tf.normalise(np.asarray(values, dtype=np.float64), data_range)
    N = tab.shape[1]
    x = np.clip(t * N - 0.5, 0.0, N - 1.0)
    u = np.sqrt(np.clip(np.asarray(spreads, dtype=np.float64) / width / SPREAD_MAX, 0.0, 1.0)) * (rows - 1)
    x0 = np.floor(x).astype(np.int64)
    x1 = np.minimum(x0 + 1, N - 1)
    u0 = np.floor(u).astype(np.int64)
    u1 = np.minimum(u0 + 1, rows - 1)
    fx = (x - x0)[..., None]
    fu = (u - u0)[..., None]
    a = tab[u0, x0] * (1 - fx) + tab[u0, x1] * fx
    b = tab[u1, x0] * (1 - fx) + tab[u1, x1] * fx
    return a * (1 - fu) + b * fu


def expected_colours(tf, values, spreads, data_range=None, rows: int = SPREAD_ROWS) -> np.ndarray:
    """``(..., 3)`` float64: the transfer function's straight colour averaged over ``N(value, spread)``
    (raw units) - what an opaque slice through the level-0 voxels beneath a coarse pixel shows on
    average (opacity plays no part in a slice). Bilinear in the table coordinate and the spread row
    like the volume paths' lookup; the tables are kept per transfer function (the last four)."""
    table = np.ascontiguousarray(np.asarray(tf.table, dtype=np.float64))
    key = table.tobytes() + MODEL.encode()
    tab = _COLOUR_ROWS.get(key)
    if tab is None:
        tab = _colour_rows(table.tobytes(), len(table), rows)
        while len(_COLOUR_ROWS) >= 4:
            _COLOUR_ROWS.pop(next(iter(_COLOUR_ROWS)))
        _COLOUR_ROWS[key] = tab
    return _bilinear(tab, tf, values, spreads, data_range, rows)


def expected_premultiplied(tf, values, spreads, data_range=None, rows: int = SPREAD_ROWS) -> np.ndarray:
    """``(..., 3)`` float64: the premultiplied colour ``E[a c]`` over ``N(value, spread)`` (raw units,
    opacity not corrected for a step) - what a coarse sample of consistent levels adds per unit of
    opacity, read from the renderer's own tables (:func:`distribution_tables`, bilinear like its
    lookup). The visible-error estimate (:func:`clipvol.scene.lod_error.classification_bias`)
    compares it with the mean premultiplied colour of the fine voxels the sample stands for."""
    table = np.ascontiguousarray(np.asarray(tf.table, dtype=np.float64))
    key = table.tobytes() + MODEL.encode() + bytes([rows])
    prem = _PREMULTIPLIED_ROWS.get(key)
    if prem is None:
        tab = distribution_tables(table, [1.0], rows)[0]
        prem = tab[..., :3] * tab[..., 3:4]
        while len(_PREMULTIPLIED_ROWS) >= 4:
            _PREMULTIPLIED_ROWS.pop(next(iter(_PREMULTIPLIED_ROWS)))
        _PREMULTIPLIED_ROWS[key] = prem
    return _bilinear(prem, tf, values, spreads, data_range, rows)


_PREMULTIPLIED_ROWS: dict[bytes, np.ndarray] = {}
