"""What a writer may replace: the one rule every ``--overwrite`` (and every output path) goes through.

Why a module of its own: ``clipvol brick``, ``brick-points``, ``export``, ``demo`` and the channel-set
build each write an output that may already exist, and a flag that removes a folder recursively is
the one place clipvol can destroy a user's work. Each writer asks here before it touches a byte,
so the rule is written once and reads the same in every message:

* **Never the input.** An output that *is* one of the inputs, a folder that *holds* one, or a path
  *inside* an input (``clipvol brick S S/inner.zarr``: writing there changes what is read) is refused
  whether or not ``--overwrite`` is given (:func:`check_not_input`). With ``--overwrite``, a folder
  holding the current folder is refused too.
* **Only clipvol's own outputs are replaced.** ``--overwrite`` removes an existing output only when it
  is (:func:`replace_refusal`):

  - for a store output (``kind="store"``): an empty folder, or a *clipvol store*: a folder whose
    ``zarr.json`` is a JSON object with an ``attributes`` object holding a ``clipvol`` object (a
    volume or point store), or ``clipvol_channels`` / ``clipvol_timeseries`` (a channel set or time
    series), and whose top level holds only names clipvol writes there (:data:`STORE_ENTRIES`:
    ``zarr.json``, level folders ``0``, ``1``, ..., ``clipvol_*``, ``labels``, ``nodes``, ``points``,
    ``_build_tmp``, ``OME``, ``c``, ``t``) - a store into which someone put ``notes/`` is not
    replaced, since that folder would go with it;
  - for a file output (``npy``, ``tif``, ``nii``, ``nii.gz``): an empty file, or one file of the same
    kind, recognised by its first bytes (the ``.npy`` magic ``\\x93NUMPY``, a TIFF or BigTIFF byte-order
    mark, a NIfTI-1 ``n+1`` / NIfTI-2 ``n+2`` magic, for ``.nii.gz`` the same inside the gzip stream).

  Anything else - a folder with ``thesis.txt`` and ``notes/``, a store where a file is asked, a file
  of another kind - is refused with what is there, and no message suggests ``--overwrite`` where it
  would be refused (:func:`exists_error`).
* **Removal is the link, not its target.** :func:`remove_output` removes a symbolic link itself; it
  is called only after the checks above and, in every writer, only once the build is about to start.
"""

from __future__ import annotations

import gzip
import json
import os
import re
import shutil
from pathlib import Path
from typing import Iterable

from ..errors import OutputExistsError

__all__ = ["FILE_KINDS", "STORE_ENTRIES", "check_not_input", "replace_refusal", "check_overwrite", "exists_error",
           "remove_output", "describe_folder"]

#: the file kinds an output may be, and what each is called in a message
FILE_KINDS = {"npy": "a .npy array", "tif": "a TIFF", "nii": "a NIfTI file", "nii.gz": "a gzipped NIfTI file"}
#: names clipvol writes at the top of a store (a level folder is any run of digits)
STORE_ENTRIES = re.compile(r"^(zarr\.json|[0-9]+|clipvol_[A-Za-z0-9_]+|labels|nodes|points|_build_tmp|OME|c|t)$")
_STORE_ATTRS = ("clipvol", "clipvol_channels", "clipvol_timeseries")
_TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def _real(p) -> Path:
    return Path(os.path.realpath(Path(p).expanduser()))


def check_not_input(output, inputs: Iterable, name: str = "OUTPUT") -> None:
    """Refuse an ``output`` that is one of ``inputs``, holds one, or lies inside one.

    ``inputs`` are the paths the command reads (files or folders; anything not a local path, such
    as a URL or an array, is skipped). Links are resolved, so a link to the input is the input."""
    out = _real(output)
    for p in inputs:
        if not isinstance(p, (str, os.PathLike)) or "://" in str(p) or str(p).startswith("procedural:"):
            continue
        r = _real(p)
        if r == out:
            raise OutputExistsError(f"{name} {output}: is the input {p}; pick another {name}")
        if out in r.parents:
            raise OutputExistsError(f"{name} {output}: holds the input {p}; writing there would destroy it: "
                                    f"pick another {name}")
        if r in out.parents:
            raise OutputExistsError(f"{name} {output}: lies inside the input {p}; writing there would change the "
                                    f"input: choose a {name} path outside it")


def describe_folder(path: Path, limit: int = 4) -> str:
    """``"holds thesis.txt, notes/"``: the first ``limit`` entries of a folder (folders with a slash)."""
    try:
        names = sorted(os.listdir(path))
    except OSError as e:
        return f"cannot be listed: {e.strerror or e}"
    shown = [n + ("/" if (path / n).is_dir() and not (path / n).is_symlink() else "") for n in names[:limit]]
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return f"holds {', '.join(shown)}{more}"


