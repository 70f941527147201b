"""clipvol.show: the notebook widget renders the data the right way round, follows its controls.

References: a block placed by hand at +x (it must be on screen right from the front, on the left
after half a turn), the PNG sent to the browser decoded with pillow against the frame kept in
Python, and the grey preset's R == G == B.
"""

from __future__ import annotations

import base64
import io

import numpy as np
import pytest

pytest.importorskip("moderngl")
pytest.importorskip("anywidget")


@pytest.fixture
def view():
    import clipvol

    vol = np.zeros((32, 32, 32), np.float32)
    vol[10:22, 10:22, 24:30] = 1.0  # at high x
    vol[12:20, 12:20, 4:8] = 0.4  # a fainter block at low x
    v = clipvol.show(vol, size=(64, 48), mode="mip", tf="grey", brick=16, threads=2)
    yield v
    v.close()


def _decode(url: str) -> np.ndarray:
    from PIL import Image

    head, _, b64 = url.partition(",")
    assert head == "data:image/png;base64"
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(b64))))


def _bright_x(img):
    lum = img[..., 0].astype(float)
    ys, xs = np.nonzero(lum > 0.9 * lum.max())
    return xs.mean()


def test_show_renders_and_turns(view):
    img = view.snapshot()
    assert img.shape == (48, 64, 4)
    np.testing.assert_array_equal(_decode(view.widget.image), img)  # what the browser gets
    assert _bright_x(img) > 32  # +x on screen right from the front
    rgb = img[..., :3].astype(int)
    assert (rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 1] == rgb[..., 2]).all()  # grey preset
    assert "bricks L" in view.widget.hud and "ms" in view.widget.hud
    view.widget.azimuth = 180.0  # what a drag in the browser sets
    assert _bright_x(view.snapshot()) < 32
    back = view.set_view(azimuth=0.0, zoom=2.0)
    assert (back[..., 3] > 0).mean() > (img[..., 3] > 0).mean()  # zoomed in: more of the image covered


def test_tf_and_mode_from_the_widget(view):
    view.widget.tf = "magma"
    rgb = view.snapshot()[..., :3].astype(int)
    assert (np.abs(rgb[..., 0] - rgb[..., 2]) > 10).any()  # no longer grey
    view.widget.mode = "composite"
    assert view.session.params.mode == "composite"
    view.widget.tf = "no-such-preset"
    assert view.widget.error.startswith("tf: expected one of")  # shown in the view, not raised
    view.widget.tf = "grey"
    assert view.widget.error == ""  # a whole frame clears it


def test_missing_anywidget_names_the_extra(monkeypatch):
    import sys

    from clipvol.app import notebook
    from clipvol.errors import MissingExtraError

    notebook._widget_class.cache_clear()
    monkeypatch.setitem(sys.modules, "anywidget", None)
    try:
        with pytest.raises(MissingExtraError, match=r"clipvol\[notebook\]"):
            notebook._widget_class()
    finally:
        notebook._widget_class.cache_clear()


def test_a_wrong_mode_is_shown_and_a_render_error_raised_and_shown(view, monkeypatch):
    from clipvol.errors import BrickLoadError

    view.widget.mode = "no-such-mode"
    assert view.widget.error.startswith("mode") and "no-such-mode" in view.widget.error
    assert view.session.params.mode == "mip"  # unchanged

    def broken(*args, **kwargs):
        raise BrickLoadError("brick (level 0, 0, 0, 1) of v.zarr: read failed")

    monkeypatch.setattr(view.session, "timed_render", broken)
    with pytest.raises(BrickLoadError, match=r"level 0, 0, 0, 1"):
        view.set_view(azimuth=30.0)  # a Python caller gets the error ...
    assert view.widget.error == "brick (level 0, 0, 0, 1) of v.zarr: read failed"  # ... and the view shows it
    monkeypatch.undo()
    view.set_view(azimuth=0.0)
    assert view.widget.error == ""


def test_failed_bricks_are_striped_and_named(tmp_path):
    import clipvol
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.loaders.zarr_store import ZarrLoader

    vol = np.zeros((32, 32, 32), np.float32)
    vol[8:24, 8:24, 8:24] = 1.0
    root = tmp_path / "v.zarr"
    brick_volume(vol, root, brick=16, progress=False, workers=1, summary=False)
    for p in root.rglob("*"):
        if p.is_file() and "c" in p.relative_to(root).parts:  # every chunk of every level
            p.write_bytes(b"not a chunk")
    with clipvol.show(ZarrLoader(root), size=(64, 48), mode="mip", tf="grey", threads=2, timeout=20) as v:
        assert "failed and nothing stands in for them" in v.widget.error and "brick (level " in v.widget.error
        rgb = v.snapshot()[..., :3].astype(int)
        red = (rgb[..., 0] == 255) & (rgb[..., 1] == 0) & (rgb[..., 2] == 0)
        assert red.mean() > 0.05  # the hole is marked (grey preset: no red from the data)
