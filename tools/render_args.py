"""The command-line flags of :class:`~clipvol.scene.params.RenderParams`, declared once for every command.

``clipvol render``, ``view``, ``slice`` and ``report`` draw with the same render parameters. Each
flag is one line of :data:`FLAGS`: the field (or fields) it sets, its name, and how the text
becomes a value; its help is the field's own (``RenderParams.help``, written once in :data:`clipvol.choices.PARAM_FIELDS`, which
:mod:`clipvol.scene.params` declares the field from) and its default the field's default. A command picks the flags it
offers with :func:`add_render_arguments` and builds its parameters with
:func:`render_params_from_args`, so a new render parameter is one field in ``RenderParams`` plus at
most one line here, and no command repeats its name, default or help.

The defaults shown and parsed are RenderParams' own, except where a flag says otherwise in its line
(``--texture-budget`` keeps its decimal ``"256MB"``; the ``--no-...`` switches turn a field off).
"""

from __future__ import annotations

import argparse
from typing import Any, Callable, Iterable, NamedTuple

from clipvol.choices import CLASSIFY, MODES, PARAM_FIELDS, PATHS, POLICIES
from clipvol.errors import ParameterError

__all__ = ["Flag", "FLAGS", "add_render_arguments", "render_params_from_args", "flag_values"]


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


#: a Flag's default when it is the field's own
FIELD_DEFAULT = object()


class Flag(NamedTuple):
    """One command-line flag of one or more RenderParams fields (a named tuple, not a dataclass:
    ``dataclasses`` imports ``inspect``, a third of ``clipvol render --help``'s own start-up).

    ``switch``: ``"on"`` for a flag that sets a bool field True (``--shading``), ``"off"`` for one
    that sets it False (``--no-visibility``; the command's value without it is then True).
    ``to_fields``: for a flag of several fields (``--light``), the parsed value -> ``{field: value}``.
    ``default``: the flag's default when it is not the field's (as the command line writes it).
    ``help``: the flag's help when it is not the field's (the switches, the grouped flags).
    """

    fields: tuple[str, ...]
    flag: str
    type: Callable[[str], Any] | None = None
    switch: str | None = None
    choices: tuple | None = None
    metavar: str | None = None
    default: Any = FIELD_DEFAULT
    help: str | None = None
    to_fields: Callable[[Any], dict] | None = None

    @property
    def dest(self) -> str:
        return self.flag.lstrip("-").replace("-", "_")


def _light(values) -> dict:
    """``--light KA,KD,KS,N`` as RenderParams fields."""
    if len(values) != 4:
        raise ParameterError(f"--light: expected four numbers ambient,diffuse,specular,shininess, got {values!r}")
    return dict(zip(("ambient", "diffuse", "specular", "shininess"), values))


#: one line per flag; the key, a command's handle for it in add_render_arguments, is the field's name
#: (the flag's own name, ``light``, for a flag of several fields)
FLAGS: dict[str, Flag] = {(f.fields[0] if len(f.fields) == 1 else f.dest): f for f in (
    Flag(("mode",), "--mode", choices=MODES),
    Flag(("iso_value",), "--iso-value", type=float),
    Flag(("policy",), "--policy", choices=POLICIES),
    Flag(("level",), "--level", type=int),
    Flag(("lod_threshold",), "--lod-threshold", type=float),
    Flag(("distance_factor",), "--distance-factor", type=float),
    Flag(("fov_fraction",), "--fov-fraction", type=float),
    Flag(("max_texels_drawn",), "--max-texels-drawn", type=int),
    Flag(("block_budget",), "--block-budget", type=int),
    Flag(("max_error",), "--max-error", metavar="FRACTION"),
    Flag(("visibility",), "--no-visibility", switch="off",
         help="--policy image: no visibility estimate (every brick counts as fully visible)"),
    Flag(("step",), "--step", type=float),
    Flag(("background",), "--background", type=_floats),
    Flag(("shading",), "--shading", switch="on"),
    Flag(("ambient", "diffuse", "specular", "shininess"), "--light", type=_floats, metavar="KA,KD,KS,N",
         to_fields=_light, help="--shading: ambient, diffuse, specular weights and shininess (default %(default)s)"),
    Flag(("refine_tolerance",), "--refine-tolerance", type=float),
    Flag(("jitter",), "--no-jitter", switch="off",
         help="sample every pixel's ray from t = 0 (shows lattice rings; for comparisons)"),
    Flag(("path",), "--render-path", choices=PATHS),
    Flag(("skip_empty",), "--no-skip-empty", switch="off",
         help="sample every cell, also those the transfer function makes transparent (the same image, slower)"),
    Flag(("texture_budget",), "--texture-budget", default="256MB"),  # decimal MB, as the command line always read it
    Flag(("texels_per_frame",), "--texels-per-frame", type=int),
    Flag(("classify",), "--classify", choices=CLASSIFY),
)}