def _store_attrs(path: Path) -> dict | None:
    """The attributes of the zarr group at ``path`` when they mark a clipvol store, else None."""
    p = path / "zarr.json"
    try:
        if not p.is_file() or p.stat().st_size > 16 * 2**20:
            return None
        doc = json.loads(p.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    attrs = doc.get("attributes") if isinstance(doc, dict) else None
    if not isinstance(attrs, dict) or not any(isinstance(attrs.get(k), dict) for k in _STORE_ATTRS):
        return None
    return attrs


def _file_kind(path: Path) -> str | None:
    """The :data:`FILE_KINDS` key ``path``'s first bytes say it is, or None."""
    try:
        with open(path, "rb") as f:
            head = f.read(352)
    except OSError:
        return None
    if head.startswith(b"\x93NUMPY"):
        return "npy"
    if head[:4] in _TIFF_MAGIC:
        return "tif"
    if head[344:348] in (b"n+1\x00", b"ni1\x00") or head[4:8] in (b"n+2\x00", b"ni2\x00"):
        return "nii"
    if head.startswith(b"\x1f\x8b"):
        try:
            with gzip.open(path, "rb") as g:
                inner = g.read(352)
        except (OSError, EOFError):
            return None
        if inner[344:348] == b"n+1\x00" or inner[4:8] == b"n+2\x00":
            return "nii.gz"
    return None


def replace_refusal(output, kind: str = "store") -> str | None:
    """Why an existing ``output`` may not be replaced by an output of ``kind``, or None when it may.

    ``kind`` is ``"store"`` or one of :data:`FILE_KINDS`; see the module docstring for what each
    may replace. The reason reads after "it": ``"is not a clipvol store (holds thesis.txt, notes/)"``."""
    path = Path(output)
    if path.is_symlink() and not path.exists():
        return None  # a dangling link: removing it loses nothing
    if path.is_dir():
        if kind != "store":
            return f"is a folder ({describe_folder(path)}), not {FILE_KINDS[kind]}"
        try:
            names = os.listdir(path)
        except OSError as e:
            return f"is a folder that cannot be listed ({e.strerror or e})"
        if not names:
            return None
        if _store_attrs(path) is None:
            return f"is not a clipvol store ({describe_folder(path)})"
        stray = sorted(n for n in names if not STORE_ENTRIES.match(n))
        if stray:
            shown = [n + ("/" if (path / n).is_dir() else "") for n in stray[:4]]
            return f"is a clipvol store that also holds {', '.join(shown)}, which clipvol did not write there"
        return None
    if not path.is_file():
        return "is not a regular file or folder"
    if kind == "store":
        return "is a file, not a clipvol store"
    try:
        if path.stat().st_size == 0:
            return None
    except OSError as e:
        return f"cannot be read ({e.strerror or e})"
    found = _file_kind(path)
    if found == kind:
        return None
    return f"is not {FILE_KINDS[kind]} ({'it is ' + FILE_KINDS[found] if found else 'its first bytes are of no kind clipvol writes'})"


def check_overwrite(output, inputs: Iterable = (), kind: str = "store", name: str = "OUTPUT") -> None:
    """Refuse ``--overwrite`` of ``output`` unless :func:`replace_refusal` allows it and it neither is,
    holds nor lies inside an input or holds the current folder. Nothing is removed here."""
    check_not_input(output, inputs, name)
    path = Path(output)
    if not path.exists() and not path.is_symlink():
        return
    if path.is_dir() and not path.is_symlink():
        out, cwd = _real(path), _real(Path.cwd())
        if out == cwd or out in cwd.parents:
            raise OutputExistsError(f"refusing to overwrite {output}: it holds the current folder; pick another {name}")
    why = replace_refusal(path, kind)
    if why is not None:
        raise OutputExistsError(f"refusing to overwrite {output}: it {why}; pick another {name} or remove it yourself")


def exists_error(output, kind: str = "store", name: str = "OUTPUT", flag: str = "--overwrite",
                 what: str = "exists") -> OutputExistsError:
    """The error for an existing ``output`` when ``flag`` was not given: it suggests ``flag`` only
    when :func:`replace_refusal` would let it replace ``output``."""
    why = replace_refusal(output, kind)
    if why is None:
        return OutputExistsError(f"{name} {output}: {what}; pass {flag} to replace it")
    return OutputExistsError(f"{name} {output}: exists and {why}; pick another {name} (clipvol does not replace it)")


def remove_output(output) -> None:
    """Remove ``output`` (a link: the link itself) after :func:`check_overwrite` allowed it."""
    path = Path(output)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
