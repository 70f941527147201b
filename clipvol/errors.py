"""The clipvol error hierarchy.

Every error a user can cause is a :class:`ClipvolError` *and* the built-in exception a caller
would naturally catch (``ValueError``, ``FileNotFoundError``, ...), so ``except ValueError`` keeps
working while ``except ClipvolError`` catches everything of ours. Messages say what was expected,
what was found, and name the file, brick or parameter, so a person can act on them.
"""

from __future__ import annotations

__all__ = [
    "ClipvolError",
    "ParameterError",
    "InputNotFoundError",
    "InputFormatError",
    "StoreFormatError",
    "StoreIncompleteError",
    "OutputExistsError",
    "LoaderError",
    "BrickLoadError",
    "MissingExtraError",
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


class OutputExistsError(ClipvolError, FileExistsError):
    """The output exists and ``overwrite`` was not given."""


class LoaderError(ClipvolError, RuntimeError):
    """A loader broke its contract (wrong shape or dtype), naming the loader, level and brick."""


class BrickLoadError(ClipvolError, RuntimeError):
    """Loading a brick failed after its retries; the original exception is ``__cause__``."""


class MissingExtraError(ClipvolError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it."""
