"""``--overlay STORE[:TF[@LO,HI]]`` (repeatable), ``--overlay-sampling``, ``--label-overlay NAME`` and
``--label-colors`` for ``clipvol render`` and ``clipvol view``.

``TF`` is a preset name (default ``diverging``: blue-grey-red, transparent around 0, its window
symmetric about 0 from the data's range), ``auto`` (a window on the overlay's foreground) or a
saved ``.json`` transfer function; ``@LO,HI`` sets its window (``:diverging@-5,5`` shows values
beyond +-1 as colour, a threshold); ``TF`` ``labels`` draws an integer label store with
per-label colours. ``--label-overlay NAME`` draws the source's own ``labels/NAME`` (from ``clipvol
brick --labels``) the same way; ``--label-colors`` gives the colours
(:class:`clipvol.scene.label_colors.LabelColors`). See :mod:`clipvol.scene.overlay` for how
overlays are drawn. ``--overlay-sampling`` sets how ``--overlay`` maps are sampled between voxels
(``classified``, the default, or ``interpolated``: :attr:`clipvol.scene.overlay.Overlay.sampling`).
"""

from __future__ import annotations

import sys

from clipvol.errors import ParameterError

__all__ = ["add_overlay_arguments", "add_channel_arguments", "parse_overlay", "overlays_from_args",
           "channels_from_args"]

HELP = ("a co-registered volume drawn over the source in the same ray cast, placed by its own spacing and origin "
        "(repeatable, at most 3, the first on top); TF: a preset (default diverging, symmetric about 0), auto, "
        "FILE.json or labels (an integer label store, --label-colors), @LO,HI its window, "
        "e.g. --overlay zmap.zarr:diverging@-6,6")


def add_overlay_arguments(g) -> None:
    g.add_argument("--overlay", action="append", default=[], metavar="STORE[:TF[@LO,HI]]", help=HELP)
    g.add_argument("--label-overlay", action="append", default=[], metavar="NAME",
                   help="draw the source's label image labels/NAME (clipvol brick --labels) over it, each label "
                        "in its own colour (sampled nearest, never interpolated)")
    g.add_argument("--label-colors", default=None, metavar="SPEC",
                   help="colours of label overlays: ID=#RRGGBB[:OPACITY], ID=OPACITY or ID=hide, comma-separated "
                        "(e.g. 3=#ff0000:0.5,7=hide), or a .json / .csv (id,r,g,b,a) file; other ids: a distinct "
                        "palette at --label-opacity, id 0 transparent")
    g.add_argument("--label-opacity", type=float, default=0.3, metavar="A",
                   help="opacity of label ids without a colour of their own (default 0.3)")
    g.add_argument("--overlay-sampling", choices=("classified", "interpolated"), default="classified",
                   help="how --overlay maps are sampled between voxels: classified (default) looks up each of the 8 "
                        "neighbouring voxels in the table and blends their colours, so a clipped, masked statistical "
                        "map shows no pale lines where its plateaus step to zero; interpolated blends the values, "
                        "then looks the result up (as the source is drawn)")
    g.add_argument("--overlay-budget", default=None, metavar="BYTES",
                   help="texture memory of each overlay: its finest level that fits is drawn (default 64MB; with "
                        "--channels, each channel gets the --texture-budget the first channel is drawn under)")


def add_channel_arguments(g) -> None:
    """``--channels C:COLOUR,...`` and ``--blend`` (``clipvol render`` and ``clipvol view``)."""
    g.add_argument("--channels", default=None, metavar="C:COLOUR,...",
                   help="several channels of an image with a c axis in one ray cast, each its colour (a name or "
                        "#RRGGBB) with a ramp opacity over its window (--tf-range for all), e.g. 0:green,1:magenta")
    g.add_argument("--blend", choices=("additive", "over"), default=None,
                   help="--channels / --overlay: colours add up (additive, default for --channels) or the "
                        "later layers over the first (over, default for --overlay)")


def channels_from_args(args, source, loader_kwargs: dict):
    """``--channels``: ``(loader of the first channel, its transfer function, overlays of the others)``,
    or None without ``--channels`` (see :mod:`clipvol.app.channels`)."""
    if not args.channels:
        return None
    from clipvol.app.channels import open_channels

    if getattr(args, "c", None) is not None:
        raise ParameterError("--c: expected either --c or --channels, got both")
    return open_channels(source, args.channels, windows=getattr(args, "tf_range", None),
                         overlay_budget=args.overlay_budget, texture_budget=getattr(args, "texture_budget", None),
                         **loader_kwargs)


