"""``clipvol serve``'s web server: one page, its two scripts and one WebSocket per view (aiohttp).

aiohttp (the asyncio HTTP library fsspec's HTTP store already uses, in the ``remote`` and
``serve`` extras) serves four fixed routes and nothing else: ``/`` (the page), ``/view.js`` (the
live view's module, shared with the notebook widget), ``/page.js`` (the page's controls and its
WebSocket ``model``) and ``/ws`` (a view). No path of a request reaches the file system: the
assets are package files read by fixed names, and a store is picked by its index in the list the
server was started with (``?store=1``).

**Secure by default**, as Jupyter is: the server binds 127.0.0.1 unless told otherwise, and every
request - the page, the scripts and the WebSocket - must carry the server's token (``?token=``,
compared in constant time); a missing or wrong one gets ``403`` with no other content. Binding
another interface without a token is refused (:func:`check_exposure`). A flood is bounded: at
most ``max_views`` WebSockets at once (more get ``503``), each message at most 16 KiB, each
connection at most ``rate`` messages a second (a token bucket; over it the connection is closed
with code 1008), and what waits to be drawn is the newest state per view, never a queue.
Responses carry ``Referrer-Policy: no-referrer`` (the token is in the URL) and a content security
policy that lets the page load only its own scripts and images.

The page's messages are the notebook widget's (``{"method": "update", "state": {...}}``), checked
by :class:`~clipvol.app.serve.state.ViewState`; the server answers each with the state it took
(``handled``, the widget's acknowledgement) and the worker's frames: a JSON ``frame`` message
(format, size, whether converged, the HUD, the error line, the camera) then the image as a binary
message.
"""

from __future__ import annotations

import asyncio
import copy
import ipaddress
import json
import re
import secrets
import socket
import time

from ... import interrupts
from ...errors import MissingExtraError, ParameterError

__all__ = ["check_exposure", "make_app", "serve", "LOOPBACK"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")
#: the largest message a page may send (a state change is a few hundred bytes)
MAX_MESSAGE = 16 * 1024
#: how often the serving loop looks for a Ctrl-C that C code swallowed (:mod:`clipvol.interrupts`)
INTERRUPT_POLL_S = 0.25
_HEADERS = {
    "Cache-Control": "no-store",
    "Referrer-Policy": "no-referrer",
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'unsafe-inline'; img-src blob:; "
                               "connect-src 'self'; frame-ancestors 'none'",
}


def _aiohttp():
    try:
        from aiohttp import web
    except ImportError:
        raise MissingExtraError("clipvol serve needs aiohttp (the web server): pip install 'clipvol[serve]'") from None
    return web


def is_loopback(host: str) -> bool:
    """Whether ``host`` names only this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_exposure(host: str, token: str | None) -> None:
    """Refuse what would open the data to the network without a token (``--no-token`` off loopback)
    and tokens too short to be secret."""
    if token is None:
        if not is_loopback(host):
            raise ParameterError(f"--no-token: refused with --host {host}: anyone who can reach that interface "
                                 f"would see the data; keep the token (the default) or bind 127.0.0.1")
        return
    if len(token) < 8 or not re.fullmatch(r"[A-Za-z0-9._~-]+", token):
        raise ParameterError(f"--token: expected at least 8 characters of A-Z a-z 0-9 . _ ~ -, got {len(token)} "
                             f"character(s){'' if re.fullmatch(r'[A-Za-z0-9._~-]*', token) else ' with others'}")


class _Bucket:
    """A token bucket: ``rate`` messages a second, ``burst`` at once."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate, self.burst = float(rate), float(burst)
        self.level = self.burst
        self.t = time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.level = min(self.burst, self.level + (now - self.t) * self.rate)
        self.t = now
        if self.level < 1.0:
            return False
        self.level -= 1.0
        return True


class _Outbox:
    """What waits to go to one page: the newest frame (an older one unsent is dropped) and state updates."""

    def __init__(self) -> None:
        self.frame = None
        self.updates: list = []
        self.event = asyncio.Event()

    def offer(self, msg: dict, data) -> None:
        if data is not None:
            self.frame = (msg, data)
        else:
            self.updates = (self.updates + [msg])[-16:]
        self.event.set()


def make_app(worker, *, token: str | None, size=(512, 512), max_views: int = 8, rate: float = 120.0):
    """The aiohttp application of ``worker``'s stores (see the module's docstring for the routes)."""
    web = _aiohttp()
    from ..live_view import asset, view_esm
    from .state import ViewState
    from .worker import new_view_id

    outboxes: dict[int, _Outbox] = {}
    loop_box: list = []
    tf_names = _tf_names()

    def deliver(vid, msg, data) -> None:  # on the worker's thread
        loop = loop_box[0] if loop_box else None
        box = outboxes.get(vid)
        if loop is not None and box is not None:
            loop.call_soon_threadsafe(box.offer, msg, data)

    worker.deliver = deliver

    def forbidden():
        return web.Response(status=403, text="403: Forbidden", headers=_HEADERS)

    @web.middleware
    async def guard(request, handler):
        if token is not None:
            given = request.query.get("token", "")
            if not secrets.compare_digest(given.encode(), token.encode()):
                return forbidden()
        resp = await handler(request)
        for k, v in _HEADERS.items():
            resp.headers.setdefault(k, v)
        return resp

    def text(body: str, ctype: str):
        return web.Response(text=body, content_type=ctype, charset="utf-8")

    page_html = asset("page.html").replace("__QUERY__", "" if token is None else f"?token={token}")

    async def page(request):
        return text(page_html, "text/html")

    async def page_js(request):
        return text(asset("page.js"), "text/javascript")

    async def view_js(request):
        return text(view_esm(), "text/javascript")

    async def ws_view(request):
        try:
            store = int(request.query.get("store", "0"))
        except ValueError:
            store = -1
        if not 0 <= store < len(worker.stores):
            return web.Response(status=404, text=f"404: no store {request.query.get('store')!r}")
        if len(outboxes) >= max_views:
            return web.Response(status=503, text=f"503: {max_views} views are open (the server's --max-views)")
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=30.0)
        await ws.prepare(request)
        vid = new_view_id()
        box = outboxes[vid] = _Outbox()
        sess = worker.stores[store].session
        frame = worker.stores[store].frame
        from ...scene.views import ANATOMICAL_VIEWS, ARRAY_VIEWS, is_anatomical

        views = tuple(ANATOMICAL_VIEWS) if is_anatomical(frame) else tuple(ARRAY_VIEWS)
        state = ViewState(views, tf_names, tuple(int(v) for v in sess.pyramid.shape))
        hello = {"method": "hello", "stores": worker.names, "store": store, "size": list(size),
                 "state": state.public(), "value_range": [float(v) for v in sess.pyramid.value_range],
                 "anatomical": is_anatomical(frame),
                 "shape": [int(v) for v in sess.pyramid.shape]}
        await ws.send_str(json.dumps(hello))

        async def send_loop():
            while not ws.closed:
                await box.event.wait()
                box.event.clear()
                updates, box.updates = box.updates, []
                frame_msg, box.frame = box.frame, None
                for m in updates:
                    await ws.send_str(json.dumps(m))
                if frame_msg is not None:
                    await ws.send_str(json.dumps(frame_msg[0]))
                    await ws.send_bytes(frame_msg[1])

        sender = asyncio.ensure_future(send_loop())
        worker.open_view(vid, store, size, copy.deepcopy(state))
        bucket = _Bucket(rate, 2 * rate)
        try:
            async for msg in ws:
                if msg.type != web.WSMsgType.TEXT:
                    break
                if not bucket.take():
                    await ws.close(code=1008, message=f"over {rate:g} messages a second".encode())
                    break
                _take(worker, vid, state, msg.data, box)
        finally:
            sender.cancel()
            worker.close_view(vid)
            outboxes.pop(vid, None)
        return ws

    async def remember_loop(app):
        loop_box.append(asyncio.get_running_loop())

    app = web.Application(middlewares=[guard], client_max_size=MAX_MESSAGE)
    app.on_startup.append(remember_loop)
    app.router.add_get("/", page)
    app.router.add_get("/page.js", page_js)
    app.router.add_get("/view.js", view_js)
    app.router.add_get("/ws", ws_view)
    return app


