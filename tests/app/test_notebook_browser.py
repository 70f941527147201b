"""clipvol.show in a real browser: the widget's JavaScript drives the kernel and shows what it sends.

The widget's own ES module runs in a headless Chromium on a page served from 127.0.0.1
(``tests/browser_harness.py``: the page's ``model`` posts the comm messages a Jupyter front end
sends, and they reach the real widget's comm handler on the test's thread). Pointer and wheel
events and key presses are dispatched by the browser's input layer (DevTools ``Input``), so the
pointer capture, the wheel listener and the ``<select>`` change events are the browser's own.

References: the turntable's geometry (an orbit keeps the camera's distance to its centre, a wheel
zoom shortens it), the PNG the kernel sent decoded with pillow and alpha-composited over the
image's black background by hand against a screenshot of the page, the grey preset's
R == G == B, and the error text the kernel raised.
"""

from __future__ import annotations

import base64
import io
import json

import numpy as np
import pytest
from optional import CHROMIUM, needs

pytest.importorskip("moderngl")
pytestmark = [CHROMIUM, needs("anywidget")]

SIZE = (64, 48)
IMG = "document.querySelector('img')"
HUD = "document.querySelector('pre')"
ALERT = "document.querySelector('[role=alert]')"


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    from browser_harness import Chromium, chromium_binary

    b = Chromium(chromium_binary(), tmp_path_factory.mktemp("chromium-profile"))
    yield b
    b.close()


def _volume():
    vol = np.zeros((32, 32, 32), np.float32)
    vol[10:22, 10:22, 24:30] = 1.0  # at high x
    vol[12:20, 12:20, 4:8] = 0.4  # a fainter block at low x
    vol[2:6, 24:30, 12:20] = 0.7  # and one off the turntable's axis, so a tilt changes the image
    return vol


@pytest.fixture
def shown(browser):
    """A view of a small volume, its page open in the browser with the first frame shown."""
    from browser_harness import WidgetPage

    import clipvol

    v = clipvol.show(_volume(), size=SIZE, mode="mip", tf="grey", brick=16, threads=2)
    page = WidgetPage(v.widget)
    try:
        browser.events.clear()
        browser.page("Page.navigate", url=page.url)
        page.wait(browser, lambda: browser.eval("window.rendered === true") and _shows(browser, v), "the first frame")
        yield v, page
        assert browser.page_errors() == []  # no uncaught exception in the widget's JavaScript
    finally:
        _leave(browser)
        page.close()
        v.close()


def _leave(browser) -> None:
    """Unload the page before its server stops (its polls would fail as page errors of the next test)."""
    browser.page("Page.navigate", url="about:blank")
    browser.events.clear()


def _decode(url: str) -> np.ndarray:
    from PIL import Image

    head, _, b64 = url.partition(",")
    assert head == "data:image/png;base64"
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(b64))).convert("RGBA"))


def _shows(browser, v) -> bool:
    """The page shows the kernel's latest frame and HUD line (decoded: the image has its size)."""
    return (browser.eval(f"{IMG}.src") == v.widget.image and browser.eval(f"{IMG}.complete")
            and browser.eval(f"{IMG}.naturalWidth") == SIZE[0] and browser.eval(f"{HUD}.textContent") == v.widget.hud)


def _centre(browser):
    r = json.loads(browser.eval(f"JSON.stringify({IMG}.getBoundingClientRect())"))
    return r["x"] + r["width"] / 2, r["y"] + r["height"] / 2


def _screen(browser) -> np.ndarray:
    """What the browser paints where the image is (a screenshot, device pixels = CSS pixels)."""
    from PIL import Image

    r = json.loads(browser.eval(f"JSON.stringify({IMG}.getBoundingClientRect())"))
    shot = browser.page("Page.captureScreenshot", format="png",
                        clip={"x": r["x"], "y": r["y"], "width": SIZE[0], "height": SIZE[1], "scale": 1})
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(shot["data"]))).convert("RGB"))


def _over_black(rgba: np.ndarray) -> np.ndarray:
    """A straight-alpha RGBA image composited over black, as the page draws it."""
    a = rgba[..., 3:4].astype(np.float64) / 255.0
    return rgba[..., :3].astype(np.float64) * a


def _orbit(v):
    cam, coi = v.camera()
    pos = np.asarray(cam.position, dtype=np.float64)
    return pos, float(np.linalg.norm(pos - np.asarray(coi, dtype=np.float64)))


