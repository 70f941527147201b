"""The clipvol error hierarchy.

Every error a user can cause is a :class:`ClipvolError` *and* the built-in exception a caller
would naturally catch (``ValueError``, ``FileNotFoundError``, ...), so ``except ValueError`` keeps
working while ``except ClipvolError`` catches everything of ours. Messages say what was expected,
what was found, and name the file, brick or parameter, so a person can act on them.
"""

from __future__ import annotations

import errno

__all__ = [
    "ClipvolError",
    "ParameterError",
    "InputNotFoundError",
    "InputFormatError",
    "StoreFormatError",
    "StoreIncompleteError",
    "UnverifiedStoreError",
    "OutputExistsError",
    "LoaderError",
    "BrickLoadError",
    "BrickIntegrityError",
    "OutputLockedError",
    "SourceChangedError",
    "OutputWriteError",
    "FrameIncompleteError",
    "OPERATIONAL_ERRNOS",
    "describe_os_error",
    "MissingExtraError",
    "RemoteStoreError",
]


class ClipvolError(Exception):
    """Base class of every error clipvol raises on purpose."""


class ParameterError(ClipvolError, ValueError):
    """A parameter is out of range or of the wrong kind (names the parameter)."""


class InputNotFoundError(ClipvolError, FileNotFoundError):
    """An input file or store does not exist (names the path)."""


class InputFormatError(ClipvolError, ValueError):
    """An input exists but cannot be read as what it claims to be (names the file)."""


class StoreFormatError(ClipvolError, ValueError):
    """A store's metadata is missing, inconsistent or absurd (names the store and the key)."""


class StoreIncompleteError(StoreFormatError):
    """A store whose completion marker is missing: a build was interrupted (re-run to resume)."""


class UnverifiedStoreError(StoreFormatError):
    """A clipvol store whose manifest is missing or does not verify, refused where only verified data
    may be drawn (``clipvol render`` without ``--unverified``); says why and what to do."""


class OutputExistsError(ClipvolError, FileExistsError):
    """The output exists and ``overwrite`` was not given."""


class LoaderError(ClipvolError, RuntimeError):
    """A loader broke its contract (wrong shape or dtype), naming the loader, level and brick."""


class BrickLoadError(ClipvolError, RuntimeError):
    """Loading a brick failed after its retries; the original exception is ``__cause__``."""


class BrickIntegrityError(InputFormatError):
    """A stored brick fails its checksum or its plausibility check (decoded bounds against the
    store's statistics; a missing chunk the statistics say holds data). Deterministic: retrying
    reads the same bytes, so the clip-texture marks the brick failed at once (names store and brick)."""


class OutputLockedError(OutputExistsError):
    """Another live process holds the output's build lock (names the lock file and its pid)."""


class SourceChangedError(OutputExistsError):
    """A build is resumed against a source that differs from the one it started with, or the source
    changed while it was being bricked (says what changed; the store is not marked complete)."""


class MissingExtraError(ClipvolError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it."""


class RemoteStoreError(ClipvolError, OSError):
    """A remote store (S3, HTTP, any fsspec URL) cannot be read: unreachable, no credentials,
    access denied, or retries exhausted (names the URL, never the credentials)."""


class FrameIncompleteError(ClipvolError, RuntimeError):
    """Some bricks of a frame failed and no verified ancestor stands in for them: the image would
    show a hole as if it were data (names the bricks and their causes). The CLI exits with
    :attr:`exit_code` 3 and writes nothing unless ``--allow-partial`` is given."""

    exit_code = 3


class OutputWriteError(ClipvolError, OSError):
    """Writing an output failed for a reason of the machine, not of the data: the disk is full,
    the file system is read-only, permission is denied (names the output and the file)."""


#: errno values that are the machine's state, not a bug: reported as one line, never a traceback
OPERATIONAL_ERRNOS = frozenset(
    getattr(errno, n) for n in ("ENOSPC", "EDQUOT", "EROFS", "EACCES", "EPERM", "EIO", "EFBIG", "EMFILE", "ENFILE",
                                "ENAMETOOLONG", "ENOTDIR", "EISDIR", "ELOOP", "EXDEV")
    if hasattr(errno, n)
)


def describe_os_error(e: OSError) -> str:
    """``e`` as one phrase: what went wrong and on which file (``No space left on device: o.zarr/0/c/1/2/3``)."""
    what = e.strerror or type(e).__name__
    name = e.filename if e.filename is not None else None
    return f"{what}: {name}" if name is not None else f"{what} ({type(e).__name__})"
