"""Read bricks from a zarr store: a clipvol store, or any plain OME-Zarr image.

:class:`ZarrLoader` is the loader plug-in (entry point ``zarr`` of ``clipvol.loaders``) and only
composes the jobs it does, each in a module of its own:

- :mod:`clipvol.loaders.zarr_meta` - JSON metadata read and validated before zarr opens anything;
- :mod:`clipvol.loaders.zarr_open` - what the store is: a clipvol store's pyramid, or a plain
  OME-Zarr 0.4 / 0.5 image's levels, leading (t, c) axes, placement and value range;
- :mod:`clipvol.loaders.zarr_chunks` - the chunk fast path (file read + numcodecs decode in the
  loader thread) and the zarr-python fallback; the one raw fetch a remote loader overrides;
- :mod:`clipvol.loaders.zarr_shards` - inner chunks of sharded arrays by byte range, neighbours
  fetched in one request (:mod:`~clipvol.loaders.zarr_shard_index`, :mod:`~clipvol.loaders.zarr_shard_cache`);
- :mod:`clipvol.loaders.zarr_integrity` - the manifest, chunk checksums and statistics checks
  (never wrong data as if right), and the per-brick statistics;
- :mod:`clipvol.loaders.zarr_crc` - which CRC-32C package computes the checksums;
- :mod:`clipvol.loaders.zarr_levels` - coarse levels an OME-Zarr image lacks, computed on demand.

Why mixins rather than held objects: the jobs share one state (the per-level arrays, tables and
the lock) that the hot path (:meth:`ZarrLoader.read_brick_into`) reads on every brick, and
:class:`~clipvol.loaders.zarr_remote.RemoteZarrLoader` swaps single methods of the read path
(``_chunk_bytes``, ``_load_chunk``, ``_read_zarr``); each mixin holds methods only, this class holds
the state and sets it up, and re-exports the names other modules import from here.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from clipvol.bricking.manifest import Manifest
from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import InputNotFoundError, ParameterError
from clipvol.paging.readcount import ReadCounter

from .zarr_chunks import ChunkReader
from .zarr_crc import CRC32C_PACKAGES, crc32c_implementation
from .zarr_crc import _CRC32C_CHECK, _CRC32C_RESIDUE, _computes_crc32c, _crc32c_function  # noqa: F401  re-exported
from .zarr_integrity import IntegrityChecks, UnverifiedStoreWarning
from .zarr_integrity import _UNREAD, SAMPLE_STRIDE  # noqa: F401  re-exported (zarr_remote, tools)
from .zarr_levels import DERIVED_CACHE_BYTES, ComputedLevels  # noqa: F401  re-exported
from .zarr_meta import group_attributes, set_of
from .zarr_meta import inside  # noqa: F401  re-exported
from .zarr_open import StoreOpening
from .zarr_shards import SHARD_RUN_BYTES, ShardReader
from .zarr_spread import SpreadReader

__all__ = ["ZarrLoader", "UnverifiedStoreWarning", "crc32c_implementation", "CRC32C_PACKAGES"]


class ZarrLoader(StoreOpening, ChunkReader, ShardReader, IntegrityChecks, ComputedLevels, SpreadReader):
    """Loader for a clipvol store or a plain OME-Zarr image on the local file system.

    Parameters
    ----------
    path : str or Path
        The store's directory (a ``zarr:`` prefix is accepted, for :func:`clipvol.open_store`
        plug-in URLs).
    t, c : int, optional
        For an OME-Zarr image with time and/or channel axes (``t, c, z, y, x``, as microscopes
        write them): the time point and channel to read (default 0). The loader is then the 3-D
        volume at that ``(t, c)``; open one loader per time point or channel.
    shard_run_bytes : int
        For sharded arrays: the most bytes one read takes from a shard - the brick asked for and
        its neighbours in the shard, served from memory when the loader threads ask for them
        (:mod:`clipvol.loaders.zarr_shards`; default 8 MiB). 0 reads one inner chunk per request.

    Raises
    ------
    InputNotFoundError
        ``path`` does not exist.
    StoreIncompleteError
        A clipvol store whose build was interrupted (``complete: false``).
    StoreFormatError, InputFormatError
        Metadata that is inconsistent, absurd, or describes unsupported data.
    """

    def __init__(self, path: str | Path, *, t: int | None = None, c: int | None = None,
                 allow_incomplete: bool = False, shard_run_bytes: int = SHARD_RUN_BYTES) -> None:
        self._allow_incomplete = bool(allow_incomplete)
        if isinstance(shard_run_bytes, bool) or not isinstance(shard_run_bytes, int) or shard_run_bytes < 0:
            raise ParameterError(f"shard_run_bytes: expected an integer >= 0, got {shard_run_bytes!r}")
        self.shard_run_bytes = shard_run_bytes
        if isinstance(path, str) and path.startswith("zarr:"):
            path = path[len("zarr:"):]
        self.path = Path(path)
        self._where = str(self.path)
        if not self.path.exists():
            raise InputNotFoundError(f"{self._where}: no such store")
        self._root_real = os.path.realpath(self.path)
        self._dirs_ok: set[str] = set()  # chunk folders already resolved inside the store
        self._manifest: Manifest | None = None
        #: True when the store's manifest verified (every brick's chunk size, crc32c and bounds are pinned)
        self.verified = False
        #: True when the verified manifest also pins every level's array metadata and the multiscale
        #: transforms (False: unverified, or a manifest written before metadata pins)
        self.metadata_pinned = False
        #: one line saying why the store is (un)verified
        self.trust = ""
        attrs = group_attributes(self.path, self._where)
        self._lock = threading.Lock()
        #: bytes of chunk files read (counted in ``_load_chunk``, where they are read)
        self.read_counter = ReadCounter()
        self._zarr_arrays: dict[int, Any] = {}
        self._stats: dict[int, dict[str, np.ndarray] | None] = {}
        self._checks: dict[int, list | None] = {}  # per level: nested lists [bz][by][bx] -> min, max, nan, inf, crc
        #: per level: (its ArrayMeta, one byte per brick, 1 where the sampled decode check passed on
        #: bytes the verified manifest proves; IntegrityChecks._check_loaded)
        self._decode_proven: dict[int, tuple[Any, bytearray]] = {}
        self._derived: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._derived_bytes = 0
        self._want = {"t": t, "c": c}
        self._select: tuple[int, ...] = ()  # index of the leading (t, c) axes
        self._chunk_lead: tuple[int, ...] = ()  # ... as chunk grid index
        self._within: tuple[int, ...] = ()  # ... inside that chunk
        self.axes: tuple[str, ...] = ()  # names of the leading axes ("t", "c")
        self.lead_shape: tuple[int, ...] = ()
        self.origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world z, y, x of voxel 0 beyond the translations
        self.unit: str | None = None  # spatial unit, when the store says
        #: the group holding the clipvol metadata, statistics, manifest and summary tables: the store
        #: itself, or a member group of an image set (``clipvol_members/c/K``)
        self.meta_path = self.path
        found = set_of(attrs, self._where)
        if found is not None and found[2] >= 2:  # the root of a 4-D clipvol brick: the member's 3-D view
            self._open_set_member(*found[:2])
        elif "clipvol" in attrs:
            self._open_clipvol(attrs)
        else:
            self._open_ome(attrs)
        self._open_spread(attrs)
        self._prepare_hot_path()

    @property
    def manifest(self) -> Manifest | None:
        """The store's verified manifest (:mod:`clipvol.bricking.manifest`), or None (unverified or foreign)."""
        return self._manifest

    @property
    def checksummed(self) -> bool:
        """True when every stored level carries zarr v3's ``crc32c`` codec (each chunk is verified on read)."""
        return all(am.checksum for am in self._arrays)

    # -- the Loader protocol ------------------------------------------------------------------
    @property
    def pyramid(self) -> Pyramid:
        return self._pyramid

    @property
    def stored_levels(self) -> int:
        """How many levels are read from the store (the rest are computed on demand)."""
        return self._stored

    def __repr__(self) -> str:
        kind = "clipvol store" if self.is_clipvol_store else "OME-Zarr"
        return f"ZarrLoader({self._where!r}, {kind}, {self._pyramid.num_levels} levels, brick {self._pyramid.brick_shape})"
