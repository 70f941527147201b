"""Chunk bytes by key, from a local directory or any fsspec URL (S3, HTTP(S), GCS, ...).

Why a layer of its own: a remote store answers in tens of milliseconds per request, so a loader
that waits for one chunk at a time spends its life waiting. :class:`FsspecByteSource` lets many
requests be in flight at once (the loader threads call :meth:`~FsspecByteSource.get`
concurrently; fsspec runs them on its own event loop over kept-alive connections, bounded by
``max_in_flight``, or - with ``max_in_flight=None`` - by the bandwidth-delay product of the link as
its answers measure it, :mod:`clipvol.paging.link`), retries a
request that failed for a passing reason (HTTP 5xx / 429, a time-out, a dropped connection) with
exponential backoff and jitter within a time budget per key (a stalled server is given up on, not
waited for six times over), and may keep chunks in an on-disk :class:`ChunkCache`, so a second
session over the same store reads from local disk. The cache keeps only what the caller has
verified (:meth:`FsspecByteSource.keep`, called by the loader once a chunk passed its checksum
against the store's manifest): never a failure, never an absent key, never an error page.

Keys are ``/``-separated paths relative to the store's root (``"0/c/1/2/3"``, ``"zarr.json"``).
:meth:`get` returns the bytes, or ``None`` when the key does not exist (an absent chunk is an
empty brick in zarr). Every other failure becomes a :class:`~clipvol.errors.RemoteStoreError`
whose one-line message names the URL (credentials in the URL are masked): unreachable host,
missing credentials, permission denied (HTTP 401/403: not corruption, nothing to repair), timed
out, or retries exhausted.

Credentials come from where the storage library looks (for S3: ``AWS_ACCESS_KEY_ID`` /
``AWS_SECRET_ACCESS_KEY`` / ``AWS_PROFILE``, ``AWS_ENDPOINT_URL`` for an S3-compatible server);
they are never passed through or printed by clipvol.
"""

from __future__ import annotations

import hashlib
import os
import random
import re
import threading
import time
from pathlib import Path
from typing import Protocol, runtime_checkable
from urllib.parse import urlsplit, urlunsplit

from ..errors import InputFormatError, MissingExtraError, ParameterError, RemoteStoreError
from .link import LinkEstimate, next_in_flight

__all__ = [
    "ByteSource",
    "LocalByteSource",
    "FsspecByteSource",
    "ChunkCache",
    "is_remote_url",
    "redact_url",
    "DEFAULT_IN_FLIGHT",
    "MAX_IN_FLIGHT",
    "DEFAULT_CONNECT_TIMEOUT",
    "DEFAULT_READ_TIMEOUT",
    "check_timeout",
]

#: requests in flight per remote store by default: enough to hide ~20-50 ms of latency at the
#: decode speed of two cores, few enough not to look like a flood to a server
DEFAULT_IN_FLIGHT = 16
#: the most requests in flight when they are sized from the measured link (``max_in_flight=None``):
#: also the loader threads a remote store asks for (those beyond the current size wait their turn)
MAX_IN_FLIGHT = 64
#: answers between two re-sizings of the requests in flight
RESIZE_EVERY = 8
#: seconds to connect, and seconds without a byte before a request is stalled (``--connect-timeout``,
#: ``--read-timeout``); with the default budget of 30 s per key a stalled server is left within it
#: (in :mod:`clipvol.choices`, where ``--help`` reads them without importing this module)
from ..choices import DEFAULT_CONNECT_TIMEOUT, DEFAULT_READ_TIMEOUT  # noqa: E402
#: the longest time-out accepted (an hour): anything longer is a typo, not a slow server
MAX_TIMEOUT = 3600.0


def check_timeout(value, name: str) -> float:
    """``value`` as seconds, refused unless a finite number in (0, :data:`MAX_TIMEOUT`], naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name}: expected seconds as a number, got {value!r}") from None
    if isinstance(value, bool) or not 0 < v <= MAX_TIMEOUT:
        raise ParameterError(f"{name}: expected seconds in (0, {MAX_TIMEOUT:g}], got {value!r}")
    return v

_KEY = re.compile(r"^[A-Za-z0-9_.\-]+(/[A-Za-z0-9_.\-]+)*$")


@runtime_checkable
class ByteSource(Protocol):
    """Where a store's bytes come from: ``get(key) -> bytes | None`` (None = absent)."""

    url: str

    def get(self, key: str) -> bytes | None: ...


