"""Read a clipvol store or OME-Zarr image from object storage or a web server (any fsspec URL).

The remote loader *is* the local :class:`~clipvol.loaders.zarr_store.ZarrLoader` with one thing
swapped: where chunk bytes come from. Its ``_chunk_bytes`` asks a
:class:`~clipvol.paging.bytesource.FsspecByteSource` (many requests in flight, retries with
backoff, optional on-disk cache) instead of opening a file, so decoding, validation, OME-Zarr
handling and error messages are the local loader's, unchanged.

Metadata (a few kB of JSON, the store's manifest, plus the per-brick statistics arrays) is
fetched once, concurrently, into a private temporary directory that mirrors the store's layout,
and the local loader reads and verifies it from there: a manifest the server does not give (a
404, an error page) makes the store *unverified*, exactly as a local one without it; a 404 on a
statistics array is a mismatch against the manifest, never "no data". Statistics of a level are
fetched the first time the renderer asks for them.

The on-disk cache (``cache=DIR``) keeps only chunk bytes that were verified: a chunk of a
verified store whose crc32c is the one its manifest records for the brick (of a foreign OME-Zarr:
one that decoded to the right size and passed its own checksum where it has one). Metadata, absent
keys, error pages and failures are never cached; cached bytes are verified again on every read,
and dropped and fetched afresh when they fail.
Sharded arrays whose inner chunk is the brick (:mod:`clipvol.loaders.zarr_shards`) are read with
ranged requests through the same byte source (its retries, time-outs and counting): a suffix (or
prefix) range for a shard's index, once per shard, and one range per run of neighbouring inner
chunks (a shard small enough to be one run: one request for the whole object). The on-disk
cache keeps their verified inner chunks one by one, as it keeps unsharded chunks. Chunks of
arrays whose codecs the fast path does not decode (transposes, filters, a compressor over whole
shards, ...) are read with zarr-python over its own fsspec store: same values, without this
loader's retries or cache.

Read-only: nothing is ever written to the remote store.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import tempfile
import threading
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from clipvol.bricking.channels import MEMBERS_GROUP, set_attrs
from clipvol.bricking.manifest import MANIFEST_DIR
from clipvol.bricking.store import STATS_GROUP, STAT_ARRAYS
from clipvol.bricking.store_files import MAX_METADATA_BYTES, chunk_cap
from clipvol.errors import BrickIntegrityError, ClipvolError, InputFormatError, RemoteStoreError
from clipvol.paging.bytesource import (
    DEFAULT_CONNECT_TIMEOUT,
    DEFAULT_READ_TIMEOUT,
    FsspecByteSource,
)
from clipvol.paging.loader import BrickKey

from .zarr_shard_index import ShardError, ShardLayout
from .zarr_store import _UNREAD, ZarrLoader

__all__ = ["RemoteZarrLoader"]

#: statistics arrays with more chunks than this are not mirrored (the renderer then reads bricks
#: to learn they are empty, as for a plain OME-Zarr image)
MAX_STATS_CHUNKS = 4096


def _json(data: bytes | None, where: str) -> dict | None:
    if data is None:
        return None
    try:
        doc = json.loads(data)
    except ValueError as e:
        raise InputFormatError(f"{where}: not JSON ({e})") from None
    return doc if isinstance(doc, dict) else None


def _chunk_keys(meta: dict) -> list[str]:
    """Every chunk key of a small zarr v3 array described by ``meta`` (default or v2 key encoding)."""
    shape = meta.get("shape")
    chunks = ((meta.get("chunk_grid") or {}).get("configuration") or {}).get("chunk_shape")
    if not (isinstance(shape, list) and isinstance(chunks, list) and len(shape) == len(chunks)
            and all(isinstance(v, int) and v > 0 for v in shape + chunks)):
        return []
    grid = [math.ceil(s / c) for s, c in zip(shape, chunks)]
    if math.prod(grid) > MAX_STATS_CHUNKS:
        return []
    cke = meta.get("chunk_key_encoding") or {"name": "default"}
    default = cke.get("name") == "default"
    sep = (cke.get("configuration") or {}).get("separator", "/" if default else ".")
    prefix = "c" + sep if default else ""
    import itertools

    return [prefix + sep.join(map(str, idx)) for idx in itertools.product(*(range(g) for g in grid))] or [prefix + "0"]


class RemoteZarrLoader(ZarrLoader):
    """A :class:`ZarrLoader` over a remote URL (``s3://``, ``https://``, ``gs://``, any fsspec URL).

    Parameters
    ----------
    url : str
        The store's root URL.
    cache : str or Path, optional
        Directory of an on-disk chunk cache (kept between sessions; one namespace per store
        version, so a rebuilt store is never read stale).
    storage_options : dict, optional
        fsspec options, e.g. ``{"anon": True}`` or ``{"endpoint_url": "http://..."}``;
        credentials otherwise come from the environment.
    max_in_flight : int or None
        Requests outstanding at once; ``None`` (the default): sized from the measured latency and
        bandwidth (the bandwidth-delay product, :mod:`clipvol.paging.link`), 16 to 64. The most it
        can be is also the number of loader threads a clip-texture uses by default
        (:attr:`preferred_threads`).
    retries, timeout, connect_timeout, read_timeout, deadline
        See :class:`~clipvol.paging.bytesource.FsspecByteSource` (a stalled server is given up on
        within ``timeout``, default 30 s, per key; nothing is read past ``deadline``, a
        :func:`time.monotonic` instant: a one-shot command's ``--timeout``).
    **loader_kwargs
        Passed to :class:`ZarrLoader` (``t``, ``c``, ``allow_incomplete``, ``shard_run_bytes``).

    Raises
    ------
    RemoteStoreError
        Unreachable, no credentials, access denied, retries exhausted (one line naming the URL).
    InputFormatError, StoreFormatError, StoreIncompleteError
        As :class:`ZarrLoader`, naming the URL: not a zarr store, not clipvol / OME-Zarr, ...
    """

    def __init__(self, url: str, *, cache: str | Path | None = None, storage_options: dict | None = None,
                 max_in_flight: int | None = None, retries: int = 5, timeout: float | None = None,
                 connect_timeout: float = DEFAULT_CONNECT_TIMEOUT, read_timeout: float = DEFAULT_READ_TIMEOUT,
                 deadline: float | None = None, **loader_kwargs) -> None:
        self.source = FsspecByteSource(url, storage_options=storage_options, max_in_flight=max_in_flight,
                                       retries=retries, timeout=timeout, connect_timeout=connect_timeout,
                                       read_timeout=read_timeout, cache=cache, deadline=deadline)
        self.url = self.source.display_url
        self._storage_options = storage_options
        self._mirror = Path(tempfile.mkdtemp(prefix="clipvol-remote-meta-"))
        self._finalizer = weakref.finalize(self, shutil.rmtree, str(self._mirror), True)
        self._stats_lock = threading.Lock()
        self._stats_mirrored: set[int] = set()
        try:
            self._mirror_metadata(loader_kwargs)
            super().__init__(self._mirror, **loader_kwargs)
            self.spread_levels = ()  # the spread's chunks are not mirrored: coarse levels classify their mean
        except ClipvolError as e:
            self._finalizer()
            raise self._renamed(e) from None
        except BaseException:
            self._finalizer()
            raise
        self._where = self.url

    @property
    def preferred_threads(self) -> int:
        """Loader threads that keep the most requests in flight busy (more than cores: they wait on
        I/O; those beyond the link's current size wait for a turn)."""
        return self.source.max_requests

    def _renamed(self, e: ClipvolError) -> ClipvolError:
        """``e`` with the private mirror's path replaced by the URL (messages name what the user gave)."""
        text = str(e).replace(str(self._mirror), self.url)
        try:
            return type(e)(text)
        except TypeError:  # pragma: no cover - every ClipvolError takes one message
            return e

    def _put(self, key: str, data: bytes) -> None:
        if len(data) > MAX_METADATA_BYTES * 16:
            raise InputFormatError(f"{self.url}/{key}: {len(data)} bytes, more than any metadata file may hold: refused")
        p = self._mirror / key
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)

    def _mirror_metadata(self, loader_kwargs: dict | None = None) -> None:
        src = self.source
        #: where the clipvol metadata lies under the URL: "" (a store) or an image set's member group
        self._meta_prefix = ""
        got = src.get_many(["zarr.json", ".zgroup", ".zattrs"])
        root = got["zarr.json"] if got["zarr.json"] is not None else None
        if root is None and got[".zgroup"] is None:
            raise InputFormatError(f"{self.url}: not a zarr store (neither zarr.json nor .zgroup found at this URL)")
        seed = b""
        for k, v in got.items():
            if v is not None:
                self._put(k, v)
                seed += k.encode() + b"\0" + v
        src.enable_cache(seed)
        doc = _json(root, f"{self.url}/zarr.json") if root is not None else None
        if root is not None:
            attrs = (doc or {}).get("attributes") or {}
        else:
            attrs = _json(got[".zattrs"], f"{self.url}/.zattrs") or {}
        paths: list[str] = []
        ome = attrs.get("ome") if isinstance(attrs.get("ome"), dict) else attrs
        ms = ome.get("multiscales") if isinstance(ome, dict) else None
        if isinstance(ms, list) and ms and isinstance(ms[0], dict) and isinstance(ms[0].get("datasets"), list):
            paths += [d["path"] for d in ms[0]["datasets"] if isinstance(d, dict) and isinstance(d.get("path"), str)]
        cv = attrs.get("clipvol")
        found = set_attrs(attrs, self.url)
        if found is not None and found[2] >= 2:  # an image set's root: the chosen member's metadata too
            axis, n, _ = found
            k = (loader_kwargs or {}).get(axis) or 0
            if isinstance(k, int) and not isinstance(k, bool) and 0 <= k < n:  # else ZarrLoader says why
                self._meta_prefix = f"{MEMBERS_GROUP}/{axis}/{k}/"
                got = src.get(self._meta_prefix + "zarr.json")
                if got is not None:
                    self._put(self._meta_prefix + "zarr.json", got)
                    cv = ((_json(got, f"{self.url}/{self._meta_prefix}zarr.json") or {}).get("attributes") or {}).get("clipvol")
        manifest: list[str] = []
        if isinstance(cv, dict) and isinstance(cv.get("levels"), list):
            paths += [str(L) for L in range(min(len(cv["levels"]), 64))]
            if "manifest" in cv:  # absent on the server: the loader finds no manifest (unverified)
                mdir = self._meta_prefix + MANIFEST_DIR
                manifest = [f"{mdir}/manifest.json"] + [f"{mdir}/{L}.bin" for L in range(min(len(cv["levels"]), 64))]
        paths = list(dict.fromkeys(p.strip("/") for p in paths if re.fullmatch(r"[A-Za-z0-9_.\-/]+", p)))
        keys = [f"{p}/{name}" for p in paths for name in ("zarr.json", ".zarray", ".zattrs")] + manifest
        for k, v in src.get_many(keys).items():
            if v is not None:
                self._put(k, v)

    # -- the one swapped piece: chunk bytes ------------------------------------------------------
    def _chunk_bytes(self, level: int, index) -> bytes | None:
        """The chunk from the cache (remembered, so that bytes failing verification are dropped)
        or the server (remembered, so that verified bytes are kept); never more bytes than the
        manifest records for the brick, or than the chunk shape allows. A brick the verified
        manifest records as never written costs no request."""
        am = self._arrays[level]
        key = am.chunk_path(self._chunk_lead + tuple(index)).relative_to(self._mirror).as_posix()
        sizes = self._sizes[level]
        want = int(sizes[tuple(index)]) if sizes is not None else 0
        if sizes is not None and not want:
            return None  # the verified manifest says no chunk was written: an empty brick, no request
        cap = want or self._caps[level]
        tls = self._tls
        data = None if getattr(tls, "no_cache", False) else self.source.cached(key, cap)
        if data is not None:
            tls.cached_key = key
            return data
        data = self.source.get(key)
        if data is None:
            return None
        if len(data) > cap or (want and len(data) != want):
            what = f"truncated or corrupt: {len(data)} bytes, but the store's manifest says {want}" if want \
                else f"{len(data)} bytes, more than the {cap} a chunk may hold"
            raise BrickIntegrityError(f"{self.url}: {BrickKey(level, tuple(index))}: chunk {key}: {what}")
        tls.pending = (key, data)
        return data

    def _shard_chunk(self, am, level: int, index):
        """As :meth:`ShardReader._shard_chunk`, through the on-disk cache when there is one: an inner
        chunk is cached under ``<shard key>.<its position in the shard>`` once verified (as an
        unsharded chunk is, by :meth:`_load_chunk`), and a cached one needs no request, not even
        for its shard's index."""
        if self.source.cache is None:
            return super()._shard_chunk(am, level, index)
        sidx, pos = am.shard.locate(self._chunk_lead + tuple(index))
        key = f"{self._shard_key(level, sidx)}.{pos}"
        tls = self._tls
        data = None if getattr(tls, "no_cache", False) else self.source.cached(key, chunk_cap(am.nbytes))
        if data is not None:
            tls.cached_key = key
            self.read_counter.add(len(data))  # read from the cache's disk, as an unsharded cached chunk
            return data
        data = super()._shard_chunk(am, level, index)
        if data is not None:
            tls.pending = (key, data)
        return data

    def _shard_key(self, level: int, sidx: tuple[int, ...]) -> str:
        am = self._arrays[level]
        return (am.path / am.shard_key(sidx)).relative_to(self._mirror).as_posix()

    def _shard_index_raw(self, level: int, sidx: tuple[int, ...], lay: ShardLayout):
        """A shard's encoded index by one ranged request (the last bytes of the object, or its first);
        None when the shard is absent. Its size is not asked for (a request more): an entry past
        the object's end is caught when its range reads short (:meth:`_shard_range`)."""
        key, n = self._shard_key(level, sidx), lay.index_nbytes
        data = self.source.get_range(key, -n, None) if lay.at_end else self.source.get_range(key, 0, n)
        if data is None:
            return None
        self.read_counter.add(len(data))
        return data, None

    def _shard_object(self, level: int, sidx: tuple[int, ...], cap: int) -> bytes | None:
        """A whole shard in one request; more than ``cap`` bytes (what its chunks and index may take) is refused."""
        data = self.source.get(self._shard_key(level, sidx))
        if data is None:
            return None
        self.read_counter.add(len(data))
        if len(data) > cap:
            raise ShardError(f"{len(data)} bytes, more than the {cap} a shard of this shape may hold")
        return data

    def _shard_range(self, level: int, sidx: tuple[int, ...], start: int, stop: int) -> bytes:
        """Bytes ``[start, stop)`` of a shard in one ranged request; fewer is a truncated shard."""
        data = self.source.get_range(self._shard_key(level, sidx), start, stop)
        if data is None:
            raise ShardError("the shard vanished after its index was read")
        self.read_counter.add(len(data))
        if len(data) != stop - start:
            raise ShardError(f"the shard is truncated: bytes {start}-{stop} read {len(data)}")
        return data

    def _load_chunk(self, am, level: int, index, out, st=_UNREAD) -> int:
        """As :meth:`ZarrLoader._load_chunk`; then keep verified network bytes in the cache, and
        drop cached bytes that fail and read the chunk again from the server."""
        tls = self._tls
        tls.pending = tls.cached_key = None
        try:
            got = super()._load_chunk(am, level, index, out, st)
        except BrickIntegrityError:
            key = tls.cached_key
            if key is None:
                raise
            self.source.forget(key)
            tls.pending = tls.cached_key = None
            tls.no_cache = True
            try:
                got = super()._load_chunk(am, level, index, out, st)
            finally:
                tls.no_cache = False
        pending, tls.pending = tls.pending, None
        if pending is not None and (got == 2 or (got == 1 and not self.is_clipvol_store)):
            self.source.keep(*pending)
        return got

    def _read_zarr(self, level: int, start, stop):
        """Arrays the fast path cannot decode: zarr-python over its own fsspec store."""
        arr = self._zarr_arrays.get(level)
        if arr is None:
            import zarr
            from zarr.storage import FsspecStore

            with self._lock:
                arr = self._zarr_arrays.get(level)
                if arr is None:
                    rel = self._arrays[level].path.relative_to(self._mirror).as_posix()
                    store = FsspecStore.from_url(self.source.url, storage_options=self._storage_options, read_only=True)
                    arr = zarr.open_array(store, path=rel, mode="r")
                    self._zarr_arrays[level] = arr
        sl = self._select + tuple(slice(a, b) for a, b in zip(start, stop))
        try:
            return np.asarray(arr[sl])
        except (OSError, RuntimeError) as e:
            raise RemoteStoreError(f"{self.url}: level {level}: {type(e).__name__}: {str(e)[:160]}") from None

    def brick_statistics(self, level: int):
        """As :meth:`ZarrLoader.brick_statistics`; the level's statistics arrays are fetched first."""
        self._pyramid.check_key(level, (0, 0, 0))
        if self.is_clipvol_store:
            with self._stats_lock:
                if level not in self._stats_mirrored:
                    self._mirror_stats(level)
                    self._stats_mirrored.add(level)
        return super().brick_statistics(level)

    def _mirror_stats(self, level: int) -> None:
        base = f"{self._meta_prefix}{STATS_GROUP}/{level}"
        metas = self.source.get_many([f"{self._meta_prefix}{STATS_GROUP}/zarr.json", f"{base}/zarr.json"]
                                     + [f"{base}/{n}/zarr.json" for n in STAT_ARRAYS])
        chunk_keys: list[str] = []
        for k, v in metas.items():
            if v is None:
                continue
            self._put(k, v)
            doc: Any = _json(v, f"{self.url}/{k}")
            if doc and doc.get("node_type") == "array":
                arr = k[: -len("/zarr.json")]
                keys = _chunk_keys(doc)
                if not keys:  # too many chunks to mirror: leave this array out
                    shutil.rmtree(self._mirror / arr, ignore_errors=True)
                    continue
                chunk_keys += [f"{arr}/{c}" for c in keys]
        for k, v in self.source.get_many(chunk_keys).items():
            if v is not None:
                self._put(k, v)

    def close(self) -> None:
        """Remove the private metadata mirror (also done when the loader is collected)."""
        self._finalizer()

    def __repr__(self) -> str:
        kind = "clipvol store" if self.is_clipvol_store else "OME-Zarr"
        return f"RemoteZarrLoader({self.url!r}, {kind}, {self._pyramid.num_levels} levels, brick {self._pyramid.brick_shape})"


def remote_set(url: str, *, storage_options: dict | None = None, **source_kwargs):
    """``(axis, n, meta_of)`` of the image set whose root is at ``url`` (``meta_of(k)``: member
    ``k``'s validated clipvol metadata), or None when the URL holds no version-2 set (a store)."""
    from clipvol.bricking.store import parse_metadata

    src = FsspecByteSource(url, storage_options=storage_options, **source_kwargs)
    root = src.get("zarr.json")
    doc = _json(root, f"{src.display_url}/zarr.json") or {} if root is not None else {}
    found = set_attrs(doc.get("attributes") or {}, src.display_url)
    if found is None or found[2] < 2:
        return None
    axis, n, _ = found

    def meta_of(k: int):
        key = f"{MEMBERS_GROUP}/{axis}/{k}/zarr.json"
        got = src.get(key)
        if got is None:
            raise InputFormatError(f"{src.display_url}/{key}: missing (member {k} of the set)")
        return parse_metadata((_json(got, f"{src.display_url}/{key}") or {}).get("attributes") or {},
                              f"{src.display_url} ({axis} = {k})")

    return axis, n, meta_of


def remote_store_meta(url: str, *, storage_options: dict | None = None, **source_kwargs):
    """The validated clipvol metadata of the store at ``url`` (complete or not), read without
    opening data, and a function ``level -> (chunks, bytes) | None`` giving the chunk objects
    stored for a level where the server can list them (object stores can; plain HTTP cannot).

    For ``clipvol info`` / ``clipvol check`` on a URL. Raises as :class:`RemoteZarrLoader`.
    """
    from clipvol.bricking.store import parse_metadata

    src = FsspecByteSource(url, storage_options=storage_options, **source_kwargs)
    root = src.get("zarr.json")
    if root is None:
        raise InputFormatError(f"{src.display_url}: not a clipvol store (no zarr.json at this URL)")
    doc = _json(root, f"{src.display_url}/zarr.json") or {}
    meta = parse_metadata(doc.get("attributes") or {}, src.display_url)

    def level_objects(level: int) -> tuple[int, int] | None:
        if src.url.split(":", 1)[0].lower() in ("http", "https"):
            return None  # HTTP has no listing; fsspec scrapes index pages, without sizes
        try:
            found = src.fs.find(f"{src._full(str(level))}/c", detail=True)
        except Exception:  # listing is optional (HTTP has none): the caller prints "-"
            return None
        sizes = [v.get("size") for v in found.values() if v.get("type", "file") == "file"]
        if not all(isinstance(x, int) for x in sizes):
            return None
        return len(sizes), sum(sizes)

    return meta, level_objects
