"""Several views of one ``clipvol serve`` at once: each its own camera and settings over one clip-texture.

Two WebSockets (aiohttp's client) on one real server: one turns, zooms and switches to a grey MIP;
the other's converged frame stays ``clipvol render``'s default view (run here, the reference), and
the first's equals ``clipvol render`` of its own camera and settings. A server that kept one state
for all views, or let one view's transfer function or mode leak into another's frame, fails.
"""

from __future__ import annotations

import asyncio
import io
import json

import numpy as np
import pytest
from optional import needs

pytest.importorskip("moderngl")
pytestmark = [needs("aiohttp"), pytest.mark.gl]

SOURCE = "procedural:fractal?size=40"
SIZE = 64


def _png(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"))


async def _converged(ws, handled: int = 0) -> tuple[np.ndarray, dict]:
    """The next converged frame of the view's first ``handled`` messages (its JSON message, then its
    PNG), bounded by the caller's timeout."""
    import aiohttp

    meta = None
    while True:
        msg = await ws.receive()
        if msg.type == aiohttp.WSMsgType.TEXT:
            doc = json.loads(msg.data)
            meta = doc if doc.get("method") == "frame" else meta
        elif msg.type == aiohttp.WSMsgType.BINARY:
            if meta is not None and meta["full"] and meta["handled"] >= handled:
                return _png(msg.data), meta
        else:
            raise ConnectionError(f"closed: {msg}")


def _render(tmp_path, name: str, *flags) -> np.ndarray:
    from PIL import Image

    from clipvol.tools.cli import main

    out = tmp_path / f"{name}.png"
    assert main(["render", SOURCE, "--brick", "16", "--out", str(out), "--size", f"{SIZE}x{SIZE}", *flags]) == 0
    return np.asarray(Image.open(out).convert("RGBA"))


def test_two_views_keep_their_own_camera_and_settings(tmp_path):
    import aiohttp
    from serve_harness import ServeProcess, next_json

    with ServeProcess([SOURCE, "--brick", "16", "--size", f"{SIZE}x{SIZE}", "--threads", "1"]) as s:
        url = s.base.replace("http", "ws") + f"/ws?token={s.token}"

        async def main_():
            async with aiohttp.ClientSession() as c:
                a = await c.ws_connect(url)
                b = await c.ws_connect(url)
                await next_json(a, "hello")
                await next_json(b, "hello")
                b_first, _ = await _converged(b)
                await _converged(a)
                await a.send_json({"method": "update", "state": {"azimuth": 50.0, "zoom": 1.5, "tf": "grey",
                                                                   "mode": "mip"}})
                a_img, a_meta = await _converged(a, 1)
                await b.send_json({"method": "update", "state": {"elevation": 0.0}})  # no change: an answer, no frame
                ack = await next_json(b, "update")
                await b.send_json({"method": "update", "state": {"zoom": 1.0001}})
                b_img, b_meta = await _converged(b, 2)  # drawn after a's grey MIP, through the same session
                await a.close()
                await b.close()
                return b_first, a_img, a_meta, ack, b_img, b_meta

        b_first, a_img, a_meta, ack, b_img, b_meta = asyncio.run(asyncio.wait_for(main_(), 120))
    iso = _render(tmp_path, "iso", "--view", "iso")
    assert int(np.abs(b_first.astype(int) - iso.astype(int)).max()) <= 1
    cam = tmp_path / "a.json"
    cam.write_text(json.dumps(a_meta["camera"]))
    a_ref = _render(tmp_path, "a", "--camera", str(cam), "--tf", "grey", "--mode", "mip")
    assert int(np.abs(a_img.astype(int) - a_ref.astype(int)).max()) <= 1
    assert np.array_equal(a_img[..., 0], a_img[..., 2])  # grey
    assert ack["state"] == {"handled": 1}
    cam.write_text(json.dumps(b_meta["camera"]))
    b_ref = _render(tmp_path, "b", "--camera", str(cam))  # b keeps its own composite and colour map
    assert int(np.abs(b_img.astype(int) - b_ref.astype(int)).max()) <= 1
    assert not np.array_equal(b_img[..., 0], b_img[..., 2])
