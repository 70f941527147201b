"""The transfer-function flags shared by ``clipvol render``, ``view`` and ``report``.

One place parses them so that the three commands mean the same thing by each flag:

* ``--tf NAME`` - ``auto`` (the default: a window on the data's foreground from the store's
  histograms, see :mod:`clipvol.scene.auto_tf`), a preset, or a JSON file saved by
  ``clipvol tf save`` / the viewer's ``S`` key;
* ``--tf-range LO,HI`` or ``--window CENTRE,WIDTH`` - the window of data values the colour map
  spans (opacity is exactly 0 at and below its low end);
* ``--opacity ramp|flat|step`` - the opacity curve over the window;
* ``--tf-points "v:r,g,b,a;..."`` - control points in data values (overrides the others).
"""

from __future__ import annotations

import argparse
import math


def _pair(text: str) -> tuple[float, float]:
    try:
        v = tuple(float(t) for t in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 2 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected two numbers a,b, got {text!r}")
    return v  # type: ignore[return-value]


def _window(text: str) -> tuple[float, float]:
    """``--window C,W``: a finite centre and a width > 0."""
    c, w = _pair(text)
    if not w > 0:
        raise argparse.ArgumentTypeError(f"expected a finite centre and a width > 0, got {text!r}")
    return c, w


#: the flags of the transfer-function group, in the order a command's help lists them
TF_FLAGS = ("tf", "tf_range", "window", "opacity", "tf_points")


def add_tf_arguments(g, names=TF_FLAGS) -> None:
    """Add the transfer-function flags ``names`` (of :data:`TF_FLAGS`: ``--tf``, ``--tf-range``,
    ``--window``, ``--opacity``, ``--tf-points``) to the group ``g``; ``clipvol slice`` takes
    ``--tf`` and ``--window`` only. Imports no numpy (the presets' names are :mod:`clipvol.choices`')."""
    from clipvol.choices import OPACITY_CURVES, TF_PRESETS

    unknown = set(names) - set(TF_FLAGS)
    if unknown:
        raise KeyError(f"tf_args: no transfer-function flag {sorted(unknown)}; expected some of {TF_FLAGS}")
    if "tf" in names:
        g.add_argument("--tf", default=None,
                       help="transfer function: auto (default: a window on the data's foreground, from its histogram; "
                            "a diverging map for signed data; slice: a grey window), a preset (" + ", ".join(TF_PRESETS)
                            + "), or a JSON file written by 'clipvol tf save' or the viewer's S key (not slice)")
    if "tf_range" in names:
        g.add_argument("--tf-range", type=_pair, default=None, metavar="LO,HI",
                       help="window of data values the colour map spans; opacity is 0 at and below LO "
                            "(default: automatic for --tf auto, else the data's value range)")
    if "window" in names:
        g.add_argument("--window", type=_window, default=None, metavar="CENTRE,WIDTH",
                       help="the same window as centre and width > 0 (window/level), instead of --tf-range (default: "
                            "automatic for --tf auto; slice: the data's value range in grey)")
    if "opacity" in names:
        g.add_argument("--opacity", choices=OPACITY_CURVES, default=None,
                       help="opacity over the window: ramp (gentle, default), flat (a threshold) or step (a surface)")
    if "tf_points" in names:
        g.add_argument("--tf-points", default=None, metavar="'V:R,G,B,A;...'",
                       help="control points in data values, e.g. '0:0,0,0,0;500:1,0.5,0.3,0.2;1500:1,1,1,1' "
                            "(colour and opacity in [0, 1]; overrides --tf, --tf-range, --window)")


def transfer_function_from_args(args, loader):
    """The :class:`~clipvol.scene.transfer.TransferFunction` the flags ask for, for ``loader``'s data."""
    from pathlib import Path

    from clipvol.errors import ParameterError
    from clipvol.scene.auto_tf import auto_transfer_function
    from clipvol.scene.transfer import TransferFunction, window_range

    if getattr(args, "tf_range", None) is not None and getattr(args, "window", None) is not None:
        raise ParameterError("--tf-range and --window: expected one of them, got both")
    if getattr(args, "tf_points", None):
        if args.opacity is not None:
            raise ParameterError("--opacity: expected no opacity curve with --tf-points (the points carry opacity)")
        return TransferFunction.parse_points(args.tf_points)
    rng = args.tf_range
    if getattr(args, "window", None) is not None:
        rng = window_range(*args.window)
    if rng is not None and not rng[0] <= rng[1]:
        raise ParameterError(f"--tf-range: expected LO <= HI, got {rng[0]:g},{rng[1]:g}")
    name = args.tf or "auto"  # --tf left out: auto
    opacity = getattr(args, "opacity", None)
    steps = None
    if rng is None and not name.lower().endswith(".json"):  # a time series: one window for every step
        from clipvol.app.timeseries import series_loaders

        steps = series_loaders(loader)
    if steps is not None and name != "auto":
        from clipvol.bricking.channels import series_window

        lo, hi = series_window([ld.pyramid.value_range for ld in steps])
        rng = (lo, hi) if name != "diverging" else (-(max(abs(lo), abs(hi)) or 1.0), max(abs(lo), abs(hi)) or 1.0)
    if name.lower().endswith(".json"):
        tf = TransferFunction.load(Path(name))
        if rng is not None:
            tf = tf.with_value_range(rng)
        return tf if opacity is None else tf.with_opacity(opacity)
    if name == "auto":
        mode = getattr(args, "mode", None)
        from clipvol.scene.auto_tf import PROJECTIONS

        if rng is None and opacity is None and mode in PROJECTIONS:
            from clipvol.scene.auto_tf import projection_transfer_function

            return projection_transfer_function(loader, mode)  # the projection's own values, opaque at the top
        if rng is None and opacity is None and (getattr(args, "overlay", None) or getattr(args, "label_overlay", None)):
            from clipvol.scene.auto_tf import context_transfer_function

            return context_transfer_function(loader)  # translucent grey: the overlay or labels inside it show
        if rng is None:
            from clipvol.scene.auto_tf import series_histogram

            hist = series_histogram(steps) if steps is not None else None
            return auto_transfer_function(loader, opacity=opacity, hist=hist)
        from clipvol.scene.auto_tf import auto_preset, default_preset

        # a z-map keeps its diverging map under a window of its own (an opacity curve: a one-sided map)
        preset = auto_preset(loader) if opacity is None else default_preset(loader)
        return TransferFunction.preset(preset, value_range=rng, opacity=opacity)
    if name not in TransferFunction.names():
        raise ParameterError(f"--tf: expected auto, one of {', '.join(TransferFunction.names())} "
                             f"or a .json file, got {name!r}")
    if name == "diverging":
        if opacity is not None:
            raise ParameterError("--opacity: the diverging preset has its own opacity (transparent around 0); expected none")
        if rng is None:  # symmetric about 0
            lo, hi = loader.pyramid.value_range
            r = max(abs(lo), abs(hi)) or 1.0
            rng = (-r, r)
    return TransferFunction.preset(name, value_range=rng, opacity=opacity)