def test_the_page_paints_the_kernels_frame(browser, shown):
    v, _ = shown
    np.testing.assert_array_equal(_decode(browser.eval(f"{IMG}.src")), v.snapshot())
    painted = _screen(browser).astype(np.float64)
    assert np.abs(painted - _over_black(v.snapshot())).max() <= 2  # PNG decode + compositing rounding
    assert "bricks L" in browser.eval(f"{HUD}.textContent")
    assert browser.eval(f"getComputedStyle({ALERT}).display") == "none"  # no error, no error line


def test_a_drag_turns_the_camera_and_brings_its_frame(browser, shown):
    v, page = shown
    az0, el0 = v.widget.azimuth, v.widget.elevation
    pos0, dist0 = _orbit(v)
    img0 = v.snapshot()
    x, y = _centre(browser)
    browser.drag((x, y), (x + 40, y))  # horizontal: turns about the up axis only
    page.wait(browser, lambda: v.widget.azimuth != az0 and _shows(browser, v), "a frame after the drag")
    assert page.handled >= 1 and page.kernel_errors == []
    assert -90 < v.widget.azimuth - az0 < 0 and v.widget.elevation == el0
    pos1, dist1 = _orbit(v)
    assert np.linalg.norm(pos1 - pos0) > 0.1 * dist0  # the camera moved ...
    assert dist1 == pytest.approx(dist0, rel=1e-6)  # ... on its orbit
    img1 = v.snapshot()
    assert not np.array_equal(img1, img0)
    np.testing.assert_array_equal(_decode(browser.eval(f"{IMG}.src")), img1)
    assert np.abs(_screen(browser).astype(np.float64) - _over_black(img1)).max() <= 2

    az1 = v.widget.azimuth
    browser.drag((x, y), (x, y + 30))  # vertical: tilts only
    page.wait(browser, lambda: v.widget.elevation != el0 and _shows(browser, v), "a frame after the tilt")
    assert v.widget.elevation > el0 and v.widget.azimuth == az1
    assert not np.array_equal(v.snapshot(), img1)


def test_a_long_drag_sends_what_the_kernel_can_draw_and_ends_where_the_pointer_did(browser, shown):
    v, page = shown
    az0, before = v.widget.azimuth, page.handled
    x, y = _centre(browser)
    browser.drag((x, y), (x + 40, y), steps=20)  # 20 moves while the kernel handles nothing
    page.wait(browser, lambda: v.widget.azimuth != az0 and _shows(browser, v), "a frame after the drag")
    assert page.handled - before < 5  # not one frame per pointer move: the backlog a drag would queue
    short = v.widget.azimuth
    browser.drag((x, y), (x - 40, y), steps=1)  # the same distance back in one move
    page.wait(browser, lambda: v.widget.azimuth != short and _shows(browser, v), "a frame after the drag back")
    assert v.widget.azimuth == pytest.approx(az0)  # the long drag's last move was not lost


def test_the_wheel_zooms(browser, shown):
    v, page = shown
    _, dist0 = _orbit(v)
    covered0 = (v.snapshot()[..., 3] > 0).mean()
    x, y = _centre(browser)
    browser.wheel(x, y, -400)  # wheel up: in
    page.wait(browser, lambda: v.widget.zoom > 1 and _shows(browser, v), "a frame after the wheel")
    _, dist1 = _orbit(v)
    assert dist1 < dist0 / 1.2
    assert (v.snapshot()[..., 3] > 0).mean() > covered0  # the volume covers more of the image
    browser.wheel(x, y, 800)  # wheel down: out, past where it started
    page.wait(browser, lambda: v.widget.zoom < 1 and _shows(browser, v), "a frame after the wheel back")
    assert _orbit(v)[1] > dist0


