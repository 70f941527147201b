"""A ``clipvol serve`` child process on 127.0.0.1 (port 0), its URL, and a WebSocket client for tests.

The server is the real command (``python -m clipvol.tools.cli serve ...``), so the tests see what a
user sees: the printed URL, the token, the exit status after Ctrl-C (SIGINT). Every wait is
bounded; :meth:`ServeProcess.stop` always ends the child (SIGINT, then SIGKILL after ``timeout``).
"""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from urllib.parse import parse_qs, urlsplit


class ServeProcess:
    """``with ServeProcess(["store.zarr", "--size", "96x96"]) as s: s.url ...``"""

    def __init__(self, args, *, timeout: float = 90.0, cwd=None) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen([sys.executable, "-m", "clipvol.tools.cli", "serve", "--port", "0", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                     text=True, env=env, cwd=cwd)
        self.timeout = float(timeout)
        self.lines: queue.Queue = queue.Queue()
        self.stderr_lines: list[str] = []
        threading.Thread(target=self._pump, args=(self.proc.stdout, self.lines.put), daemon=True).start()
        threading.Thread(target=self._pump, args=(self.proc.stderr, self.stderr_lines.append), daemon=True).start()
        deadline = time.monotonic() + self.timeout
        self.url = None
        while self.url is None:
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                self.stop()
                raise RuntimeError(f"clipvol serve printed no URL (rc {self.proc.returncode}); stderr: "
                                   f"{''.join(self.stderr_lines)[-2000:]}")
            try:
                line = self.lines.get(timeout=min(left, 0.5))
            except queue.Empty:
                continue
            m = re.search(r"(http://\S+)", line)
            if m:
                self.url = m.group(1)
        parts = urlsplit(self.url)
        self.base = f"{parts.scheme}://{parts.netloc}"
        self.token = parse_qs(parts.query).get("token", [None])[0]

    @staticmethod
    def _pump(stream, put) -> None:
        for line in stream:
            put(line)

    def stop(self) -> int:
        """Ctrl-C (SIGINT) and wait; the exit status (killed after ``timeout``: -9)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=self.timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        return self.proc.returncode

    def stderr(self) -> str:
        return "".join(self.stderr_lines)

    def __enter__(self) -> "ServeProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def http_get(url: str, timeout: float = 20.0) -> tuple[int, bytes]:
    """``(status, body)`` of a GET (an error status is returned, not raised)."""
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def ws_session(url: str, script, timeout: float = 60.0):
    """Run ``await script(ws)`` on a WebSocket to ``url`` (aiohttp's client), bounded by ``timeout``;
    its result. A refused handshake raises ``aiohttp.WSServerHandshakeError`` (its ``status``)."""
    import asyncio

    import aiohttp

    async def main():
        async with aiohttp.ClientSession() as s:
            async with s.ws_connect(url) as ws:
                return await script(ws)

    return asyncio.run(asyncio.wait_for(main(), timeout))


async def next_json(ws, method: str, timeout: float = 60.0) -> dict:
    """The next JSON message of ``method`` (others skipped), bounded by ``timeout``."""
    import asyncio

    import aiohttp

    deadline = time.monotonic() + timeout
    while True:
        msg = await asyncio.wait_for(ws.receive(), max(0.01, deadline - time.monotonic()))
        if msg.type == aiohttp.WSMsgType.TEXT:
            doc = json.loads(msg.data)
            if doc.get("method") == method:
                return doc
        elif msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
            raise ConnectionError(f"the server closed the WebSocket ({msg.data}, {msg.extra})")
