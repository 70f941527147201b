"""Which CRC-32C function verifies the zarr loader's chunk checksums.

Why a module of its own: the choice is made once per process, among packages that differ only in
speed (and in whether they release the GIL), and it must never fall on a function that computes
something else: each candidate is checked against the standard's check value and the codec's
residue before it may vouch for data (:func:`crc32c_implementation`). The checksum itself is
verified in :mod:`clipvol.loaders.zarr_integrity`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["CRC32C_PACKAGES", "crc32c_implementation"]

#: CRC-32C packages, fastest first on the CPUs we measured (``docs/benchmarks.md``, integrity):
#: fastcrc folds with VPCLMULQDQ / PMULL (57 GB/s on our AVX-512 machine) and releases the GIL;
#: crc32c uses the SSE4.2 / ARMv8 CRC instruction (28 GB/s) and releases the GIL; google-crc32c
#: (zarr's own dependency, so always installed) is as fast as crc32c but holds the GIL.
CRC32C_PACKAGES = ("fastcrc", "crc32c", "google-crc32c")
#: CRC-32C of b"123456789", the check value of the iSCSI CRC (RFC 3720)
_CRC32C_CHECK = 0xE3069283
#: CRC-32C of any byte string followed by its own CRC-32C (little-endian), the codec's layout
_CRC32C_RESIDUE = 0x48674BC7


def _crc32c_function(package: str) -> Callable[[Any], int] | None:
    """The CRC-32C function of ``package`` (one of :data:`CRC32C_PACKAGES`), or None when it is not installed."""
    try:
        if package == "fastcrc":
            from fastcrc.crc32 import iscsi as fn
        elif package == "crc32c":
            from crc32c import crc32c as fn
        elif package == "google-crc32c":
            from google_crc32c import value

            def fn(data, _value=value):  # it refuses memoryviews (the loader's read buffer), not arrays
                return _value(np.frombuffer(data, dtype=np.uint8))
        else:
            raise ValueError(f"expected one of {CRC32C_PACKAGES}, got {package!r}")
    except ImportError:
        return None
    return fn


def _computes_crc32c(fn: Callable[[Any], int]) -> bool:
    """True when ``fn`` gives the standard check value, on bytes and on a memoryview of a bytearray
    (the loader hands it both), and the codec's residue: a package that computes another CRC, or
    a build that mishandles buffers, is never used to vouch for data."""
    msg = bytearray(b"123456789")
    try:
        return (fn(bytes(msg)) == _CRC32C_CHECK and fn(memoryview(msg)) == _CRC32C_CHECK
                and fn(bytes(msg) + _CRC32C_CHECK.to_bytes(4, "little")) == _CRC32C_RESIDUE)
    except Exception:  # noqa: BLE001  anything a broken build raises disqualifies it
        return False


@functools.cache
def crc32c_implementation() -> tuple[str, Callable[[Any], int]]:
    """``(package, function)``: the first of :data:`CRC32C_PACKAGES` that is installed and passes
    :func:`_computes_crc32c`. Chosen once per process; ``verify_checksums`` stays a full check of
    every byte whichever is used, only its speed differs."""
    for package in CRC32C_PACKAGES:
        fn = _crc32c_function(package)
        if fn is not None and _computes_crc32c(fn):
            return package, fn
    raise ImportError(f"no working CRC-32C among {CRC32C_PACKAGES} (google-crc32c is a dependency of zarr: "
                      "reinstall it)")
