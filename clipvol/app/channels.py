"""Channels of one image (OME-Zarr ``c`` axis), each with its own colour and window, in one ray cast.

A microscopist's three stains are three volumes of one geometry. They are drawn with the overlay
machinery of :mod:`clipvol.scene.overlay`: the first channel listed is the primary (paged through
the clip-texture, multiresolution, culled), the others are overlays sampled at the same points
(each drawn from its finest level that fits the overlay texture budget). A channel is not a small
map beside a large scan: it is as large as the first, so its overlay budget defaults to the texture
budget the first channel is drawn under (an overlay's own 64 MB default drew a second channel of a
2 x 384 x 768^2 stack from level 2, 4x coarser than the first). Each channel's transfer
function is its colour with the ``ramp`` opacity over its window (default: the channel's range,
OME ``omero.window``). ``RenderParams.blend`` says how they combine at each sample:

* ``"additive"`` - fluorescence: the channels' premultiplied colours add up, opacity
  ``1 - prod(1 - a_k)`` (where green and magenta overlap the sample turns white);
* ``"over"`` - the second channel's colour over the others (the later channels on top of the
  first, the second on top), each sample composited front to back as usual.

:func:`open_channels` turns ``"0:green,1:magenta"`` into the loader of the first channel, its
transfer function and the overlays of the others.
"""

from __future__ import annotations

from ..errors import ParameterError
from ..scene.overlay import MAX_OVERLAYS, Overlay, store_origin
from ..scene.params import RenderParams
from ..scene.transfer import TransferFunction, opacity_curve
from .session import open_loader

__all__ = ["CHANNEL_COLORS", "channel_tf", "parse_channels", "open_channels"]

#: colour names for ``--channels``
CHANNEL_COLORS = {
    "red": (1.0, 0.0, 0.0), "green": (0.0, 1.0, 0.0), "blue": (0.15, 0.35, 1.0), "magenta": (1.0, 0.0, 1.0),
    "cyan": (0.0, 1.0, 1.0), "yellow": (1.0, 1.0, 0.0), "orange": (1.0, 0.55, 0.0), "white": (1.0, 1.0, 1.0),
    "grey": (0.7, 0.7, 0.7), "gray": (0.7, 0.7, 0.7),
}


def _color(text: str, where: str) -> tuple[float, float, float]:
    t = text.strip().lower()
    if t in CHANNEL_COLORS:
        return CHANNEL_COLORS[t]
    if t.startswith("#") and len(t) == 7:
        try:
            return tuple(int(t[i:i + 2], 16) / 255.0 for i in (1, 3, 5))  # type: ignore[return-value]
        except ValueError:
            pass
    raise ParameterError(f"{where}: expected a colour name ({', '.join(sorted(CHANNEL_COLORS))}) or #RRGGBB, got {text!r}")


def channel_tf(color, value_range=None, n: int = 256) -> TransferFunction:
    """A channel's transfer function: ``color`` (a name, ``#RRGGBB`` or ``(r, g, b)``) at every
    value, opacity the ``ramp`` curve over ``value_range`` (0 at and below its low end)."""
    rgb = _color(color, "channel colour") if isinstance(color, str) else tuple(float(c) for c in color)
    tf = TransferFunction.from_points([(0.0, (*rgb, 0.0)), (1.0, (*rgb, 1.0))], value_range, n)
    table = tf.table.astype(float)
    table[:, :3] = rgb
    table[:, 3] = opacity_curve("ramp", n)
    table[0, 3] = 0.0
    name = color if isinstance(color, str) else "channel"
    return TransferFunction(table, value_range, name)


def parse_channels(spec: str) -> list[tuple[int, str]]:
    """``"0:green,1:magenta"`` -> ``[(0, "green"), (1, "magenta")]`` (a channel without a colour: the next of
    green, magenta, cyan, yellow)."""
    out = []
    default = ("green", "magenta", "cyan", "yellow")
    for k, part in enumerate(p.strip() for p in str(spec).split(",") if p.strip()):
        idx, _, col = part.partition(":")
        try:
            c = int(idx)
        except ValueError:
            raise ParameterError(f"--channels: expected C[:COLOUR] with an integer channel, got {part!r}") from None
        col = col or default[k % len(default)]
        _color(col, f"--channels {part}")
        out.append((c, col))
    if not out:
        raise ParameterError(f"--channels: expected C[:COLOUR],C[:COLOUR],..., got {spec!r}")
    if len(out) > MAX_OVERLAYS + 1:
        raise ParameterError(f"--channels: expected at most {MAX_OVERLAYS + 1} channels, got {len(out)}")
    if len({c for c, _ in out}) != len(out):
        raise ParameterError(f"--channels: expected each channel once, got {spec!r}")
    return out


def open_channels(source, channels, *, windows=None, overlay_budget=None, texture_budget=None, **kwargs):
    """``(loader, tf, overlays)`` for ``channels`` (a spec string or ``[(c, colour), ...]``) of ``source``.

    ``windows``: optional ``{c: (lo, hi)}``, or one ``(lo, hi)`` for every channel; ``kwargs`` go to
    the loader (``t=``, ``brick=``). ``overlay_budget``: texture bytes of each channel after the
    first (default: ``texture_budget``, the first channel's, itself by default
    :class:`~clipvol.scene.params.RenderParams`' 256 MB).
    A channel beyond the image's ``c`` axis, or an image without one, is a ParameterError naming both.
    """
    chans = parse_channels(channels) if isinstance(channels, str) else [(int(c), col) for c, col in channels]
    probe = open_loader(source, **kwargs)
    axes = tuple(getattr(probe, "axes", ()) or ())
    if "c" not in axes:
        raise ParameterError(f"channels: expected an image with a c axis, got {source} with axes "
                             f"{list(axes) + ['z', 'y', 'x']}")
    n = int(probe.lead_shape[axes.index("c")])
    for c, _ in chans:
        if not 0 <= c < n:
            raise ParameterError(f"channels: expected channels 0..{n - 1} of {source} (its c axis has {n}), got {c}")
    loaders = [open_loader(source, c=c, **kwargs) for c, _ in chans]
    first = loaders[0].pyramid
    for (c, _), ld in zip(chans, loaders):
        if [lv.shape for lv in ld.pyramid.levels] != [lv.shape for lv in first.levels]:
            raise ParameterError(f"channel {c}: expected the levels of channel {chans[0][0]}, got "
                                 f"{[lv.shape for lv in ld.pyramid.levels]}")
    if windows is not None and not isinstance(windows, dict):
        windows = {c: tuple(windows) for c, _ in chans}
    windows = dict(windows or {})
    tfs = [channel_tf(col, windows.get(c, ld.pyramid.value_range)) for (c, col), ld in zip(chans, loaders)]
    origin = tuple(float(v) for v in store_origin(loaders[0]))  # one image: the channels share its frame
    if overlay_budget is None:
        overlay_budget = texture_budget if texture_budget is not None else RenderParams().texture_budget
    # a channel is an intensity image like the first (drawn interpolated, then classified), not a thresholded map
    overlays = tuple(Overlay(ld, tf, origin=origin, texture_budget=overlay_budget, name=f"{source} channel {c}",
                             sampling="interpolated")
                     for (c, _), ld, tf in zip(chans[1:], loaders[1:], tfs[1:]))
    return loaders[0], tfs[0], overlays
