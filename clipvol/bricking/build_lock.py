"""The build lock: one writer per output store, a pid file ``<output>.lock`` beside it.

Why these rules:

* **Written whole or not at all.** The lock's JSON (pid and host) is written to a temporary file
  beside it and hard-linked to ``<output>.lock``, which creates the name only if it does not exist
  (as ``O_EXCL`` does) and only with its whole content: a full disk or a crash between the create
  and the write can no longer leave an empty lock that blocks every later build (``pid None``).
* **A stale lock is taken over, with a note on stderr.** A lock that names a dead process on this
  host, or one that is empty or unreadable (left by a crash of an older clipvol that created the
  file before writing it), is renamed aside and replaced; the take-over is atomic, so of two
  builds that find the same stale lock only one wins. A lock held by a live process, or by a
  process on another host (whose liveness cannot be checked from here), is refused, naming it.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import sys
from pathlib import Path

from ..errors import OutputLockedError

__all__ = ["output_lock", "lock_path"]


def lock_path(output) -> Path:
    """``<output>.lock``: the lock file of the build of ``output``."""
    output = Path(output)
    return output.with_name(output.name + ".lock")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    except (OverflowError, ValueError):
        return False  # no such pid can exist
    return True


def _read_lock(lock: Path) -> bytes | None:
    """The lock file's bytes, ``b""`` when it cannot be read, None when it is gone."""
    try:
        return lock.read_bytes()
    except FileNotFoundError:
        return None
    except OSError:
        return b""


def _holder(raw: bytes) -> dict | None:
    """The ``{"pid", "host"}`` a lock's bytes name, or None (empty, garbage, not an object)."""
    try:
        doc = json.loads(raw.decode())
    except (UnicodeDecodeError, ValueError):
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("pid"), int) or isinstance(doc.get("pid"), bool):
        return None
    return doc


class output_lock:
    """Context manager: the build lock of ``output`` (see the module docstring). A second writer
    gets :class:`~clipvol.errors.OutputLockedError` naming the holder. Any build path (the streaming
    sweep, a Dask build, ``clipvol repair``) takes it around its writes."""

    def __init__(self, output) -> None:
        self.path = lock_path(output)

    def __enter__(self) -> "output_lock":
        me = {"pid": os.getpid(), "host": socket.gethostname()}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(3):
            if self._create(json.dumps(me).encode()):
                return self
            raw = _read_lock(self.path)
            if raw is None:
                continue  # released meanwhile: try again
            held = _holder(raw)
            if held is None:
                what = "is empty" if not raw else "cannot be read as a lock"
                self._take_over(raw, f"{self.path}: a stale build lock ({what}) is taken over")
                continue
            pid, host = held.get("pid"), held.get("host")
            if host == me["host"] and pid != me["pid"] and not _pid_alive(pid):
                self._take_over(raw, f"{self.path}: a stale build lock (pid {pid} on this host is gone) is taken over")
                continue
            raise OutputLockedError(
                f"{self.path}: another clipvol brick (pid {pid}, host {host}) is writing {self.path.stem}; wait for "
                "it to finish, or delete this lock file if that process is gone"
            )
        raise OutputLockedError(f"{self.path}: could not take the build lock (it keeps changing hands)")

    def _create(self, content: bytes) -> bool:
        """Create the lock with ``content`` whole, or return False if one exists. A write error (a
        full disk) leaves no file behind."""
        tmp = self.path.with_name(f".{os.getpid()}.{self.path.name}")
        try:
            fd = os.open(tmp, os.O_CREAT | os.O_TRUNC | os.O_WRONLY, 0o644)
            try:
                if os.write(fd, content) != len(content):
                    raise OSError(errno.ENOSPC, "No space left on device (short write)", str(tmp))
            finally:
                os.close(fd)
            try:
                os.link(tmp, self.path)
            except FileExistsError:
                return False
            except OSError as e:  # a file system without hard links: exclusive create, then the write
                if e.errno not in (errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK, errno.ENOSYS):
                    raise
                try:
                    fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
                except FileExistsError:
                    return False
                try:
                    os.write(fd, content)
                except BaseException:
                    os.close(fd)
                    self.path.unlink(missing_ok=True)
                    raise
                os.close(fd)
            return True
        finally:
            tmp.unlink(missing_ok=True)

    def _take_over(self, stale: bytes, note: str) -> None:
        """Remove a stale lock, atomically: rename it aside, and put it back if it was not the one
        judged stale (another process took it over first)."""
        aside = self.path.with_name(f"{self.path.name}.stale-{os.getpid()}")
        try:
            os.rename(self.path, aside)
        except FileNotFoundError:
            return
        if _read_lock(aside) != stale:
            try:
                os.link(aside, self.path)
            except FileExistsError:
                pass
        else:
            print(f"note: {note}", file=sys.stderr)
        aside.unlink(missing_ok=True)

    def __exit__(self, *exc) -> None:
        self.path.unlink(missing_ok=True)
