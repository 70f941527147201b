"""A headless Chromium driven over the DevTools protocol, and a page that hosts an anywidget.

The notebook view's browser half is JavaScript (pointer drags, the wheel, the menus, the HUD and
error lines); these helpers run it in a real browser without JupyterLab:

- :class:`Chromium` starts the distribution's ``chromium`` with ``--remote-debugging-pipe``: the
  DevTools protocol's commands and events are NUL-terminated JSON on the child's fds 3 and 4, so no
  websocket client is needed, and the browser opens no port.
- :class:`WidgetPage` serves, on 127.0.0.1, a page that imports the widget's own ES module
  (``_esm``) and hands its ``render`` a small stand-in for anywidget's ``model`` (get / set / on /
  off / save_changes / send). ``save_changes`` posts the changed state as the comm message a
  Jupyter front end sends (``{"method": "update", "state": ...}``); the page polls for what the
  widget sends back. The messages reach the real widget's comm handler (``Widget._handle_msg``)
  on the test's thread, in :meth:`WidgetPage.pump`, the way a kernel handles comm messages on its
  main thread (the view's GL context is current there). An exception in the handler goes where
  ipywidgets sends it outside IPython, to the widget's log (in a kernel: ``showtraceback`` on a
  comm message, which no notebook cell shows); it is kept in :attr:`WidgetPage.kernel_errors`
  and never reaches the page by that road.

Every wait is bounded: a command that gets no reply, or a condition that does not come true,
raises ``TimeoutError`` naming what was awaited.
"""

from __future__ import annotations

import http.server
import json
import logging
import os
import queue
import shutil
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

#: the binaries tried, in order (Debian's package installs ``chromium``)
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-extensions", "--disable-dev-shm-usage", "--remote-debugging-pipe")


def chromium_binary() -> str | None:
    """The Chromium to drive: the first of :data:`CHROMIUM_NAMES` on PATH."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def _high_fd(fd: int) -> int:
    """``fd`` moved to a number >= 10, so that placing the child's fds 3 and 4 clobbers neither."""
    import fcntl

    new = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
    os.close(fd)
    return new


#: run in the child before Chromium: put the two pipe ends on fds 3 and 4, then exec
_TRAMPOLINE = ("import os, sys; r, w = int(sys.argv[1]), int(sys.argv[2]); os.dup2(r, 3); os.dup2(w, 4); "
               "os.close(r); os.close(w); os.execv(sys.argv[3], sys.argv[3:])")


