"""What kind of data a clipvol store holds, read from its group attributes alone.

A store written by ``clipvol brick-points`` says ``clipvol.kind = "points"`` in its ``zarr.json``;
a volume store (or a plain OME-Zarr image) says nothing. Reading that one attribute without opening
the store lets the volume opener refuse another kind's store by name, and lets each data kind of
:mod:`clipvol.app.kinds` recognise its own, without either knowing the other's format.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["store_kind"]


def store_kind(path) -> str | None:
    """The ``clipvol.kind`` attribute of the zarr group at ``path``, or None (a volume, a plain
    OME-Zarr image, no zarr v3 group, a URL, anything unreadable: the store's own readers report
    what is wrong with it)."""
    from .store_files import read_file

    try:
        p = Path(path) / "zarr.json"
    except TypeError:  # a loader object or an array, not a path
        return None
    try:  # never a FIFO or a device: the store's readers refuse those with a message
        attrs = json.loads(read_file(p, p.parent)).get("attributes", {})
    except (OSError, ValueError, AttributeError):
        return None
    cv = attrs.get("clipvol") if isinstance(attrs, dict) else None
    kind = cv.get("kind") if isinstance(cv, dict) else None
    return kind if isinstance(kind, str) else None
