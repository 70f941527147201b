"""``clipvol serve`` in a real browser: the page turns, zooms and switches, and its still frame is ``clipvol render``'s.

A real ``clipvol serve`` process (``tests/serve_harness.py``) serves two stores; a headless
Chromium (``tests/browser_harness.py``, DevTools protocol) opens the printed URL and is driven by
its input layer (pointer drags, the wheel, clicks). References: the converged frame the page
received (the PNG bytes, read back out of the page) against ``clipvol render`` of the same store and
camera run in this process (the camera the server sent with the frame, through ``--camera``, or the
same ``--view`` preset), within one 8-bit level; the grey preset's R == G == B; the corrupt
chunks the test wrote itself for the failed-brick HUD.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import time

import numpy as np
import pytest
from optional import CHROMIUM, needs

pytest.importorskip("moderngl")
pytestmark = [CHROMIUM, needs("aiohttp"), pytest.mark.gl]

SIZE = 96
IMG = "document.querySelector('#view img')"
HUD = "document.querySelector('#view pre')"
ALERT = "document.querySelector('[role=alert]')"


def _volume() -> np.ndarray:
    z, y, x = np.mgrid[0:48, 0:48, 0:48].astype(np.float32)
    v = np.exp(-((x - 30) ** 2 + (y - 24) ** 2 + (z - 20) ** 2) / 120.0)
    v += 0.6 * np.exp(-((x - 14) ** 2 + (y - 30) ** 2 + (z - 30) ** 2) / 40.0)  # off-centre: a turn changes the image
    return v.astype(np.float32)


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    """A bricked store and a copy whose every chunk is corrupt."""
    from clipvol.tools.cli import main

    d = tmp_path_factory.mktemp("serve-stores")
    np.save(d / "v.npy", _volume())
    assert main(["brick", str(d / "v.npy"), str(d / "v.zarr"), "--brick", "16"]) == 0
    shutil.copytree(d / "v.zarr", d / "broken.zarr")
    for level in ("0", "1", "2"):
        for chunk in (d / "broken.zarr" / level / "c").rglob("*"):
            if chunk.is_file():
                raw = bytearray(chunk.read_bytes())
                raw[len(raw) // 2] ^= 0xFF
                chunk.write_bytes(bytes(raw))
    return d


@pytest.fixture(scope="module")
def server(stores):
    from serve_harness import ServeProcess

    s = ServeProcess([str(stores / "v.zarr"), str(stores / "broken.zarr"), "--size", f"{SIZE}x{SIZE}",
                      "--threads", "2", "--memory-budget", "64MB"])
    yield s
    assert s.stop() == 130  # Ctrl-C ends it cleanly, with the CLI's interrupt status
    assert "interrupted" in s.stderr() and "Traceback" not in s.stderr()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    from browser_harness import Chromium, chromium_binary

    b = Chromium(chromium_binary(), tmp_path_factory.mktemp("chromium-profile"), timeout=60.0)
    yield b
    b.close()


def _wait(browser, expr: str, what: str, timeout: float = 90.0):
    deadline = time.monotonic() + timeout
    while True:
        v = browser.eval(expr)
        if v:
            return v
        if time.monotonic() > deadline:
            raise TimeoutError(f"waited {timeout:.0f} s for {what}; page errors: {browser.page_errors()}")
        time.sleep(0.05)


def _open(browser, url: str) -> None:
    browser.events.clear()
    browser.page("Page.navigate", url=url)
    _wait(browser, "window.clipvol && window.clipvol.full >= 1 && document.querySelector('#view img').complete",
          "the first converged frame")


def _leave(browser) -> None:
    browser.page("Page.navigate", url="about:blank")
    browser.events.clear()


def _full_after(browser, n: int) -> tuple[np.ndarray, dict]:
    """The next converged frame after the ``n``-th: the PNG bytes the page received, decoded, and its message."""
    from PIL import Image

    # a converged frame of everything the page has sent (the server's count of messages taken: `handled`)
    _wait(browser, f"window.clipvol.full > {n} && window.clipvol.last.full && {IMG}.complete && "
                   "window.clipvol.lastFullMessage.handled === window.clipvol.sent", "a converged frame")
    url = browser.eval("new Promise((ok) => { const r = new FileReader(); r.onload = () => ok(r.result); "
                       "r.readAsDataURL(window.clipvol.lastFull); })")
    head, _, b64 = url.partition(",")
    assert head == "data:image/png;base64"  # the converged frame is lossless
    meta = json.loads(browser.eval("JSON.stringify(window.clipvol.lastFullMessage)"))
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(b64))).convert("RGBA")), meta


def _full(browser) -> int:
    return int(browser.eval("window.clipvol.full"))


def _render(store, tmp_path, *flags) -> np.ndarray:
    """``clipvol render`` of ``store`` (the reference, run here, not by the server)."""
    from PIL import Image

    from clipvol.tools.cli import main

    out = tmp_path / f"ref{len(list(tmp_path.glob('ref*.png')))}.png"
    assert main(["render", str(store), "--out", str(out), "--size", f"{SIZE}x{SIZE}", *flags]) == 0
    return np.asarray(Image.open(out).convert("RGBA"))


def _same(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    assert int(np.abs(a.astype(np.int16) - b.astype(np.int16)).max()) <= 1  # within one 8-bit level
    assert (a[..., 3] > 0).sum() > 0.05 * a[..., 3].size  # and something is drawn


def _centre(browser):
    r = json.loads(browser.eval(f"JSON.stringify({IMG}.getBoundingClientRect())"))
    return r["x"] + r["width"] / 2, r["y"] + r["height"] / 2


def test_the_first_frame_is_clipvol_renders_and_a_drag_brings_fast_frames_then_the_converged_one(
        browser, server, stores, tmp_path):
    _open(browser, server.url)
    try:
        first, meta = _full_after(browser, 0)
        assert meta["converged"] and meta["error"] == ""
        _same(first, _render(stores / "v.zarr", tmp_path, "--view", "iso"))  # the page's default view
        assert browser.eval(f"{IMG}.naturalWidth") == SIZE and browser.eval(f"{IMG}.src").startswith("blob:")
        assert "bricks L" in browser.eval(f"{HUD}.textContent") and "failed 0" in browser.eval(f"{HUD}.textContent")

        n, moving = _full(browser), browser.eval("window.clipvol.moving")
        x, y = _centre(browser)
        browser.drag((x, y), (x + 30, y + 12), steps=6)
        turned, meta = _full_after(browser, n)
        assert browser.eval("window.clipvol.moving") > moving  # frames while moving came first, at adaptive quality
        assert np.abs(turned.astype(int) - first.astype(int)).max() > 20  # the view turned
        cam = tmp_path / "cam.json"
        cam.write_text(json.dumps(meta["camera"]))
        _same(turned, _render(stores / "v.zarr", tmp_path, "--camera", str(cam)))

        n = _full(browser)
        browser.wheel(x, y, -400)  # zoom in
        zoomed, meta = _full_after(browser, n)
        cam.write_text(json.dumps(meta["camera"]))
        _same(zoomed, _render(stores / "v.zarr", tmp_path, "--camera", str(cam)))
        assert (zoomed[..., 3] > 0).sum() > (turned[..., 3] > 0).sum()  # nearer: the volume covers more
        assert browser.page_errors() == []
    finally:
        _leave(browser)


def test_presets_transfer_function_mode_slice_and_probe(browser, server, stores, tmp_path):
    _open(browser, server.url)
    try:
        n = _full(browser)
        browser.eval("document.querySelector('button[data-view=front]').click()")
        front, _ = _full_after(browser, n)
        _same(front, _render(stores / "v.zarr", tmp_path, "--view", "front"))

        def choose(index: int, value: str) -> None:  # the widget's menus: 0 tf, 1 mode
            browser.eval(f"(() => {{ const s = document.querySelectorAll('#view select')[{index}]; s.value = '{value}'; "
                         f"s.dispatchEvent(new Event('change')); }})()")

        n = _full(browser)
        choose(0, "grey")
        _full_after(browser, n)
        n = _full(browser)
        choose(1, "mip")
        mip, _ = _full_after(browser, n)
        assert np.array_equal(mip[..., 0], mip[..., 1]) and np.array_equal(mip[..., 1], mip[..., 2])  # grey
        _same(mip, _render(stores / "v.zarr", tmp_path, "--view", "front", "--tf", "grey", "--mode", "mip"))

        def type_in(element: str, text: str) -> None:
            browser.eval(f"(() => {{ const i = document.getElementById('{element}'); i.value = '{text}'; "
                         f"i.dispatchEvent(new Event('change')); }})()")

        n = _full(browser)
        browser.eval("document.getElementById('window-low').value = '0.02'")
        type_in("window-high", "0.7")  # its change sends both ends
        windowed, _ = _full_after(browser, n)
        n = _full(browser)
        type_in("crop", "0,0,0,24,48,48")  # x, y, z: the half at low x
        cropped, _ = _full_after(browser, n)
        assert np.abs(cropped.astype(int) - windowed.astype(int)).max() > 20
        _same(cropped, _render(stores / "v.zarr", tmp_path, "--view", "front", "--tf", "grey", "--mode", "mip",
                               "--tf-range", "0.02,0.7", "--crop-voxels", "0:24,0:48,0:48"))
        n = _full(browser)
        type_in("crop", "")
        _full_after(browser, n)

        n = _full(browser)
        browser.eval("(() => { const s = document.getElementById('slice'); s.value = 'axial'; "
                     "s.dispatchEvent(new Event('change')); })()")
        axial, _ = _full_after(browser, n)
        assert "axial slice" in browser.eval(f"{HUD}.textContent")
        assert np.abs(axial.astype(int) - mip.astype(int)).max() > 20
        n = _full(browser)
        browser.eval("(() => { const s = document.getElementById('slice'); s.value = ''; "
                     "s.dispatchEvent(new Event('change')); })()")
        _full_after(browser, n)

        browser.eval("document.getElementById('save-camera').click()")  # the camera file download: no page error
        x, y = _centre(browser)  # a click (no drag): the probe's line on the HUD
        browser.mouse("mouseMoved", x, y)
        browser.mouse("mousePressed", x, y, button="left", buttons=1, clickCount=1)
        browser.mouse("mouseReleased", x, y, button="left", buttons=0, clickCount=1)
        _wait(browser, f"{HUD}.textContent.includes('probe ')", "the probe's line")
        assert browser.page_errors() == []
    finally:
        _leave(browser)


def test_a_broken_store_shows_its_failed_bricks(browser, server):
    _open(browser, server.url + "&store=1")
    try:
        assert "failed" in browser.eval(f"{ALERT}.textContent")  # named on the error line, the frame dimmed
        assert float(browser.eval(f"getComputedStyle({IMG}).opacity")) < 1
        hud = browser.eval(f"{HUD}.textContent")
        failed = int(hud.split("failed ")[1].split()[0])
        assert failed >= 1
    finally:
        _leave(browser)
