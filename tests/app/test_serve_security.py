"""``clipvol serve`` is secure by default: the token on every request, nothing of the file system, bounded floods.

Each rule is checked against a real ``clipvol serve`` process (``tests/serve_harness.py``) from
outside, as an attacker on the same machine would probe it: plain HTTP requests (urllib) and
WebSockets (aiohttp's client). A server without the rule fails its test: without the token check
the page (or the WebSocket's first message) comes back; with a static route a traversal returns
the file's bytes; without the rate bound the flooding connection stays open; without the view
limit the extra WebSocket is accepted.
"""

from __future__ import annotations

import asyncio

import pytest
from optional import needs

pytest.importorskip("moderngl")
pytestmark = [needs("aiohttp"), pytest.mark.gl]

SOURCE = "procedural:fractal?size=32"


@pytest.fixture(scope="module")
def server():
    from serve_harness import ServeProcess

    s = ServeProcess([SOURCE, "--brick", "16", "--size", "32x32", "--threads", "1", "--max-views", "2",
                      "--message-rate", "20"])
    yield s
    assert s.stop() == 130


def test_the_printed_url_binds_loopback_and_carries_a_random_token(server):
    from serve_harness import http_get

    assert server.base.startswith("http://127.0.0.1:")
    assert server.token and len(server.token) >= 24
    status, body = http_get(server.url)
    assert status == 200 and b"page.js" in body


@pytest.mark.parametrize("path", ["/", "/page.js", "/view.js", "/ws", "/nothing"])
@pytest.mark.parametrize("token", [None, "", "wrong-token-123", "TOKEN-PREFIX"])
def test_a_missing_or_wrong_token_gets_403_and_nothing_else(server, path, token):
    from serve_harness import http_get

    if token == "TOKEN-PREFIX":
        token = server.token[:-1]  # all but one character: still wrong
    query = "" if token is None else f"?token={token}"
    status, body = http_get(server.base + path + query)
    assert status == 403
    assert body == b"403: Forbidden"


def test_the_websocket_needs_the_token_too(server):
    import aiohttp
    from serve_harness import next_json, ws_session

    async def hello(ws):
        return await next_json(ws, "hello")

    for bad in ("", "?token=wrong-token-123"):
        with pytest.raises(aiohttp.WSServerHandshakeError) as e:
            ws_session(server.base.replace("http", "ws") + "/ws" + bad, hello)
        assert e.value.status == 403
    doc = ws_session(server.base.replace("http", "ws") + f"/ws?token={server.token}", hello)
    assert doc["stores"] == [SOURCE]


@pytest.mark.parametrize("path", [
    "/../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/etc/passwd", "/..%2f..%2f..%2fetc%2fpasswd",
    "/web/page.js", "/clipvol/app/web/view.js", "/view.js/../../../../etc/passwd", "//etc/passwd",
    "/static/../../pyproject.toml", "/static/pyproject.toml", "/page.html",
])
def test_no_path_reaches_the_file_system(server, path):
    import http.client

    conn = http.client.HTTPConnection(server.base.split("//")[1], timeout=20)
    conn.request("GET", f"{path}?token={server.token}")  # sent as written (no client-side normalising)
    r = conn.getresponse()
    body = r.read()
    conn.close()
    assert r.status in (403, 404)
    assert b"root:" not in body and b"[project]" not in body and b"function render" not in body


def test_a_store_is_chosen_by_its_index_only(server):
    import aiohttp
    from serve_harness import next_json, ws_session

    async def hello(ws):
        return await next_json(ws, "hello")

    for store in ("1", "-1", "../etc/passwd", "/etc/passwd"):
        with pytest.raises(aiohttp.WSServerHandshakeError) as e:
            ws_session(server.base.replace("http", "ws") + f"/ws?token={server.token}&store={store}", hello)
        assert e.value.status == 404


def test_a_message_flood_closes_that_connection_and_the_server_lives_on(server):
    import aiohttp
    from serve_harness import next_json, ws_session

    url = server.base.replace("http", "ws") + f"/ws?token={server.token}"

    async def flood(ws):
        await next_json(ws, "hello")
        for i in range(500):
            if ws.closed:
                break
            await ws.send_json({"method": "update", "state": {"azimuth": float(i)}})
        while True:  # the server closes it: a bounded wait (ws_session's timeout)
            msg = await ws.receive()
            if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING):
                return ws.close_code

    assert ws_session(url, flood) == 1008  # policy violation: over --rate messages a second

    async def calm(ws):
        await next_json(ws, "hello")
        await ws.send_json({"method": "update", "state": {"zoom": 2.0}})
        while True:  # the view's first frames, then the one of this change (bounded: ws_session's timeout)
            frame = await next_json(ws, "frame")
            if frame["handled"] >= 1:
                return frame

    assert ws_session(url, calm)["handled"] == 1  # the server lives on and answers the next view


def test_a_big_or_malformed_message_is_refused(server):
    import aiohttp
    from serve_harness import next_json, ws_session

    url = server.base.replace("http", "ws") + f"/ws?token={server.token}"

    async def wrong(ws):
        await next_json(ws, "hello")
        await ws.send_str("not json")
        first = await next_json(ws, "update")
        await ws.send_json({"method": "update", "state": {"handled": 99, "zoom": 3.0}})
        second = await next_json(ws, "update")
        await ws.send_str("x" * (64 * 1024))
        msg = await ws.receive()
        while msg.type == aiohttp.WSMsgType.TEXT:
            msg = await ws.receive()
        return first, second, ws.close_code

    first, second, code = ws_session(url, wrong)
    assert "expected" in first["state"]["error"]
    assert "no field 'handled'" in second["state"]["error"]
    assert code == 1009  # message too big


def test_views_beyond_max_views_are_refused(server):
    import aiohttp
    from serve_harness import next_json

    url = server.base.replace("http", "ws") + f"/ws?token={server.token}"

    async def main_():
        async with aiohttp.ClientSession() as s:
            a = await s.ws_connect(url)
            b = await s.ws_connect(url)
            await next_json(a, "hello")
            await next_json(b, "hello")
            try:
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await s.ws_connect(url)
                return e.value.status
            finally:
                await a.close()
                await b.close()

    assert asyncio.run(asyncio.wait_for(main_(), 60)) == 503