def redact_url(url: str) -> str:
    """``url`` with any ``user:password@`` part masked, for messages and logs."""
    try:
        parts = urlsplit(url)
    except ValueError:
        return url
    if parts.username is None and parts.password is None:
        return url
    host = parts.hostname or ""
    if parts.port:
        host += f":{parts.port}"
    return urlunsplit((parts.scheme, "***@" + host, parts.path, parts.query, parts.fragment))


def is_remote_url(text: str) -> bool:
    """Whether ``text`` is a URL with a protocol fsspec knows other than the local file system."""
    m = re.match(r"^([A-Za-z][A-Za-z0-9+.\-]*)://", text)
    if not m:
        return False
    proto = m.group(1).lower()
    if proto in ("file", "local"):
        return False
    try:
        from fsspec.registry import known_implementations, registry
    except ImportError:  # pragma: no cover - fsspec ships with zarr's remote extras
        return proto in ("s3", "gs", "gcs", "http", "https", "az", "abfs")
    return proto in known_implementations or proto in registry


def _check_key(key: str) -> str:
    if not _KEY.match(key) or any(p in (".", "..") for p in key.split("/")):
        raise ParameterError(f"store key: expected a relative path of plain names, got {key!r}")
    return key


class LocalByteSource:
    """Bytes from files under a local directory (the default for a path)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.url = str(self.root)

    def get(self, key: str) -> bytes | None:
        try:
            with open(self.root / _check_key(key), "rb") as f:
                return f.read()
        except (FileNotFoundError, NotADirectoryError):
            return None


class ChunkCache:
    """An on-disk copy of fetched keys under ``directory/<namespace>/``.

    ``namespace`` identifies the store *and its version* (the caller hashes the URL with the root
    metadata), so a rebuilt store never reads stale chunks. Files are written to a temporary name
    and renamed, so a reader never sees half a chunk. Only bytes a caller verified are put here;
    absent keys are never remembered (a 404 may be passing, and "absent" is a claim the store's
    manifest must confirm each time). A cached file that later fails verification is
    dropped (:meth:`drop`). Nothing else is evicted: the cache grows to the bytes actually viewed.
    """

    def __init__(self, directory: str | Path, namespace: str) -> None:
        self.root = Path(directory) / namespace
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ParameterError(f"--cache: cannot create the cache directory {self.root} ({e.strerror or e})") from None
        self.hits = 0

    def get(self, key: str, cap: int | None = None) -> bytes | None:
        """The cached bytes of ``key``, or None for a miss (a cached file that is not a regular file
        inside the cache, or larger than ``cap``, is a miss and is dropped)."""
        from ..bricking.store_files import read_file

        try:
            data = read_file(self.root / "data" / key, self.root, cap or 2**31)
        except (FileNotFoundError, NotADirectoryError):
            return None
        except (OSError, ValueError):
            self.drop(key)
            return None
        self.hits += 1
        return data

    def drop(self, key: str) -> None:
        """Forget ``key`` (its cached bytes failed verification)."""
        try:
            (self.root / "data" / key).unlink()
        except OSError:
            pass

    def put(self, key: str, data: bytes) -> None:
        path = self.root / "data" / key
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
            with open(tmp, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except OSError:  # a full or read-only cache disk must not break viewing
            pass


def _status(e: BaseException) -> int | None:
    """The HTTP status of a failed request, where the exception carries one."""
    for attr in ("status", "status_code", "code"):
        v = getattr(e, attr, None)
        if isinstance(v, int) and 100 <= v < 600:
            return v
    resp = getattr(e, "response", None)  # botocore ClientError
    if isinstance(resp, dict):
        v = resp.get("ResponseMetadata", {}).get("HTTPStatusCode")
        if isinstance(v, int):
            return v
    # s3fs and friends sometimes only say it in words: "... (HTTP 503)", "status code: 403"
    m = re.search(r"(?:HTTP|[Ss]tatus(?: code)?)\W{0,3}(5\d\d|429|403|401)\b", str(e)) if isinstance(e, OSError) else None
    return int(m.group(1)) if m else None


def _classify(e: BaseException) -> str:
    """``"absent"``, ``"retry"`` (a passing failure) or ``"fatal"``."""
    name = type(e).__name__
    if isinstance(e, (FileNotFoundError, NotADirectoryError)):
        return "absent"
    if name in ("NoCredentialsError", "PartialCredentialsError", "CredentialRetrievalError"):
        return "fatal"
    if isinstance(e, PermissionError):
        return "fatal"
    st = _status(e)
    if st is not None:
        return "retry" if st >= 500 or st == 429 else "fatal"
    if isinstance(e, (TimeoutError, ConnectionError)) or name in (
        "ServerTimeoutError", "ClientConnectorError", "ClientConnectionError", "ServerDisconnectedError",
        "ClientOSError", "ClientPayloadError", "ConnectTimeoutError", "ReadTimeoutError", "EndpointConnectionError",
        "IncompleteRead",
    ):
        return "retry"
    return "fatal"


def _describe(e: BaseException) -> str:
    name = type(e).__name__
    if name in ("NoCredentialsError", "PartialCredentialsError", "CredentialRetrievalError"):
        return ("no credentials found (set AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY or AWS_PROFILE, "
                "or pass storage_options={'anon': True} for a public bucket)")
    st = _status(e)
    if isinstance(e, PermissionError) or st in (401, 403):
        return (f"permission denied{f' (HTTP {st})' if st else ''}: the server refuses this client (check the "
                "credentials and the bucket's policy); the store itself may be intact")
    if st is not None:
        return f"HTTP {st}"
    if name in ("ClientConnectorError", "EndpointConnectionError", "ConnectionRefusedError") or isinstance(e, ConnectionError):
        return f"cannot connect ({name})"
    if isinstance(e, TimeoutError) or "Timeout" in name:
        return "timed out"
    text = str(e).splitlines()[0] if str(e) else ""
    return f"{name}{': ' + text[:160] if text else ''}"


class _Gate:
    """A semaphore whose capacity can change while threads wait on it (the requests in flight)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.busy = 0
        self._cv = threading.Condition()

    def resize(self, capacity: int) -> None:
        with self._cv:
            if capacity != self.capacity:
                self.capacity = int(capacity)
                self._cv.notify_all()

    def __enter__(self) -> "_Gate":
        self.acquire(None)
        return self

    def acquire(self, timeout: float | None) -> bool:
        """Take a slot, waiting at most ``timeout`` seconds (None: for as long as it takes);
        False when none came free in time."""
        end = None if timeout is None else time.monotonic() + timeout
        with self._cv:
            while self.busy >= self.capacity:
                left = None if end is None else end - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._cv.wait(left)
            self.busy += 1
        return True

    def __exit__(self, *exc) -> None:
        with self._cv:
            self.busy -= 1
            self._cv.notify()


