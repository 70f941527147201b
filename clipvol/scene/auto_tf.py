"""The automatic transfer function: a window on the data's foreground, from its histogram.

Why: a colour map whose opacity rises over the whole value range turns almost any real volume
into a fog box - the background (air around a CT, the dark field of a fluorescence stack, the
zeros around a statistical map) is the most frequent value and gets opacity like everything
else. Windowing tools for medical images and microscopes solve this the same way: find the
background from the histogram and put the window on what is left.

What it does, from one 64-bin histogram of the data (the store's per-brick histograms summed
over one level - nothing is read - or, for a source without statistics, the bricks of a coarse
level read once):

* **Background**: the most frequent bin (the mode) and its shoulders (the background's noise).
* **Unsigned data** (or signed data whose background is not 0): the window runs from the 1st to
  the 99.5th percentile of the values *above* the background's bins; the preset (``grey`` for a
  scan in a patient frame — CT and MRI are read in grey, as every medical viewer shows them —
  ``viridis`` otherwise, unless asked) has opacity exactly 0 at and below the window's low end and rises
  along a gentle ramp (:data:`clipvol.scene.transfer.OPACITY_CURVES`), so the background is
  transparent and the bright structure shows.
* **Signed data** (float data whose background bin holds 0 and whose range reaches comparably far
  either side of 0 - a statistical or difference map): the ``diverging`` preset on a window
  symmetric about 0 out to the 99.5th percentile of ``|v|``, transparent within 20 % of that
  around 0, as neuroimaging viewers threshold such maps.

**Projections** (MIP, minIP, average) draw one value per ray, and those values are not the
voxels': a MIP holds the bright end, an average is pulled towards the background by the air each
ray crosses, a minIP of a scan in air is mostly air. A window on the voxels' foreground with a gentle
opacity ramp then draws a washed-out MIP (opacity at most ~0.6), an average of median opacity
~0.04 and an empty minIP. :func:`projection_transfer_function` instead measures the projection's
own values - the projections of a small level along the three axes - and maps their 1st..99.5th
percentiles over the whole table, opacity rising linearly from 0 to 1 (for a minIP, whose
interesting values are the low ones, the table and its opacity run the other way).

Percentiles are interpolated linearly inside a bin, so the window is good to about a bin width
(1/64 of the value range), which is all a default needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bricking.stats import histogram_edges
from .transfer import TransferFunction

__all__ = ["ValueHistogram", "value_histogram", "series_histogram", "auto_window", "auto_transfer_function",
           "default_preset", "context_transfer_function", "CONTEXT_OPACITY", "PROJECTIONS",
           "projection_transfer_function", "auto_preset"]

#: most bricks summed from the stored statistics (one level); a finer level with more is skipped
MAX_STAT_BRICKS = 1 << 18
#: most bricks read to build a histogram when a source stores none
MAX_READ_BRICKS = 64
BINS = 64


@dataclass(frozen=True, slots=True)
class ValueHistogram:
    """Counts of the non-NaN values over ``edges`` (``len(edges) == len(counts) + 1``); ``level``
    is the pyramid level they come from; ``stored`` is True when they come from the store's
    statistics (nothing read)."""

    counts: np.ndarray
    edges: np.ndarray
    level: int
    stored: bool
    nan_count: int = 0
    inf_count: int = 0


@dataclass(frozen=True, slots=True)
class AutoWindow:
    """The outcome of :func:`auto_window`: ``signed`` picks the diverging preset."""

    window: tuple[float, float]
    signed: bool
    background: float


def _stored_histogram(loader) -> ValueHistogram | None:
    stats_fn = getattr(loader, "brick_statistics", None)
    if stats_fn is None:
        return None
    pyr = loader.pyramid
    for L in range(pyr.num_levels):
        if pyr.num_bricks(L) > MAX_STAT_BRICKS:
            continue
        st = stats_fn(L)
        if not st or "histogram" not in st:
            return None
        h = np.asarray(st["histogram"], dtype=np.int64)
        counts = h.reshape(-1, h.shape[-1]).sum(axis=0)
        nan = int(np.asarray(st["nan_count"]).sum()) if "nan_count" in st else 0
        inf = int(np.asarray(st["inf_count"]).sum()) if "inf_count" in st else 0
        return ValueHistogram(counts, histogram_edges(*pyr.value_range, len(counts)), L, True, nan, inf)
    return None


def _read_histogram(loader) -> ValueHistogram:
    """Histogram of the finest level with at most :data:`MAX_READ_BRICKS` bricks, read brick by brick."""
    pyr = loader.pyramid
    level = pyr.num_levels - 1
    while level > 0 and pyr.num_bricks(level - 1) <= MAX_READ_BRICKS:
        level -= 1
    edges = histogram_edges(*pyr.value_range, BINS)
    counts = np.zeros(BINS, dtype=np.int64)
    nan = inf = 0
    shape = pyr.levels[level].shape
    B = pyr.brick_shape
    for idx in np.ndindex(*pyr.grid(level)):
        block = np.asarray(loader.read_brick(level, idx))
        valid = tuple(slice(0, min(B[a], shape[a] - idx[a] * B[a])) for a in range(3))
        v = block[valid].astype(np.float64, copy=False).reshape(-1)
        isnan = np.isnan(v)
        nan += int(isnan.sum())
        inf += int(np.isinf(v).sum())
        v = np.clip(v[~isnan], edges[0], edges[-1])
        counts += np.histogram(v, bins=edges)[0]
    return ValueHistogram(counts, edges, level, False, nan, inf)


def value_histogram(loader) -> ValueHistogram:
    """The data's histogram: the stored statistics of the finest level with at most
    :data:`MAX_STAT_BRICKS` bricks, else the bricks of a coarse level read once."""
    h = _stored_histogram(loader)
    return h if h is not None else _read_histogram(loader)


def series_histogram(loaders) -> ValueHistogram:
    """One histogram over every step of a time series (``loaders``: one per step), on 64 bins over
    the union of the steps' value ranges: the automatic window of a series is then one window for
    all steps, so a value is as bright at every ``t`` (a per-step window would brighten a dim step
    until it looks like the bright ones). Each step's bin counts are placed at their bin's centre,
    so the result is good to a bin width, as a single histogram is."""
    hs = [value_histogram(ld) for ld in loaders]
    edges = histogram_edges(min(float(h.edges[0]) for h in hs), max(float(h.edges[-1]) for h in hs), BINS)
    counts = np.zeros(BINS, dtype=np.int64)
    for h in hs:
        e = np.asarray(h.edges, dtype=np.float64)
        centres = np.clip((e[:-1] + e[1:]) / 2, edges[0], edges[-1])
        counts += np.histogram(centres, bins=edges, weights=np.asarray(h.counts, dtype=np.float64))[0].round().astype(np.int64)
    return ValueHistogram(counts, edges, max(h.level for h in hs), all(h.stored for h in hs),
                          sum(h.nan_count for h in hs), sum(h.inf_count for h in hs))


def _percentile(counts: np.ndarray, edges: np.ndarray, q: float) -> float:
    """The ``q``-th percentile (0..100) of binned values, linear inside the bin."""
    c = np.cumsum(counts, dtype=np.float64)
    total = c[-1]
    target = q / 100.0 * total
    i = int(np.searchsorted(c, target, side="left"))
    i = min(i, len(counts) - 1)
    before = c[i - 1] if i > 0 else 0.0
    frac = 0.0 if counts[i] == 0 else (target - before) / counts[i]
    return float(edges[i] + np.clip(frac, 0.0, 1.0) * (edges[i + 1] - edges[i]))


def _background_bins(counts: np.ndarray, m: int, floor: float = 1e-3) -> tuple[int, int]:
    """``(first, last)`` bin of the background peak around the mode ``m``: its shoulders, followed
    while the counts keep falling and stay above ``floor`` of the peak (the noise of the
    background, e.g. air in a CT, spreads over a bin or two either side)."""
    peak = counts[m]
    b1 = m
    while b1 + 1 < len(counts) and counts[b1 + 1] < counts[b1] and counts[b1 + 1] >= floor * peak:
        b1 += 1
    b0 = m
    while b0 > 0 and counts[b0 - 1] < counts[b0] and counts[b0 - 1] >= floor * peak:
        b0 -= 1
    return b0, b1


def auto_window(hist: ValueHistogram, *, float_data: bool = True, low: float = 1.0, high: float = 99.5) -> AutoWindow:
    """The window (and whether the data are treated as signed) from a histogram (see the module docstring)."""
    counts = np.asarray(hist.counts, dtype=np.int64)
    edges = np.asarray(hist.edges, dtype=np.float64)
    lo, hi = float(edges[0]), float(edges[-1])
    if counts.sum() == 0:
        return AutoWindow((lo, hi), False, lo)
    m = int(np.argmax(counts))
    background = float((edges[m] + edges[m + 1]) / 2)
    b0, b1 = _background_bins(counts, m)
    holds_zero = edges[m] <= 0.0 <= edges[m + 1]
    if float_data and lo < 0.0 < hi and holds_zero and min(-lo, hi) >= 0.25 * max(-lo, hi):
        centres = np.abs((edges[:-1] + edges[1:]) / 2)
        fg = counts.copy()
        fg[b0 : b1 + 1] = 0
        if fg.sum() == 0:
            fg = counts
        # percentile of |v| over the foreground: bin the absolute centres on [0, max|edge|]
        amax = max(-lo, hi)
        abs_edges = np.linspace(0.0, amax, len(counts) + 1)
        abs_counts = np.histogram(centres, bins=abs_edges, weights=fg)[0]
        r = _percentile(abs_counts, abs_edges, high)
        r = r if r > 0 else amax
        return AutoWindow((-r, r), True, background)
    fg = counts.copy()
    fg[: b1 + 1] = 0
    if fg.sum() < 1e-3 * counts.sum():
        fg = counts  # no foreground above the background: window the whole histogram
    w0, w1 = _percentile(fg, edges, low), _percentile(fg, edges, high)
    if not w1 > w0:
        w0, w1 = lo, hi
    return AutoWindow((w0, w1), False, background)


def default_preset(loader) -> str:
    """``grey`` for a store in a patient frame (a CT or MRI from NIfTI / DICOM), ``viridis`` otherwise."""
    frame = getattr(loader, "frame", None)
    return "grey" if frame is not None and getattr(frame, "frame", "") == "RAS" else "viridis"


def _auto_window_of(loader, hist: ValueHistogram | None = None) -> AutoWindow:
    lo, hi = (float(v) for v in loader.pyramid.value_range)
    if lo == hi:  # a constant volume: a zero-width window is a step at its value, drawn at mid-table
        return AutoWindow((lo, hi), False, lo)
    hist = value_histogram(loader) if hist is None else hist
    return auto_window(hist, float_data=np.dtype(loader.pyramid.dtype).kind == "f")


def auto_preset(loader, hist: ValueHistogram | None = None) -> str:
    """The colour map the automatic transfer function picks: ``diverging`` for signed data (a
    statistical map), else :func:`default_preset`. A window the user gives (``--tf-range -5,5``)
    keeps it, so a z-map stays diverging rather than turning into a grey ramp."""
    return "diverging" if _auto_window_of(loader, hist).signed else default_preset(loader)


def auto_transfer_function(loader, preset: str | None = None, opacity: str | None = None,
                           hist: ValueHistogram | None = None) -> TransferFunction:
    """The automatic :class:`~clipvol.scene.transfer.TransferFunction` of ``loader``'s data.

    ``preset`` replaces the chosen colour map (default :func:`default_preset`: ``grey`` for a
    store with a patient frame, ``viridis`` otherwise, ``diverging`` for signed data); ``opacity`` its opacity curve. Its :attr:`~TransferFunction.name` says what was chosen,
    e.g. ``auto: viridis 12.5..230``.
    """
    aw = _auto_window_of(loader, hist)
    name = preset or ("diverging" if aw.signed else default_preset(loader))
    tf = TransferFunction.preset(name, value_range=aw.window, opacity=None if name == "diverging" else opacity)
    return tf.with_name(f"auto: {tf.name} {aw.window[0]:.4g}..{aw.window[1]:.4g}")


#: the opacity of the primary under an overlay, as a fraction of its automatic opacity
CONTEXT_OPACITY = 0.1


def context_transfer_function(loader, hist: ValueHistogram | None = None) -> TransferFunction:
    """The automatic transfer function of a primary drawn under an overlay: translucent grey context.

    An opaque scan hides a map inside it (a statistical map lies within the brain), so when the
    user gives an overlay and leaves the primary's colours automatic, the primary keeps its
    automatic window but in grey with :data:`CONTEXT_OPACITY` of its opacity: the anatomy shows
    as a faint shell and the map inside it in full colour.
    """
    tf = auto_transfer_function(loader, preset="grey", hist=hist)
    table = np.array(tf.table, dtype=np.float64)
    table[:, 3] *= CONTEXT_OPACITY
    return TransferFunction(table, tf.value_range, name=f"{tf.name} (context, opacity x{CONTEXT_OPACITY:g})")


#: the render modes whose pixel is one value per ray
PROJECTIONS = ("mip", "minip", "average")
#: most voxels of the level whose projections measure a projection's window
PROJECTION_VOXELS = 1 << 21


def projection_transfer_function(loader, mode: str, preset: str | None = None) -> TransferFunction:
    """The automatic transfer function of a projection ``mode`` (``mip``, ``minip`` or ``average``).

    The window is the 1st..99.5th percentile of the finite values of the ``mode`` projections, along
    z, y and x, of the finest level with at most :data:`PROJECTION_VOXELS` voxels (read once); the
    table is ``preset`` (default :func:`default_preset`) with opacity rising linearly from 0 at the
    window's low end to 1 at its high end, both reversed for ``minip``. So the projection's own
    values fill the table and its opacity: the brightest MIP ray is opaque, the background's
    transparent.
    """
    from ..errors import ParameterError
    from .overlay import read_level

    reducers = {"mip": np.nanmax, "minip": np.nanmin, "average": np.nanmean}
    if mode not in reducers:
        raise ParameterError(f"mode: expected one of {', '.join(PROJECTIONS)}, got {mode!r}")
    pyr = loader.pyramid
    level = next((L for L in range(pyr.num_levels) if int(np.prod(pyr.levels[L].shape)) <= PROJECTION_VOXELS),
                 pyr.num_levels - 1)
    vol = read_level(loader, level, np.float64, failed=np.nan)
    vol[~np.isfinite(vol)] = np.nan
    vals = []
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rays: NaN, left out below
            for axis in range(3):
                p = reducers[mode](vol, axis=axis).ravel()
                vals.append(p[np.isfinite(p)])
    v = np.concatenate(vals)
    lo, hi = (float(x) for x in np.percentile(v, [1.0, 99.5])) if v.size else (0.0, 0.0)
    if not hi > lo:  # a projection of one value: the data's range
        lo, hi = (float(x) for x in pyr.value_range)
    name = preset or default_preset(loader)
    tf = TransferFunction.preset(name, value_range=(lo, hi))
    table = np.array(tf.table, dtype=np.float64)
    if mode == "minip":
        table = table[::-1].copy()
    ramp = np.linspace(0.0, 1.0, len(table))
    table[:, 3] = ramp[::-1] if mode == "minip" else ramp
    return TransferFunction(table, (lo, hi), name=f"auto {mode}: {name} {lo:.4g}..{hi:.4g}")
