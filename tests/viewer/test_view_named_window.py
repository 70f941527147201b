"""``clipvol view scan.nii.gz --view NAME`` under Xvfb: the window opens on the named side of the
patient, head up, whatever the storage order, where ``clipvol render --view NAME`` puts the eye.

The synthetic patient of ``world_volumes`` carries a bright marker at its left-anterior-superior
corner: seen from the patient's left with the head up, anterior is on the image's left, so the
marker is top left; seen from the front it is top right (the patient's left on the viewer's right).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("glfw")
pytest.importorskip("moderngl")
pytest.importorskip("nibabel")

from test_view_window import _converge, xdisplay  # noqa: E402,F401  (the Xvfb fixture)
from world_volumes import write_copy  # noqa: E402

MIP = ("--mode", "mip", "--tf", "grey", "--tf-range", "0,1000")


def _window(tmp_path, monkeypatch, name: str, view: str) -> tuple[np.ndarray, object]:
    """What ``clipvol view COPY --view VIEW`` shows once converged (HUD hidden), and its camera."""
    from clipvol.tools.cli import main
    from clipvol.viewer.window import Viewer

    seen = {}

    def run(self, max_frames=None):  # instead of the event loop: converge, read the screen, close
        self.key("H")
        _converge(self)
        seen["screen"], seen["camera"] = self.read_screen(), self.camera()
        return 0

    monkeypatch.setattr(Viewer, "run", run)
    src = write_copy(tmp_path, name)
    assert main(["view", src, "--store", str(tmp_path / f"{name}.zarr"), "--view", view, "--size", "64x64", *MIP]) == 0
    return seen["screen"], seen["camera"]


def _marker_centre(img: np.ndarray) -> np.ndarray:
    # the marker (1000) is ten times as bright as the body (100): its pixels are the brightest, even
    # where a small window draws a coarser level that blurs it
    lum = img[..., 0]
    assert lum.max() > 100, f"the marker is not in the picture (max {lum.max()})"
    bright = lum > 0.6 * lum.max()
    rows, cols = np.nonzero(bright)
    return np.array([rows.mean(), cols.mean()])


@pytest.mark.parametrize("view, where", [("left", "top left"),
                                         pytest.param("anterior", "top right", marks=pytest.mark.slow)])
def test_view_name_opens_the_window_on_that_side_head_up(xdisplay, tmp_path, monkeypatch, view, where):  # noqa: F811
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.views import preset_camera

    centres = {}
    for name in ("ras", "las"):
        screen, cam = _window(tmp_path, monkeypatch, name, view)
        r, c = centres[name] = _marker_centre(screen.astype(np.float64))
        top, left = where.split()
        assert r < 28, f"{name}: marker at row {r:.1f}, expected the top"
        assert (c < 36) if left == "left" else (c > 28), f"{name}: marker at column {c:.1f}, expected the {left}"
        # the window starts from the camera clipvol render uses for the same name
        loader = ZarrLoader(tmp_path / f"{name}.zarr")
        ref = preset_camera(*loader.pyramid.volume_box(), view, (64, 64), frame=loader.frame)
        np.testing.assert_allclose(cam.forward, ref.forward, atol=1e-6)
        np.testing.assert_allclose(cam.up, ref.up, atol=1e-6)
    np.testing.assert_allclose(centres["las"], centres["ras"], atol=1.5)
