"""Store files that are what they claim: regular files inside the store, read with a size cap.

Why: a reader trusts a path because it lies under the store's directory. A symbolic link can make a
chunk or a level's ``zarr.json`` another file anywhere on the machine; a FIFO blocks ``open()``
for ever; a device such as ``/dev/zero`` never ends; a file of gigabytes where a chunk of
kilobytes belongs fills memory. Every file a reader of a local store opens goes through here:

* it is opened without following a final symbolic link and without blocking (``O_NOFOLLOW``,
  ``O_NONBLOCK``); a link is followed only when its resolved target lies inside the store;
* ``fstat`` of the open descriptor must say *regular file* (a FIFO, socket or device is refused
  before a byte is read);
* its size must not exceed a cap (the manifest's exact size for a chunk of a verified store; a
  bound from the chunk shape for any other store; :data:`MAX_METADATA_BYTES` for JSON metadata),
  and it is never read past that cap even if it grows while being read.

Each refusal is a :class:`StoreFileError` (an :class:`~clipvol.errors.InputFormatError`) naming
the path: a reader that tolerates a missing or malformed optional file (a foreign image's coarser
level) still stops at a file that is not what it claims.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from ..errors import InputFormatError

__all__ = [
    "StoreFileError",
    "MAX_METADATA_BYTES",
    "O_SAFE",
    "open_inside",
    "check_opened",
    "open_checked",
    "read_capped",
    "read_file",
    "check_tree",
    "chunk_cap",
]

class StoreFileError(InputFormatError):
    """A store file that is not what it claims: a link out of the store, a FIFO, a device, a
    socket, a directory, or more bytes than its kind may hold (names the path)."""


#: the largest JSON metadata file read (OME metadata of even large plates is well under this)
MAX_METADATA_BYTES = 16 * 2**20
#: open flags of every store file: read-only, no final symbolic link followed, no blocking open
O_SAFE = os.O_RDONLY | getattr(os, "O_BINARY", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
_O_RESOLVED = os.O_RDONLY | getattr(os, "O_BINARY", 0) | getattr(os, "O_NONBLOCK", 0)


def chunk_cap(decoded_nbytes: int) -> int:
    """Most bytes a stored chunk of ``decoded_nbytes`` decoded bytes may take when no manifest
    says its exact size: the decoded size plus an eighth (no codec zarr uses expands data more
    than a few bytes per block) plus 64 KiB of headers and checksums."""
    return int(decoded_nbytes) + int(decoded_nbytes) // 8 + 65536


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory")):
        if test(mode):
            return name
    return "not a regular file"


def _inside(root_real: str, target: str) -> bool:
    return target == root_real or target.startswith(root_real.rstrip(os.sep) + os.sep)


def open_inside(path: str, root_real: str) -> int | None:
    """A read-only, non-blocking descriptor of ``path``, or None when it does not exist.

    ``root_real`` is the store's directory with its links resolved (``os.path.realpath``). A final
    symbolic link is followed only when it resolves inside ``root_real``; a dangling one counts as
    absent. The caller checks the descriptor with :func:`check_opened`.
    """
    try:
        return os.open(path, O_SAFE)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as e:
        if e.errno not in (errno.ELOOP, errno.EMLINK):  # ELOOP: the last component is a link
            raise
    target = os.path.realpath(path)
    if not _inside(root_real, target):
        raise StoreFileError(f"{path}: a symbolic link to {target}, outside the store {root_real}")
    try:
        return os.open(target, _O_RESOLVED)
    except (FileNotFoundError, NotADirectoryError):
        return None


def open_checked(path: str, root_real: str, folders_ok: set, cap: int | None,
                 exact: int | None = None) -> tuple[int, int] | None:
    """``(fd, size)`` of the store file ``path`` opened as what it claims, or None when it does not
    exist: its folder resolved inside ``root_real`` (once per folder: ``folders_ok`` remembers the
    folders already checked), the file opened by :func:`open_inside` and checked by
    :func:`check_opened` (the descriptor is closed when that refuses it). An
    :class:`InputFormatError` names the path otherwise. The one way a loader opens a chunk or a
    shard file."""
    folder = path.rpartition("/")[0]
    if folder not in folders_ok:
        real = os.path.realpath(folder)
        if not _inside(root_real, real):
            raise StoreFileError(f"{folder}: resolves to {real}, outside the store {root_real}")
        folders_ok.add(folder)
    fd = open_inside(path, root_real)
    if fd is None:
        return None
    try:
        return fd, check_opened(fd, path, cap, exact)
    except BaseException:
        os.close(fd)
        raise


def check_opened(fd: int, path: str, cap: int | None, exact: int | None = None) -> int:
    """The size of the regular file open as ``fd``; an :class:`InputFormatError` naming ``path``
    when it is a FIFO, device, socket or directory, larger than ``cap``, or not ``exact`` bytes."""
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        raise StoreFileError(f"{path}: {_kind(st.st_mode)}, not a regular file: refused")
    if exact is not None and st.st_size != exact:
        raise StoreFileError(f"{path}: truncated or corrupt: {st.st_size} bytes, but the store's manifest says {exact}")
    if cap is not None and st.st_size > cap:
        raise StoreFileError(f"{path}: {st.st_size} bytes, more than the {cap} a file of this kind may hold: refused")
    return st.st_size


def read_capped(fd: int, size: int, cap: int, path: str) -> bytes:
    """All bytes of ``fd`` (``size`` by its ``fstat``), never more than ``cap``: a file that grows
    while it is read past the cap is refused, naming ``path``."""
    data = os.read(fd, size + 1)
    if len(data) != size:  # short read, or a file that changed since fstat: read on to the end, bounded
        parts = [data]
        total = len(data)
        while True:
            more = os.read(fd, 1 << 20)
            if not more:
                break
            total += len(more)
            if total > cap:
                raise StoreFileError(f"{path}: grew past {cap} bytes while being read: refused")
            parts.append(more)
        data = b"".join(parts)
    if len(data) > cap:
        raise StoreFileError(f"{path}: grew past {cap} bytes while being read: refused")
    return data


def read_file(path: str | Path, root: str | Path, cap: int = MAX_METADATA_BYTES) -> bytes:
    """The bytes of the store file ``path`` under the store ``root``: a regular file whose resolved
    path lies inside ``root``, at most ``cap`` bytes. Raises FileNotFoundError when absent and
    :class:`InputFormatError` (naming the path) for anything else that is not what it claims."""
    root_real = os.path.realpath(root)
    p = str(path)
    parent = os.path.realpath(os.path.dirname(p) or ".")
    if not _inside(root_real, parent):
        raise StoreFileError(f"{p}: its folder resolves to {parent}, outside the store {root_real}")
    fd = open_inside(p, root_real)
    if fd is None:
        raise FileNotFoundError(errno.ENOENT, "no such file", p)
    try:
        size = check_opened(fd, p, cap)
        return read_capped(fd, size, cap, p)
    finally:
        os.close(fd)


def check_tree(directory: str | Path, root: str | Path, cap: int) -> None:
    """Every entry under ``directory`` (a small array of the store, such as a statistics array,
    before zarr-python reads it): regular files or folders, links only when they resolve inside
    ``root``, files at most ``cap`` bytes. Never opens anything, so nothing can block."""
    root_real = os.path.realpath(root)
    top = os.path.realpath(directory)
    if not _inside(root_real, top):
        raise StoreFileError(f"{directory}: resolves to {top}, outside the store {root_real}")
    for base, dirs, files in os.walk(directory):
        for name in dirs + files:
            p = os.path.join(base, name)
            st = os.lstat(p)
            if stat.S_ISLNK(st.st_mode):
                target = os.path.realpath(p)
                if not _inside(root_real, target):
                    raise StoreFileError(f"{p}: a symbolic link to {target}, outside the store {root_real}")
                st = os.stat(p)
            if stat.S_ISDIR(st.st_mode):
                continue
            if not stat.S_ISREG(st.st_mode):
                raise StoreFileError(f"{p}: {_kind(st.st_mode)}, not a regular file: refused")
            if st.st_size > cap:
                raise StoreFileError(f"{p}: {st.st_size} bytes, more than the {cap} a file of this kind may hold: refused")
