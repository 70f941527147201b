"""The server's slices are cut by the view's crop box as its volume is.

``clipvol serve`` drew a view's slice whole after the page had cropped the volume: the crop box
cut the ray cast but not the plane, so the slice showed data the user had cut away. The render
worker is driven directly (its own thread and EGL context, as in the server); the reference is
the geometry of the fitted view, stated here: a 40³ store of unit spacing, an axial plane fitted
into a 64² view, each column ``i`` at world x = 20 + (i + 0.5 - 32) · 40 / 64.
"""

from __future__ import annotations

import io
import queue

import numpy as np
import pytest

pytest.importorskip("moderngl")
pytestmark = pytest.mark.gl

N, SIZE = 40, 64


@pytest.fixture(scope="module")
def slices():
    """``slices(changes)``: the converged RGBA of a new view with ``changes`` applied to its state."""
    from PIL import Image

    from clipvol.app.serve.state import ViewState
    from clipvol.app.serve.worker import RenderWorker
    from clipvol.app.session import open_loader

    frames: queue.Queue = queue.Queue()
    worker = RenderWorker([open_loader(f"procedural:fractal?size={N}")], ["fractal"], threads=2, timeout=30,
                          deliver=lambda vid, msg, data: frames.put((vid, msg, data)) if msg["method"] == "frame" else None)
    worker.start()
    views = iter(range(1000))

    def draw(changes: dict) -> np.ndarray:
        state = ViewState(("iso",), ("auto",), (N, N, N))
        state.apply(changes)
        vid = next(views)
        worker.open_view(vid, 0, (SIZE, SIZE), state)
        while True:
            got, msg, data = frames.get(timeout=60)
            if got == vid and msg["full"]:
                assert msg["converged"] and not msg["error"], msg
                return np.asarray(Image.open(io.BytesIO(data)).convert("RGBA"))

    try:
        yield draw
    finally:
        worker.close()


def test_a_crop_box_cuts_the_slice_as_it_cuts_the_volume(slices):
    plane = {"slice": "axial", "slice_index": N // 2}
    whole = slices(plane)
    assert (whole[..., 3] == 255).all()  # the plane meets the volume everywhere in the view
    half = slices({**plane, "crop_voxels": [0, 0, 0, N // 2, N, N]})  # x below 20 kept
    x = N / 2 + (np.arange(SIZE) + 0.5 - SIZE / 2) * N / SIZE  # world x of each column's centre
    kept, cut = x < N / 2, x > N / 2
    assert (half[:, cut, 3] == 0).all()  # cut away: nothing drawn
    np.testing.assert_array_equal(half[:, kept], whole[:, kept])  # kept: the slice as drawn whole
    beside = slices({**plane, "crop_voxels": [0, 0, N // 2 + 4, N, N, N]})  # the box lies off the plane
    assert (beside[..., 3] == 0).all()