class Chromium:
    """A headless Chromium and one attached page (``with Chromium(binary, tmpdir) as b: ...``)."""

    def __init__(self, binary: str, profile: Path, *, timeout: float = 30.0, size=(480, 400)) -> None:
        self.timeout = float(timeout)
        to_child_r, self._to_child = (_high_fd(f) for f in os.pipe())
        self._from_child, from_child_w = (_high_fd(f) for f in os.pipe())
        self.stderr_path = Path(profile) / "chromium.log"
        self._log = open(self.stderr_path, "wb")
        args = [binary, *FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}", "about:blank"]
        self.proc = subprocess.Popen([sys.executable, "-c", _TRAMPOLINE, str(to_child_r), str(from_child_w), *args],
                                     pass_fds=(to_child_r, from_child_w), stdin=subprocess.DEVNULL,
                                     stdout=self._log, stderr=subprocess.STDOUT)
        os.close(to_child_r)
        os.close(from_child_w)
        self._next_id = 0
        self._lock = threading.Lock()
        self._replies: dict[int, dict] = {}
        self._cond = threading.Condition()
        self.events: list[dict] = []
        self._reader = threading.Thread(target=self._read, name="cdp-reader", daemon=True)
        self._reader.start()
        try:
            targets = self.call("Target.getTargets")["targetInfos"]
            page = next((t for t in targets if t["type"] == "page"), None)
            target = page["targetId"] if page else self.call("Target.createTarget", url="about:blank")["targetId"]
            self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            for domain in ("Page", "Runtime"):
                self.call(f"{domain}.enable", session=self.session)
            self.call("Emulation.setDeviceMetricsOverride", session=self.session, width=size[0], height=size[1],
                      deviceScaleFactor=1, mobile=False)
        except Exception as e:
            self.close()
            tail = self.stderr_path.read_text(errors="replace")[-2000:]
            raise RuntimeError(f"{binary} did not start a DevTools session: {e}; its log ends:\n{tail}") from e

    # -- the protocol ---------------------------------------------------------------------------
    def _read(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._from_child, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                with self._cond:
                    self._replies[-1] = {"error": {"message": "chromium closed its DevTools pipe"}}
                    self._cond.notify_all()
                return
            buf += chunk
            *msgs, buf = buf.split(b"\0")
            with self._cond:
                for raw in msgs:
                    msg = json.loads(raw)
                    if "id" in msg:
                        self._replies[msg["id"]] = msg
                    else:
                        self.events.append(msg)
                self._cond.notify_all()

    def call(self, method: str, *, session: str | None = None, **params) -> dict:
        """Send one DevTools command and wait (bounded) for its result; an error reply raises."""
        with self._lock:
            self._next_id += 1
            mid = self._next_id
        msg = {"id": mid, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        os.write(self._to_child, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        with self._cond:
            while mid not in self._replies and -1 not in self._replies:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"chromium: no reply to {method} within {self.timeout:.0f} s")
                self._cond.wait(left)
            reply = self._replies.pop(mid, None) or self._replies[-1]
        if "error" in reply:
            raise RuntimeError(f"chromium: {method} failed: {reply['error'].get('message')}")
        return reply.get("result", {})

    def page(self, method: str, **params) -> dict:
        """A command to the attached page."""
        return self.call(method, session=self.session, **params)

    def eval(self, expression: str):
        """Evaluate ``expression`` in the page and return its value (JSON); a thrown error raises."""
        r = self.page("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"page: {expression!r} threw: {r['exceptionDetails'].get('exception', {}).get('description')}")
        return r["result"].get("value")

    def page_errors(self) -> list[str]:
        """Uncaught exceptions and ``console.error`` lines of the page so far."""
        with self._cond:
            events = list(self.events)
        out = []
        for e in events:
            if e.get("method") == "Runtime.exceptionThrown":
                d = e["params"]["exceptionDetails"]
                out.append(d.get("exception", {}).get("description") or d.get("text", "exception"))
            elif e.get("method") == "Runtime.consoleAPICalled" and e["params"]["type"] == "error":
                out.append(" ".join(str(a.get("value", a.get("description"))) for a in e["params"]["args"]))
        return out

    # -- input ----------------------------------------------------------------------------------
    def mouse(self, kind: str, x: float, y: float, **extra) -> None:
        self.page("Input.dispatchMouseEvent", type=kind, x=x, y=y, **extra)

    def drag(self, start, end, steps: int = 4) -> None:
        """Press the left button at ``start``, move in ``steps`` to ``end``, release."""
        (x0, y0), (x1, y1) = start, end
        self.mouse("mouseMoved", x0, y0)
        self.mouse("mousePressed", x0, y0, button="left", buttons=1, clickCount=1)
        for i in range(1, steps + 1):
            t = i / steps
            self.mouse("mouseMoved", x0 + (x1 - x0) * t, y0 + (y1 - y0) * t, button="left", buttons=1)
        self.mouse("mouseReleased", x1, y1, button="left", buttons=0, clickCount=1)

    def wheel(self, x: float, y: float, delta_y: float) -> None:
        self.mouse("mouseWheel", x, y, deltaX=0, deltaY=delta_y)

    def key(self, key: str, code: int) -> None:
        """Press and release ``key`` (``windowsVirtualKeyCode`` ``code``) in the focused element."""
        for kind in ("rawKeyDown", "keyUp"):
            self.page("Input.dispatchKeyEvent", type=kind, key=key, code=key, windowsVirtualKeyCode=code,
                      nativeVirtualKeyCode=code)

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                os.write(self._to_child, json.dumps({"id": 0, "method": "Browser.close"}).encode() + b"\0")
                self.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait(timeout=10)
        for fd in (self._to_child, self._from_child):
            try:
                os.close(fd)
            except OSError:
                pass
        self._log.close()

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>widget</title>
<style>body { margin: 0; background: #fff; }</style></head>
<body><div id="out"></div>
<script type="module">
import widget from "/widget.js";
const state = await (await fetch("/state")).json();
window.widgetState = state;  // what the page holds, compared with the kernel's by WidgetPage.wait
const handlers = {};
let dirty = {};
let chain = Promise.resolve();
const emit = (name, ...args) => { for (const cb of handlers[name] || []) cb(...args); };
window.pending = 0;  // messages posted and not yet taken by the server
const post = (body) => {
  window.pending++;
  chain = chain.then(() => fetch("/msg", { method: "POST", body: JSON.stringify(body) }))
    .catch((e) => console.error("post failed: " + e)).finally(() => { window.pending--; });
};
const model = {
  get: (k) => state[k],
  set: (k, v) => { if (state[k] !== v) { state[k] = v; dirty[k] = v; emit("change:" + k); emit("change"); } },
  on: (name, cb) => { (handlers[name] = handlers[name] || []).push(cb); },
  off: (name, cb) => { handlers[name] = (handlers[name] || []).filter((f) => cb && f !== cb); },
  save_changes: () => { if (Object.keys(dirty).length) { post({ method: "update", state: dirty }); dirty = {}; } },
  send: (content) => post({ method: "custom", content }),
};
const receive = (msg) => {
  if (msg.method === "update") {
    for (const [k, v] of Object.entries(msg.state)) { state[k] = v; emit("change:" + k); }
    emit("change");
  } else if (msg.method === "custom") {
    emit("msg:custom", msg.content, []);
  }
};
const poll = async () => {
  try {
    for (const msg of await (await fetch("/poll")).json()) receive(msg);
  } finally {
    setTimeout(poll, 30);
  }
};
const w = widget.default ? widget.default : widget;
await w.render({ model, el: document.getElementById("out") });
window.rendered = true;
poll();
</script></body></html>
"""


class _FakeComm:
    """The comm a widget sends through: kept messages for the page, the handler the kernel calls."""

    kernel = True  # ipywidgets sends state only over a comm with a kernel

    def __init__(self) -> None:
        self.comm_id = uuid.uuid4().hex
        self.outbox: list[dict] = []
        self.lock = threading.Lock()
        self.handler = None

    def send(self, data=None, metadata=None, buffers=None) -> None:
        if buffers:
            raise AssertionError("the widget sent binary buffers; the test page only takes JSON")
        with self.lock:
            self.outbox.append(data)

    def on_msg(self, callback) -> None:
        self.handler = callback

    def on_close(self, callback) -> None:
        pass

    def close(self, *args, **kwargs) -> None:
        pass

    def take(self) -> list[dict]:
        with self.lock:
            out, self.outbox = self.outbox, []
        return out


class WidgetPage:
    """Serve ``widget`` (an anywidget) on 127.0.0.1; :meth:`pump` delivers the page's messages to it."""

    def __init__(self, widget) -> None:
        self.widget = widget
        self.comm = _FakeComm()
        widget.comm = self.comm  # ipywidgets hooks its _handle_msg to the new comm
        self.inbox: queue.Queue = queue.Queue()
        self.kernel_errors: list[BaseException] = []
        self.handled = 0
        page = self

        class Keep(logging.Handler):  # ipywidgets logs a comm handler's exception (no IPython here)
            def emit(self, record) -> None:
                if record.exc_info and record.exc_info[1] is not None:
                    page.kernel_errors.append(record.exc_info[1])

        self._keep = Keep()
        widget.log.addHandler(self._keep)

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:  # quiet
                pass

            def _send(self, body: bytes, ctype: str) -> None:
                self.send_response(200)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:
                if self.path == "/":
                    self._send(_PAGE.encode(), "text/html; charset=utf-8")
                elif self.path == "/widget.js":
                    self._send(str(page.widget._esm).encode(), "text/javascript; charset=utf-8")
                elif self.path == "/state":
                    self._send(json.dumps(page.widget.get_state()).encode(), "application/json")
                elif self.path == "/poll":
                    self._send(json.dumps(page.comm.take()).encode(), "application/json")
                else:
                    self.send_error(404)

            def do_POST(self) -> None:
                if self.path != "/msg":
                    self.send_error(404)
                    return
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                page.inbox.put(json.loads(body))
                self._send(b"{}", "application/json")

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/"
        self._thread = threading.Thread(target=self.server.serve_forever, name="widget-page", daemon=True)
        self._thread.start()

    def pump(self, seconds: float = 0.05) -> int:
        """Deliver the page's waiting messages to the widget (on this thread); how many were handled."""
        n = 0
        deadline = time.monotonic() + seconds
        while True:
            try:
                data = self.inbox.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                return n
            try:
                self.comm.handler({"content": {"data": data}, "buffers": []})
            except Exception as e:  # what ipykernel's comm manager does: log it, carry on
                self.kernel_errors.append(e)
            n += 1
            self.handled += 1

    def settled(self, browser: Chromium) -> bool:
        """Nothing in flight: every message the page posted is handled, and the page holds the
        kernel's state (so it has seen every answer, and whatever it held back for one is sent)."""
        pending, held = browser.eval("[window.pending, JSON.stringify(window.widgetState || null)]")
        # posted messages are in the inbox once the page's count drops, so that is read first
        if pending != 0 or not self.inbox.empty():
            return False
        return json.loads(held) == json.loads(json.dumps(self.widget.get_state()))

    def wait(self, browser: Chromium, predicate, what: str, timeout: float = 30.0) -> None:
        """Pump messages until the page and the kernel are :meth:`settled` and ``predicate()`` holds."""
        deadline = time.monotonic() + timeout
        while True:
            self.pump()
            if self.settled(browser) and predicate():
                return
            if time.monotonic() > deadline:
                raise TimeoutError(f"waited {timeout:.0f} s for {what}; page errors: {browser.page_errors()}")

    def close(self) -> None:
        self.widget.log.removeHandler(self._keep)
        self.server.shutdown()
        self.server.server_close()
