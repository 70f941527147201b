"""``--overlay STORE[:TF[@LO,HI]]`` (repeatable) for ``clipvol render`` and ``clipvol view``.

``TF`` is a preset name (default ``diverging``: blue-grey-red, transparent around 0, its window
symmetric about 0 from the data's range), ``auto`` (a window on the overlay's foreground) or a
saved ``.json`` transfer function; ``@LO,HI`` sets its window (``:diverging@-5,5`` shows values
beyond +-1 as colour, a threshold). See :mod:`clipvol.scene.overlay` for how overlays are drawn.
"""

from __future__ import annotations

from clipvol.errors import ParameterError

__all__ = ["add_overlay_arguments", "parse_overlay", "overlays_from_args"]

HELP = ("a co-registered volume drawn over the source in the same ray cast, placed by its own spacing and origin "
        "(repeatable, at most 3, the first on top); TF: a preset (default diverging, symmetric about 0), auto or "
        "FILE.json, @LO,HI its window, e.g. --overlay zmap.zarr:diverging@-6,6")


def add_overlay_arguments(g) -> None:
    g.add_argument("--overlay", action="append", default=[], metavar="STORE[:TF[@LO,HI]]", help=HELP)
    g.add_argument("--overlay-budget", default="64MB", metavar="BYTES",
                   help="texture memory of each overlay: its finest level that fits is drawn (default 64MB)")


def _is_tf(text: str) -> bool:
    from clipvol.scene.transfer import TransferFunction

    name = text.split("@", 1)[0]
    return "@" in text or name == "auto" or name.lower().endswith(".json") or name in TransferFunction.names()


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


def overlays_from_args(args) -> tuple:
    """The :class:`~clipvol.scene.overlay.Overlay` objects of ``--overlay`` flags (their stores opened)."""
    from pathlib import Path

    from clipvol.paging.open import open_store
    from clipvol.scene.auto_tf import auto_transfer_function
    from clipvol.scene.overlay import Overlay
    from clipvol.scene.transfer import TransferFunction

    out = []
    for spec in getattr(args, "overlay", None) or []:
        source, name, rng = parse_overlay(spec)
        loader = open_store(source)
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
        out.append(Overlay(loader, tf, texture_budget=args.overlay_budget, name=source))
    return tuple(out)