def test_the_menus_change_the_transfer_function_and_mode(browser, shown):
    v, page = shown
    rgb = v.snapshot()[..., :3].astype(int)
    assert (rgb[..., 0] == rgb[..., 2]).all()  # grey to start with
    names = list(v.widget.tf_names)
    browser.eval("document.querySelectorAll('select')[0].focus()")
    browser.key("ArrowDown", 40)  # a closed <select> steps to the next option and fires change
    want = names[names.index("grey") + 1]
    page.wait(browser, lambda: v.widget.tf == want and _shows(browser, v), f"the {want} preset's frame")
    assert browser.eval("document.querySelectorAll('select')[0].value") == want
    rgb = v.snapshot()[..., :3].astype(int)
    assert (np.abs(rgb[..., 0] - rgb[..., 2]) > 10).any()  # no longer grey
    assert np.abs(_screen(browser).astype(np.float64) - _over_black(v.snapshot())).max() <= 2

    browser.eval("document.querySelectorAll('select')[1].focus()")
    browser.key("ArrowUp", 38)  # mip -> composite
    page.wait(browser, lambda: v.widget.mode == "composite" and _shows(browser, v), "the composite frame")
    assert v.session.params.mode == "composite"


def test_a_kernel_error_shows_in_the_view_until_a_frame_is_whole(browser, shown, monkeypatch):
    from clipvol.errors import BrickLoadError

    v, page = shown
    msg = "brick (level 0, 0, 1, 1) of scan.zarr: read failed: Input/output error"

    def broken(*args, **kwargs):
        raise BrickLoadError(msg)

    monkeypatch.setattr(v.session, "timed_render", broken)
    x, y = _centre(browser)
    browser.drag((x, y), (x + 20, y), steps=1)
    page.wait(browser, lambda: bool(page.kernel_errors) and browser.eval(f"{ALERT}.textContent") != "",
              "the error line")
    assert isinstance(page.kernel_errors[0], BrickLoadError)  # raised on in the kernel, too
    assert browser.eval(f"{ALERT}.textContent") == f"error: {msg}"
    assert browser.eval(f"getComputedStyle({ALERT}).display") == "block"
    assert browser.eval(f"{ALERT}.getBoundingClientRect().height") > 0  # laid out, not zero-sized
    assert float(browser.eval(f"getComputedStyle({IMG}).opacity")) < 1  # the stale frame is dimmed

    monkeypatch.undo()
    page.kernel_errors.clear()
    browser.drag((x, y), (x + 20, y), steps=1)
    page.wait(browser, lambda: browser.eval(f"getComputedStyle({ALERT}).display") == "none" and _shows(browser, v),
              "the error line to clear")
    assert page.kernel_errors == []
    assert float(browser.eval(f"getComputedStyle({IMG}).opacity")) == 1


def test_a_frame_the_page_cannot_decode_is_not_shown_as_if_right(browser, shown):
    v, page = shown
    v.widget.image = "data:image/png;base64,AAAA"  # not a PNG
    page.wait(browser, lambda: browser.eval(f"{ALERT}.textContent") != "", "the decode error line")
    assert "could not be decoded" in browser.eval(f"{ALERT}.textContent")
    assert float(browser.eval(f"getComputedStyle({IMG}).opacity")) < 1
    v.render()
    page.wait(browser, lambda: browser.eval(f"getComputedStyle({ALERT}).display") == "none" and _shows(browser, v),
              "the next frame")
    assert float(browser.eval(f"getComputedStyle({IMG}).opacity")) == 1


def test_failed_bricks_with_nothing_in_their_place_are_named_in_the_view(browser, tmp_path):
    from browser_harness import WidgetPage
    from clipvol.loaders.zarr_store import ZarrLoader

    import clipvol
    from clipvol.bricking.pipeline import brick_volume

    root = tmp_path / "v.zarr"
    brick_volume(_volume(), root, brick=16, progress=False, workers=1, summary=False)
    chunks = [p for p in root.rglob("*") if p.is_file() and "c" in p.relative_to(root).parts]
    assert chunks
    for p in chunks:  # every brick of every level: nothing can stand in
        p.write_bytes(b"not a chunk")
    v = clipvol.show(ZarrLoader(root), size=SIZE, mode="mip", tf="grey", threads=2, timeout=20)
    page = WidgetPage(v.widget)
    try:
        browser.events.clear()
        browser.page("Page.navigate", url=page.url)
        page.wait(browser, lambda: browser.eval("window.rendered === true") and _shows(browser, v), "the first frame")
        text = browser.eval(f"{ALERT}.textContent")
        assert text.startswith("error: ") and "failed and nothing stands in for them" in text
        assert "brick (level " in text
        assert browser.eval(f"getComputedStyle({ALERT}).display") == "block"
        assert float(browser.eval(f"getComputedStyle({IMG}).opacity")) < 1
        assert browser.page_errors() == []
    finally:
        _leave(browser)
        page.close()
        v.close()