class FsspecByteSource:
    """Bytes from any fsspec URL, many requests in flight, retried with backoff, optionally cached.

    Parameters
    ----------
    url : str
        The store's root, e.g. ``s3://bucket/scan.zarr`` or ``https://host/scan.zarr``.
    storage_options : dict, optional
        Passed to the fsspec file system (e.g. ``{"anon": True}``, ``{"endpoint_url": ...}``).
    max_in_flight : int or None
        Most requests outstanding at once (shared by all calling threads). ``None``: sized from the
        link as measured (:mod:`clipvol.paging.link`): the bandwidth-delay product of the answers so
        far, between :data:`DEFAULT_IN_FLIGHT` and :data:`MAX_IN_FLIGHT`, so a store 50 ms away
        keeps enough requests outstanding to hide the round trip, and a slow link is not split into
        more answers than it carries (they would all arrive late, the nearest bricks with them).
    retries : int
        Extra attempts after a passing failure (5xx, 429, time-out, dropped connection).
    backoff : float
        First wait in seconds; doubled per attempt, with +-50 % jitter, capped at 5 s.
    timeout : float, optional
        Seconds one key may take, all its attempts and waits together: no retry starts that could
        not finish inside it. Default: ``max(30, connect_timeout + read_timeout)``.
    connect_timeout : float
        Seconds to establish a connection (default 10).
    read_timeout : float
        Seconds without a byte arriving before a request counts as stalled (default 10).
    cache : str or Path, optional
        Directory of an on-disk :class:`ChunkCache`.
    deadline : float, optional
        A :func:`time.monotonic` instant after which no request waits, starts or goes on: a
        one-shot command's ``--timeout`` bounding the whole command. A request in flight is given
        at most the time left (an HTTP request's whole answer, however slowly it trickles in: a
        per-read timeout alone lets a server that sends a byte a second hold it for ever), and a
        key asked for after it fails at once (:class:`RemoteStoreError` naming the time limit).
    """

    def __init__(self, url: str, *, storage_options: dict | None = None, max_in_flight: int | None = DEFAULT_IN_FLIGHT,
                 retries: int = 5, backoff: float = 0.05, timeout: float | None = None,
                 connect_timeout: float = DEFAULT_CONNECT_TIMEOUT, read_timeout: float = DEFAULT_READ_TIMEOUT,
                 cache: str | Path | None = None, deadline: float | None = None) -> None:
        try:
            import fsspec
        except ImportError:  # pragma: no cover
            raise MissingExtraError(f"{redact_url(url)}: remote stores need fsspec: pip install 'clipvol[remote]'") from None
        self.adaptive = max_in_flight is None
        if self.adaptive:
            max_in_flight = DEFAULT_IN_FLIGHT
        if max_in_flight < 1:
            raise ParameterError(f"max_in_flight: expected an integer >= 1 or None, got {max_in_flight}")
        for name, v in (("connect_timeout", connect_timeout), ("read_timeout", read_timeout)):
            check_timeout(v, name)
        if timeout is None:
            timeout = max(30.0, float(connect_timeout) + float(read_timeout))
        check_timeout(timeout, "timeout")
        if retries < 0 or not backoff >= 0:
            raise ParameterError(f"retries/backoff: expected >= 0, >= 0, got {retries}, {backoff}")
        self.url = url.rstrip("/")
        self.display_url = redact_url(self.url)
        self.max_in_flight = int(max_in_flight)
        #: the most requests this source will ever have outstanding (connections it may keep open)
        self.max_requests = MAX_IN_FLIGHT if self.adaptive else self.max_in_flight
        self.retries, self.backoff, self.timeout = int(retries), float(backoff), float(timeout)
        self.connect_timeout, self.read_timeout = float(connect_timeout), float(read_timeout)
        #: time.monotonic() instant past which nothing is read (None: no limit beyond ``timeout`` per key)
        self.deadline = None if deadline is None else float(deadline)
        opts = dict(storage_options or {})
        proto = urlsplit(self.url).scheme.lower()
        self._http = proto in ("http", "https") and "client_kwargs" not in opts
        if proto in ("http", "https") and "client_kwargs" not in opts:
            import aiohttp

            opts["client_kwargs"] = {"timeout": aiohttp.ClientTimeout(
                total=self.timeout, connect=self.connect_timeout, sock_connect=self.connect_timeout,
                sock_read=self.read_timeout)}
        if proto == "s3":
            opts.setdefault("config_kwargs", {}).setdefault("connect_timeout", self.connect_timeout)
            opts["config_kwargs"].setdefault("read_timeout", self.read_timeout)
            opts["config_kwargs"].setdefault("max_pool_connections", max(10, self.max_requests))
            # one attempt per call: the retries (and their time budget) are this class's, not botocore's on top
            opts["config_kwargs"].setdefault("retries", {"max_attempts": 1, "mode": "standard"})
        try:
            # a fresh instance: fsspec caches file systems by their arguments, which would keep
            # credentials (or their absence) from an earlier session alive
            self.fs, self._root = fsspec.core.url_to_fs(self.url, skip_instance_cache=True, **opts)
        except ImportError as e:
            raise InputFormatError(f"{self.display_url}: no file system for this URL ({e}); install the fsspec "
                                   f"implementation it needs (s3fs for s3://, gcsfs for gs://)") from None
        except (ValueError, TypeError) as e:
            raise InputFormatError(f"{self.display_url}: not a usable URL ({e})") from None
        self._gate = _Gate(self.max_in_flight)
        #: latency and bandwidth of the answers so far (each request's send time, last byte, bytes)
        self.link = LinkEstimate()
        self._resize_lock = threading.Lock()
        self._cache_dir = cache
        self.cache: ChunkCache | None = None
        self.requests = 0  # requests sent, retries included
        self.retried = 0
        self.bytes_fetched = 0  # response bytes over the network (counted where they arrive)
        self._count_lock = threading.Lock()

    def enable_cache(self, namespace_seed: bytes) -> None:
        """Start the on-disk cache (if a directory was given) in a namespace for this store's version."""
        if self._cache_dir is not None:
            ns = hashlib.sha256(self.display_url.encode() + b"\0" + namespace_seed).hexdigest()[:20]
            self.cache = ChunkCache(self._cache_dir, ns)

    def _full(self, key: str) -> str:
        return f"{self._root.rstrip('/')}/{key}" if self._root else key

    def get(self, key: str) -> bytes | None:
        """The bytes at ``key`` from the server (never from the cache), ``None`` when absent; raises
        :class:`RemoteStoreError` otherwise."""
        return self._fetch(_check_key(key))

    def get_range(self, key: str, start: int, end: int | None) -> bytes | None:
        """Bytes ``[start, end)`` of ``key`` from the server in one ranged request (``start < 0``,
        ``end`` None: the last ``-start`` bytes), ``None`` when the key is absent. Same retries,
        time-outs and counting as :meth:`get`. An object that ends before ``end`` answers fewer
        bytes (or none, HTTP 416): the caller, who knows how many it asked for, decides. A server
        that ignores the range and sends more is refused."""
        if isinstance(start, bool) or not isinstance(start, int) or (end is not None and not (isinstance(end, int) and 0 <= start < end)) \
                or (end is None and start >= 0):
            raise ParameterError(f"byte range of {key}: expected 0 <= start < end, or start < 0 and no end, got {start}, {end}")
        data = self._fetch(_check_key(key), (start, end))
        want = -start if end is None else end - start
        if data is not None and len(data) > want:
            raise RemoteStoreError(f"{self.display_url}: {key}: asked for {want} bytes (a byte range), got {len(data)}: "
                                   "the server ignores byte ranges, which a sharded store needs")
        return data

    def cached(self, key: str, cap: int | None = None) -> bytes | None:
        """``key``'s bytes from the on-disk cache, or None (no cache, or a miss). The caller verifies
        them as it would fresh bytes and calls :meth:`forget` for them when they fail."""
        if self.cache is None:
            return None
        return self.cache.get(_check_key(key), cap)

    def keep(self, key: str, data: bytes) -> None:
        """Put ``data`` in the cache: the caller has verified it is ``key``'s true content."""
        if self.cache is not None and data is not None:
            self.cache.put(_check_key(key), bytes(data))

    def forget(self, key: str) -> None:
        """Drop ``key`` from the cache (its cached bytes failed verification)."""
        if self.cache is not None:
            self.cache.drop(_check_key(key))

    def _out_of_time(self, key: str) -> RemoteStoreError:
        return RemoteStoreError(f"{self.display_url}: cannot read {key}: the time limit ran out (--timeout; "
                                "a server that answers this slowly cannot be waited for)")

    def _cat(self, path: str, byte_range, start: float) -> bytes:
        """One request for ``path`` (a byte range or all of it), its whole answer bounded by what is
        left of the key's budget (``timeout``, counted from ``start``) and of the deadline - not only
        each socket read, which a server sending a byte a second never trips."""
        a, b = (None, None) if byte_range is None else byte_range
        left = None
        if self._http or self.deadline is not None:
            left = self.timeout - (time.monotonic() - start)
            if self.deadline is not None:
                left = min(left, self.deadline - time.monotonic())
            left = max(0.05, left)
        if self._http:
            import aiohttp
            from fsspec.asyn import sync

            limit = aiohttp.ClientTimeout(total=left, connect=self.connect_timeout, sock_connect=self.connect_timeout,
                                          sock_read=self.read_timeout)

            async def one():
                return await self.fs._cat_file(path, start=a, end=b, timeout=limit)

            return bytes(sync(self.fs.loop, one))
        if left is not None and getattr(self.fs, "async_impl", False):  # fsspec's own bound of the whole call
            return bytes(self.fs.cat_file(path, start=a, end=b, timeout=left))
        if byte_range is None:
            return bytes(self.fs.cat_file(path))
        return bytes(self.fs.cat_file(path, start=a, end=b))

    def _fetch(self, key: str, byte_range: tuple[int, int | None] | None = None) -> bytes | None:
        path = self._full(key)
        attempt = 0
        start = time.monotonic()
        while True:
            if self.deadline is not None:  # waiting for a slot counts against the deadline too
                if not self._gate.acquire(max(0.0, self.deadline - time.monotonic())):
                    raise self._out_of_time(key)
            else:
                self._gate.acquire(None)
            try:
                if self.deadline is not None and time.monotonic() >= self.deadline:
                    raise self._out_of_time(key)
                with self._count_lock:
                    self.requests += 1
                try:
                    sent = time.monotonic()
                    data = self._cat(path, byte_range, start)
                except Exception as e:  # the storage libraries raise many types: classify them
                    kind = _classify(e)
                    if kind == "absent":
                        return None
                    if byte_range is not None and _status(e) == 416:
                        return b""  # range not satisfiable: the object ends before it (the caller refuses)
                    wait = min(5.0, self.backoff * 2 ** attempt) * random.uniform(0.5, 1.5)
                    # no retry that could not finish within the budget: a stalled server is given up on
                    spent = time.monotonic() - start
                    over = kind == "retry" and spent + wait + self.read_timeout > self.timeout
                    if kind != "fatal" and self.deadline is not None and time.monotonic() + wait >= self.deadline:
                        raise self._out_of_time(key) from None
                    if kind == "fatal" or attempt >= self.retries or over:
                        tail = f" after {attempt + 1} attempts" if kind == "retry" else ""
                        if over and attempt < self.retries:
                            tail += f" in {spent:.0f} s (the budget per request is {self.timeout:g} s)"
                        raise RemoteStoreError(f"{self.display_url}: cannot read {key}: {_describe(e)}{tail}") from None
                else:
                    self.link.add(sent, time.monotonic(), len(data))
                    with self._count_lock:
                        self.bytes_fetched += len(data)
                        resize = self.adaptive and self.requests % RESIZE_EVERY == 0
                    if resize:
                        self._resize()
                    return data
            finally:
                self._gate.__exit__()
            attempt += 1
            with self._count_lock:
                self.retried += 1
            time.sleep(wait)

    def _resize(self) -> None:
        """Requests in flight from the link measured so far (``max_in_flight=None``)."""
        if not self._resize_lock.acquire(blocking=False):
            return  # another thread is re-sizing from the same answers
        try:
            target = self.link.in_flight(lo=DEFAULT_IN_FLIGHT, hi=MAX_IN_FLIGHT, default=DEFAULT_IN_FLIGHT)
            n = next_in_flight(self.max_in_flight, target)
            self.max_in_flight = n
            self._gate.resize(n)
        finally:
            self._resize_lock.release()

    def get_many(self, keys: list[str]) -> dict[str, bytes | None]:
        """Fetch ``keys`` concurrently (up to ``max_in_flight`` at once)."""
        from concurrent.futures import ThreadPoolExecutor

        if not keys:
            return {}
        with ThreadPoolExecutor(min(self.max_requests, len(keys)), thread_name_prefix="clipvol-fetch") as pool:
            return dict(zip(keys, pool.map(self.get, keys)))

    def __repr__(self) -> str:
        n = "None" if self.adaptive else self.max_in_flight
        return f"FsspecByteSource({self.display_url!r}, max_in_flight={n}, cache={self._cache_dir!r})"