def _tf_names() -> tuple[str, ...]:
    from ...scene.transfer import TransferFunction

    return ("auto", *TransferFunction.names())


def _take(worker, vid: int, state, raw: str, box: _Outbox) -> None:
    """One message of a page: a checked state change handed to the worker, or its error answered."""
    from ...render.failures import _cause as one_line

    try:
        try:
            msg = json.loads(raw)
        except ValueError:
            raise ParameterError(f"message: expected JSON, got {raw[:40]!r}") from None
        if not isinstance(msg, dict) or msg.get("method") != "update" or not isinstance(msg.get("state"), dict):
            raise ParameterError("message: expected {\"method\": \"update\", \"state\": {...}}")
        changes = msg["state"]
        pick = None
        if "pick" in changes:
            p = changes["pick"]
            if not (isinstance(p, list) and len(p) >= 3 and all(isinstance(v, (int, float)) for v in p[:3])):
                raise ParameterError(f"pick: expected [x, y, shift, counter], got {p!r}")
            pick = (float(p[0]), float(p[1]), bool(p[2]))
        kinds = state.apply(changes)
    except ParameterError as e:
        state.handled += 1
        box.offer({"method": "update", "state": {"error": one_line(e), "handled": state.handled}}, None)
        return
    state.handled += 1
    if kinds or pick is not None:
        worker.request(vid, copy.deepcopy(state), kinds, pick)
    else:  # nothing to draw: the page may send its next change
        box.offer({"method": "update", "state": {"handled": state.handled}}, None)


def serve(worker, *, host: str = "127.0.0.1", port: int = 8642, token: str | None, size=(512, 512),
          max_views: int = 8, rate: float = 120.0, announce=print, stop: asyncio.Event | None = None) -> None:
    """Serve ``worker``'s stores on ``host:port`` until interrupted (Ctrl-C) or ``stop`` is set.

    ``announce`` gets the URL to open (with its token) once the socket listens; ``port`` 0 takes a
    free port. The caller closes the worker afterwards.
    """
    check_exposure(host, token)
    web = _aiohttp()
    app = make_app(worker, token=token, size=size, max_views=max_views, rate=rate)
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, int(port)))
    except OSError as e:
        sock.close()
        raise ParameterError(f"--host {host} --port {port}: cannot listen there: {e.strerror or e}") from None

    async def main() -> None:
        runner = web.AppRunner(app, handle_signals=False, access_log=None)
        await runner.setup()
        try:
            await web.SockSite(runner, sock).start()
            bound = sock.getsockname()[1]
            shown = f"[{host}]" if ":" in host else host
            query = f"?token={token}" if token is not None else ""
            announce(f"http://{shown}:{bound}/{query}")
            until = stop if stop is not None else asyncio.Event()
            while not until.is_set():
                # a Ctrl-C that C code swallowed on its way (clipvol.interrupts) still stops the server
                interrupts.check()
                try:
                    await asyncio.wait_for(until.wait(), INTERRUPT_POLL_S)
                except asyncio.TimeoutError:
                    pass
        finally:
            await runner.cleanup()

    try:
        asyncio.run(main())
    finally:
        sock.close()