def _is_tf(text: str) -> bool:
    from clipvol.scene.transfer import TransferFunction

    name = text.split("@", 1)[0]
    return ("@" in text or name in ("auto", "labels") or name.lower().endswith(".json")
            or name in TransferFunction.names())


def parse_overlay(spec: str) -> tuple[str, str, tuple[float, float] | None]:
    """``STORE[:TF[@LO,HI]]`` -> ``(store, tf name or file, window or None)``."""
    source, tf = spec, "diverging"
    head, sep, tail = spec.rpartition(":")
    if sep and head and _is_tf(tail):
        source, tf = head, tail
    rng = None
    if "@" in tf:
        tf, _, r = tf.partition("@")
        try:
            lo, hi = (float(v) for v in r.split(","))
        except ValueError:
            raise ParameterError(f"--overlay {spec}: expected a window @LO,HI of two numbers, got {r!r}") from None
        if not lo < hi:
            raise ParameterError(f"--overlay {spec}: expected LO < HI in @LO,HI, got {lo:g},{hi:g}")
        rng = (lo, hi)
    if not source:
        raise ParameterError(f"--overlay: expected STORE[:TF[@LO,HI]], got {spec!r}")
    return source, tf or "diverging", rng


def overlays_from_args(args, source=None, primary=None) -> tuple:
    """The :class:`~clipvol.scene.overlay.Overlay` objects of ``--overlay`` and ``--label-overlay``
    flags (their stores opened); ``source``/``primary``: the path and loader drawn under them."""
    from pathlib import Path

    from clipvol.paging.open import open_store
    from clipvol.scene.auto_tf import auto_transfer_function
    from clipvol.scene.label_colors import LabelColors
    from clipvol.scene.overlay import Overlay, store_origin
    from clipvol.scene.transfer import TransferFunction

    from clipvol.scene.overlay import DEFAULT_OVERLAY_BUDGET

    budget = args.overlay_budget if getattr(args, "overlay_budget", None) is not None else DEFAULT_OVERLAY_BUDGET
    sampling = getattr(args, "overlay_sampling", None) or "classified"
    colors = None
    if getattr(args, "label_colors", None) is not None or getattr(args, "label_overlay", None):
        colors = LabelColors.parse(args.label_colors or "", getattr(args, "label_opacity", 0.3))
    out = []
    for name in getattr(args, "label_overlay", None) or []:
        from clipvol.bricking.labels import label_names

        names = label_names(Path(str(source))) if source is not None else []
        if name not in names:
            raise ParameterError(f"--label-overlay: expected one of the store's labels {names or '(none)'}, got {name!r}")
        # a label image of the store shares its frame (OME image-label): placed at the image's origin
        out.append(Overlay(open_store(Path(str(source)) / "labels" / name), colors, name=f"labels/{name}",
                           origin=tuple(store_origin(primary)[:]) if primary is not None else None,
                           frame=getattr(primary, "frame", None), texture_budget=budget))
    for spec in getattr(args, "overlay", None) or []:
        source, name, rng = parse_overlay(spec)
        from clipvol.app.autobrick import bricked_source

        source = bricked_source(source, None, log=lambda line: print(line, file=sys.stderr))  # NIfTI etc.: bricked once
        loader = open_store(source)
        if name == "labels":
            tf = colors or LabelColors(default_opacity=getattr(args, "label_opacity", 0.3))
            out.append(Overlay(loader, tf, texture_budget=budget, name=source))
            continue
        if name.lower().endswith(".json"):
            tf = TransferFunction.load(Path(name))
        elif name == "auto":
            tf = auto_transfer_function(loader)
        elif name not in TransferFunction.names():
            raise ParameterError(f"--overlay {spec}: transfer function: expected auto, one of "
                                 f"{', '.join(TransferFunction.names())} or a .json file, got {name!r}")
        elif name == "diverging" and rng is None:
            tf = name  # Overlay makes its window symmetric about 0
        else:
            tf = TransferFunction.preset(name, value_range=rng)
        if rng is not None and not isinstance(tf, str):
            tf = tf.with_value_range(rng)
        out.append(Overlay(loader, tf, texture_budget=budget, name=source, sampling=sampling))
    return tuple(out)