def _field_default(name: str):
    """Field ``name``'s default, as RenderParams declares it (from :data:`clipvol.choices.PARAM_FIELDS`)."""
    return PARAM_FIELDS[name][0]


def _default(flag: Flag):
    if flag.switch is not None:
        return False
    if flag.default is not FIELD_DEFAULT:
        return flag.default
    if len(flag.fields) > 1:
        return tuple(_field_default(n) for n in flag.fields)
    return _field_default(flag.fields[0])


def add_render_arguments(group, names: Iterable[str]) -> None:
    """Add the flags of the RenderParams fields ``names`` (keys of :data:`FLAGS`) to ``group``: the
    same type, default, choices and help in every command (a field's help says where a command
    uses it its own way, e.g. ``--level`` for ``slice``). Imports no numpy."""
    for name in names:
        if name not in FLAGS:
            raise KeyError(f"render_args: no flag for the render parameter {name!r}; add a line to FLAGS")
        f = FLAGS[name]
        text = f.help if f.help is not None else PARAM_FIELDS[f.fields[0]][1]
        kw: dict[str, Any] = dict(dest=f.dest, help=text, default=_default(f))
        if f.switch is not None:
            kw["action"] = "store_true"
        else:
            if f.type is not None:
                kw["type"] = f.type
            if f.choices is not None:
                kw["choices"] = f.choices
            if f.metavar is not None:
                kw["metavar"] = f.metavar
        if len(f.fields) > 1 and "%(default)s" in text:  # a grouped default reads as the user types it
            kw["help"] = text.replace("%(default)s", ",".join(f"{v:g}" for v in kw["default"]))
        group.add_argument(f.flag, **kw)


def flag_values(args) -> dict:
    """The RenderParams fields that the flags present in ``args`` set (a parsed namespace)."""
    out: dict[str, Any] = {}
    for f in FLAGS.values():
        if not hasattr(args, f.dest):
            continue
        value = getattr(args, f.dest)
        if f.switch == "on":
            out[f.fields[0]] = bool(value)
        elif f.switch == "off":
            out[f.fields[0]] = not value
        elif f.to_fields is not None:
            out.update(f.to_fields(value))
        else:
            out[f.fields[0]] = value
    return out


def render_params_from_args(args, **fixed):
    """The :class:`~clipvol.scene.params.RenderParams` of the render flags in ``args``, with the
    ``fixed`` fields a command sets itself (``clipvol slice``'s ``policy="plane"``) over them.
    Validation (and its one-line errors) is RenderParams' own, with each mode's checks (registered by
    :mod:`clipvol.render.modes`: ``--mode iso`` needs ``--iso-value``)."""
    import clipvol.render.modes  # noqa: F401 - registers the draw modes and their checks
    from clipvol.scene.params import RenderParams

    values = flag_values(args)
    # --max-error is the image policy's budget: it selects that policy where --policy is left at its default
    if values.get("max_error") is not None and values.get("policy") == _field_default("policy"):
        values["policy"] = "image"
    return RenderParams(**{**values, **fixed})
