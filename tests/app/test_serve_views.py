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


@needs("nibabel")
def test_a_nifti_input_is_bricked_and_its_presets_are_the_patients(tmp_path):
    """A NIfTI input: bricked once (``--store``), its presets the patient's sides, its converged
    anterior frame ``clipvol render --view anterior``'s (head up, lettered), the HUD naming the edges."""
    import aiohttp
    import nibabel as nib
    from serve_harness import ServeProcess, next_json

    z, y, x = np.mgrid[0:24, 0:28, 0:20].astype(np.float32)
    head = np.exp(-((x - 12) ** 2 / 40 + (y - 14) ** 2 / 60 + (z - 10) ** 2 / 30)).astype(np.float32)
    head[2:6, 20:26, 4:8] = 1.0  # one blob off every axis: a flipped image differs
    nib.save(nib.Nifti1Image(head.T.copy(), np.diag([-1.5, 1.0, 1.2, 1.0])), tmp_path / "head.nii.gz")  # LAS storage
    store = tmp_path / "head.zarr"
    with ServeProcess([str(tmp_path / "head.nii.gz"), "--store", str(store),
                       "--size", f"{SIZE}x{SIZE}", "--threads", "1"]) as s:
        url = s.base.replace("http", "ws") + f"/ws?token={s.token}"

        async def main_():
            async with aiohttp.ClientSession() as c:
                ws = await c.ws_connect(url)
                hello = await next_json(ws, "hello")
                await _converged(ws)
                await ws.send_json({"method": "update", "state": {"view": "anterior"}})
                img, meta = await _converged(ws, 1)
                await ws.close()
                return hello, img, meta

        hello, img, meta = asyncio.run(asyncio.wait_for(main_(), 120))
    assert hello["anatomical"] is True
    assert hello["state"]["views"] == ["anterior", "posterior", "left", "right", "superior", "inferior", "iso"]
    assert "left R right L top S" in meta["hud"]  # facing the patient: their right on the image's left
    from PIL import Image

    from clipvol.tools.cli import main

    out = tmp_path / "anterior.png"
    assert main(["render", str(store), "--out", str(out), "--size", f"{SIZE}x{SIZE}", "--view", "anterior"]) == 0
    ref = np.asarray(Image.open(out).convert("RGBA"))
    assert int(np.abs(img.astype(int) - ref.astype(int)).max()) <= 1
