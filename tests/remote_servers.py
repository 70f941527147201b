"""Real servers on 127.0.0.1 for the remote-store tests: a static HTTP server over a directory
(optionally slow, behind a bandwidth cap, keeping connections alive, failing with 503, refusing
with 403, stalling, or answering chosen paths with a chosen status and body) and a moto S3 server.

Shared by the paging, CLI and benchmark code that needs a store behind a network socket.
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import io
import os
import re
import threading
import time
from collections import Counter
from pathlib import Path


class _Handler(http.server.SimpleHTTPRequestHandler):
    """Static files with injected latency and faults; counts requests per path."""

    def log_message(self, *args) -> None:  # quiet
        pass

    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        srv = self.server
        with srv.lock:
            srv.counts[self.path] += 1
            n = srv.counts[self.path]
        if srv.latency:
            time.sleep(srv.latency)
        if any(self.path.startswith(p) for p in srv.stall):
            srv.stopping.wait(120)  # accept, never answer: until the server shuts down (bounded)
            return
        if self.path in srv.answers:
            status, body = srv.answers[self.path]
            self.send_response(status)
            self.send_header("Content-Type", "text/html" if body.lstrip().startswith(b"<") else "application/octet-stream")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        if any(self.path.startswith(p) for p in srv.forbid):
            self.send_error(403, "Forbidden")
            return
        if srv.fail_first and n <= srv.fail_first:
            with srv.lock:
                srv.failures += 1
            self.send_error(503, "Service Unavailable (injected)")
            return
        if self.headers.get("Range"):
            self._send_range(self.headers["Range"])
            return
        super().do_GET()

    def _log(self, status: int, nbytes: int) -> None:
        with self.server.lock:
            self.server.log.append((self.path, self.headers.get("Range"), status, nbytes))

    def _send_range(self, spec: str) -> None:
        """One byte range of a file (``bytes=a-b``, ``bytes=a-``, ``bytes=-n``): 206 with the bytes,
        416 when it starts past the end, as an HTTP server or object store answers."""
        path = self.translate_path(self.path)
        if not os.path.isfile(path):
            self._log(404, 0)
            self.send_error(404, "File not found")
            return
        size = os.path.getsize(path)
        m = re.fullmatch(r"bytes=(\d*)-(\d*)", spec.strip())
        if not m or not (m[1] or m[2]):
            self._log(400, 0)
            self.send_error(400, "Bad range")
            return
        if m[1]:
            start, last = int(m[1]), min(size - 1, int(m[2])) if m[2] else size - 1
        else:
            start, last = max(0, size - int(m[2])), size - 1
        if start >= size or last < start:
            self._log(416, 0)
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        with open(path, "rb") as f:
            f.seek(start)
            body = f.read(last - start + 1)
        self.send_response(206)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Range", f"bytes {start}-{last}/{size}")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self._log(206, len(body))
        self.copyfile(io.BytesIO(body), self.wfile, logged=True)

    def copyfile(self, source, outputfile, logged: bool = False) -> None:
        """The file's bytes, paced to the server's ``bandwidth`` (one link shared by every answer);
        a whole-file answer is logged with its size in ``server.log``."""
        srv = self.server
        if any(self.path.startswith(p) for p in srv.drip):  # one byte at a time, until shutdown
            try:
                for b in iter(lambda: source.read(1), b""):
                    if srv.stopping.wait(1.0 / srv.drip_rate):
                        return
                    outputfile.write(b)
                    outputfile.flush()
            except OSError:  # the client gave up (its deadline): what the test wants
                pass
            return
        if not logged:
            try:
                self._log(200, os.fstat(source.fileno()).st_size)
            except (AttributeError, OSError, io.UnsupportedOperation):  # a directory listing (BytesIO)
                self._log(200, len(source.getbuffer()))
        if not srv.bandwidth:
            return super().copyfile(source, outputfile)
        while True:
            piece = source.read(64 * 1024)
            if not piece:
                return
            with srv.lock:  # reserve the link for this piece, after every piece reserved before it
                begin = max(time.monotonic(), srv.link_free)
                srv.link_free = begin + len(piece) / srv.bandwidth
                until = srv.link_free
            time.sleep(max(0.0, until - time.monotonic()))
            outputfile.write(piece)


class _Server(http.server.ThreadingHTTPServer):
    """A threading server with a backlog for many clients connecting at once (the default of 5
    drops connections, which then wait a second for the SYN to be sent again), counting connections."""

    request_queue_size = 256

    def process_request(self, request, client_address) -> None:
        with self.lock:
            self.connections += 1
        super().process_request(request, client_address)


@contextlib.contextmanager
def serve_directory(root: str | Path, *, latency: float = 0.0, fail_first: int = 0, forbid: tuple[str, ...] = (),
                    stall: tuple[str, ...] = (), answers: dict | None = None, bandwidth: float | None = None,
                    keep_alive: bool = False, drip: tuple[str, ...] = (), drip_rate: float = 1.0):
    """Serve ``root`` on ``http://127.0.0.1:PORT``; yields ``(base_url, server)``.

    ``latency`` seconds are slept before every answer; ``bandwidth`` (bytes a second) caps the
    file bytes of all answers together, as one link would; ``keep_alive`` answers in HTTP/1.1 and
    keeps connections open for the next request (``server.connections`` counts those accepted);
    the first ``fail_first`` requests of every
    path get HTTP 503; paths starting with a prefix in ``forbid`` get 403; requests for paths
    starting with a prefix in ``stall`` are accepted and never answered (until shutdown);
    files of paths starting with a prefix in ``drip`` are sent ``drip_rate`` bytes a second, each
    byte flushed (a server that answers, but too slowly to ever finish a chunk);
    ``answers`` maps a path to ``(status, body bytes)`` sent instead of the file (a 404, an HTML
    error page with 200). ``Range`` requests get 206 with the bytes (416 past the end). ``server.counts``
    (per path), ``server.log`` (every file answer: path, range, status, bytes) and ``server.failures``
    say what was asked, what was sent and what was refused; all of these can be changed on ``server`` while it runs.
    """
    cls = type("_KeepAlive", (_Handler,), {"protocol_version": "HTTP/1.1"}) if keep_alive else _Handler
    handler = functools.partial(cls, directory=str(root))
    srv = _Server(("127.0.0.1", 0), handler)
    srv.daemon_threads = True
    srv.bandwidth, srv.link_free, srv.connections = bandwidth, 0.0, 0
    srv.lock = threading.Lock()
    srv.counts = Counter()
    srv.log = []  # (path, Range header or None, status, body bytes sent) of every file answer
    srv.failures = 0
    srv.latency, srv.fail_first, srv.forbid = latency, fail_first, forbid
    srv.stall, srv.answers, srv.stopping = stall, dict(answers or {}), threading.Event()
    srv.drip, srv.drip_rate = tuple(drip), float(drip_rate)
    t = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    t.start()
    try:
        yield f"http://127.0.0.1:{srv.server_address[1]}", srv
    finally:
        srv.stopping.set()
        srv.shutdown()
        srv.server_close()
        t.join(5)


def _serve_child(root: str, kwargs: dict, q, stop) -> None:
    with serve_directory(root, **kwargs) as (url, _):
        q.put(url)
        stop.wait()


@contextlib.contextmanager
def serve_directory_process(root: str | Path, **kwargs):
    """:func:`serve_directory` in a process of its own (so the server does not share the client's
    interpreter lock: what a benchmark measures); yields the base URL."""
    import multiprocessing as mp

    ctx = mp.get_context("fork")
    q, stop = ctx.Queue(), ctx.Event()
    proc = ctx.Process(target=_serve_child, args=(str(root), kwargs, q, stop), daemon=True)
    proc.start()
    try:
        yield q.get(timeout=30)
    finally:
        stop.set()
        proc.join(5)
        if proc.is_alive():
            proc.terminate()
            proc.join(5)


@contextlib.contextmanager
def moto_s3():
    """A moto S3 server on 127.0.0.1 (its own thread, real HTTP); yields the endpoint URL.

    Sets the AWS environment for the duration (dummy keys, the endpoint, no instance metadata
    look-ups) and restores it afterwards.
    """
    import logging

    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    env = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
           "AWS_ENDPOINT_URL": endpoint, "AWS_EC2_METADATA_DISABLED": "true"}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield endpoint
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        server.stop()


def upload_directory(endpoint: str, root: str | Path, bucket: str, prefix: str) -> int:
    """Put every file under ``root`` into ``s3://bucket/prefix/`` with boto3; returns the count."""
    import boto3

    s3 = boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1")
    with contextlib.suppress(s3.exceptions.BucketAlreadyOwnedByYou):
        s3.create_bucket(Bucket=bucket)
    n = 0
    root = Path(root)
    for p in sorted(root.rglob("*")):
        if p.is_file():
            s3.put_object(Bucket=bucket, Key=f"{prefix}/{p.relative_to(root).as_posix()}", Body=p.read_bytes())
            n += 1
    return n
