"""Parsing of human-written sizes ("512MB", "2 GiB") used by every budget parameter."""

from __future__ import annotations

import re

from .errors import ParameterError

__all__ = ["parse_bytes", "format_bytes"]

_UNITS = {
    "": 1, "b": 1,
    "k": 10**3, "kb": 10**3, "m": 10**6, "mb": 10**6, "g": 10**9, "gb": 10**9, "t": 10**12, "tb": 10**12,
    "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40,
}


def parse_bytes(value: int | float | str, name: str = "size") -> int:
    """Return ``value`` as a whole number of bytes.

    Accepts ints, floats and strings such as ``"512MB"``, ``"1.5 GiB"`` or ``"4096"``. Decimal
    units (kB, MB, GB) are powers of 1000 and binary units (KiB, MiB, GiB) powers of 1024, as in
    the SI/IEC standards. ``name`` is the parameter's name, used in the error message.
    """
    if isinstance(value, bool):
        raise ParameterError(f"{name}: expected a number of bytes or a string like '512MB', got {value!r}")
    if isinstance(value, (int, float)):
        n = value
    elif isinstance(value, str):
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([a-zA-Z]*)\s*", value)
        if m is None or m.group(2).lower() not in _UNITS:
            raise ParameterError(f"{name}: expected a size like '512MB' or '2GiB', got {value!r}")
        n = float(m.group(1)) * _UNITS[m.group(2).lower()]
    else:
        raise ParameterError(f"{name}: expected a number of bytes or a string like '512MB', got {type(value).__name__}")
    if not (n >= 0) or n == float("inf"):
        raise ParameterError(f"{name}: expected a finite size >= 0, got {value!r}")
    return int(n)


def format_bytes(n: float) -> str:
    """Format a byte count for people: ``1536000 -> '1.5 MB'`` (decimal units)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if abs(n) < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"  # pragma: no cover
