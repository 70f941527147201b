"""A transfer function for label volumes: integer id -> colour and opacity (never an interpolated id).

A segmentation is drawn as an overlay (:mod:`clipvol.scene.overlay`) whose table is a
:class:`LabelColors`: each sample takes the id of the voxel *holding* the point (nearest, a
``texelFetch`` in the shader: an id halfway between 3 and 7 is not 5), and that id's straight RGBA,
its opacity per the primary's level-0 voxel like any transfer function (corrected for the
sample step). Ids without a colour of their own get a distinct default colour (a golden-ratio walk
round the hue circle) and ``default_opacity``; id 0 is the background, transparent unless given.
Opacity 0 hides a label (Volumizer's tagging: Bhaniramka & Demange 2002, section 2.1.3).

Spelling on the command line (``--label-colors``): ``3=#ff0000:0.5,7=hide,12=0.8`` (colour and
opacity, hidden, or the default colour with that opacity), or a ``.json`` file
``{"3": "#ff0000", "4": [0, 1, 0, 0.5], "7": "hide"}`` or a ``.csv`` file of rows
``id,r,g,b,a`` (0..1, a header row allowed).
"""

from __future__ import annotations

import colorsys
import csv
import json
from pathlib import Path

import numpy as np

from ..errors import ParameterError

__all__ = ["LabelColors", "palette_color"]

_GOLDEN = 0.618033988749895


def palette_color(label: int) -> tuple[float, float, float]:
    """A distinct colour for ``label`` (hues a golden-ratio step apart, saturated, bright)."""
    h = (int(label) * _GOLDEN) % 1.0
    s = 0.65 + 0.25 * ((int(label) // 7) % 2)
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h, s, 0.95))  # type: ignore[return-value]


def _hex(text: str, where: str) -> tuple[float, float, float]:
    t = text.strip().lstrip("#")
    if len(t) != 6:
        raise ParameterError(f"{where}: expected a colour #RRGGBB, got {text!r}")
    try:
        return tuple(int(t[i:i + 2], 16) / 255.0 for i in (0, 2, 4))  # type: ignore[return-value]
    except ValueError:
        raise ParameterError(f"{where}: expected a colour #RRGGBB, got {text!r}") from None


def _unit(v, where: str) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        f = float("nan")
    if not 0.0 <= f <= 1.0:
        raise ParameterError(f"{where}: expected a value in [0, 1], got {v!r}")
    return f


class LabelColors:
    """Per-label straight RGBA.

    Parameters
    ----------
    colors : mapping int -> (r, g, b, a) or (r, g, b) or float opacity or None
        Ids with their own colour; a float is the opacity with the default colour; ``None`` or
        opacity 0 hides the label.
    default_opacity : float
        Opacity of the ids not in ``colors`` (the background id 0 excepted).
    background : int or None
        The id drawn transparent unless ``colors`` names it (default 0).
    """

    def __init__(self, colors=None, default_opacity: float = 0.3, background: int | None = 0) -> None:
        self.default_opacity = _unit(default_opacity, "default_opacity")
        self.background = None if background is None else int(background)
        self._colors: dict[int, tuple[float, float, float, float]] = {}
        for k, v in dict(colors or {}).items():
            try:
                key = int(k)
            except (TypeError, ValueError):
                raise ParameterError(f"label colors: expected integer label ids, got {k!r}") from None
            where = f"label {key}"
            if v is None:
                rgba = (*palette_color(key), 0.0)
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                rgba = (*palette_color(key), _unit(v, f"{where} opacity"))
            else:
                vals = tuple(v)
                if len(vals) not in (3, 4):
                    raise ParameterError(f"{where}: expected r, g, b[, a] in [0, 1], got {v!r}")
                rgba = tuple(_unit(c, where) for c in vals) + ((self.default_opacity,) if len(vals) == 3 else ())
            self._colors[key] = rgba  # type: ignore[assignment]
        self.name = "labels"

    def rgba(self, label: int) -> tuple[float, float, float, float]:
        """The straight RGBA of ``label``."""
        label = int(label)
        if label in self._colors:
            return self._colors[label]
        if label == self.background:
            return (0.0, 0.0, 0.0, 0.0)
        return (*palette_color(label), self.default_opacity)

    def table(self, ids) -> np.ndarray:
        """``(len(ids), 4)`` float64 straight RGBA of ``ids``."""
        return np.array([self.rgba(i) for i in np.asarray(ids).reshape(-1)], dtype=np.float64).reshape(-1, 4)

    @property
    def hidden(self) -> set[int]:
        """Ids given opacity 0."""
        return {k for k, v in self._colors.items() if v[3] == 0.0}

    # -- parsing ---------------------------------------------------------------------------------
    @classmethod
    def parse(cls, spec: str, default_opacity: float = 0.3) -> "LabelColors":
        """``ID=#RRGGBB[:OPACITY]``, ``ID=OPACITY`` or ``ID=hide``, comma-separated; or a .json / .csv file."""
        text = str(spec).strip()
        if text.lower().endswith((".json", ".csv")):
            return cls.load(text, default_opacity)
        colors: dict = {}
        for part in (p.strip() for p in text.split(",") if p.strip()):
            key, sep, val = part.partition("=")
            if not sep:
                raise ParameterError(f"--label-colors: expected ID=#RRGGBB[:OPACITY], ID=OPACITY or ID=hide, got {part!r}")
            try:
                label = int(key)
            except ValueError:
                raise ParameterError(f"--label-colors: expected an integer label id before '=', got {key!r}") from None
            val = val.strip()
            if val.lower() == "hide":
                colors[label] = None
            elif val.startswith("#"):
                col, _, op = val.partition(":")
                rgb = _hex(col, f"--label-colors {part}")
                colors[label] = (*rgb, _unit(op, f"--label-colors {part} opacity") if op else default_opacity)
            else:
                colors[label] = _unit(val, f"--label-colors {part} opacity")
        return cls(colors, default_opacity)

    @classmethod
    def load(cls, path, default_opacity: float = 0.3) -> "LabelColors":
        """A ``.json`` (``{"ID": "#RRGGBB" | [r, g, b(, a)] | opacity | "hide"}``) or ``.csv`` (``id,r,g,b,a``) file."""
        p = Path(path)
        if not p.is_file():
            raise ParameterError(f"{p}: no such label colour file")
        colors: dict = {}
        if p.suffix.lower() == ".json":
            try:
                doc = json.loads(p.read_text())
            except json.JSONDecodeError as e:
                raise ParameterError(f"{p}: not valid JSON ({e})") from None
            if not isinstance(doc, dict):
                raise ParameterError(f"{p}: expected an object of label id -> colour, got {type(doc).__name__}")
            for k, v in doc.items():
                if isinstance(v, str):
                    colors[k] = None if v.lower() == "hide" else (*_hex(v, f"{p} label {k}"), default_opacity)
                else:
                    colors[k] = v
        else:
            with open(p, newline="") as f:
                for row in csv.reader(f):
                    if not row or row[0].strip().lower() in ("id", "label", ""):
                        continue
                    if len(row) not in (4, 5):
                        raise ParameterError(f"{p}: expected rows id,r,g,b[,a], got {row!r}")
                    try:
                        colors[int(row[0])] = tuple(float(v) for v in row[1:])
                    except ValueError:
                        raise ParameterError(f"{p}: expected rows id,r,g,b[,a] of numbers, got {row!r}") from None
        return cls(colors, default_opacity)

    def __repr__(self) -> str:
        return f"LabelColors({len(self._colors)} given, default opacity {self.default_opacity:g})"
