"""Viewer keys of image-based level of detail: L switches the policy, < > change the block budget,
the HUD shows budget and estimated error, and a store without tables falls back with a message."""

from __future__ import annotations

import numpy as np

from clipvol.viewer.controls import MODES, ViewState
from test_view_window import xdisplay  # noqa: F401  (the Xvfb fixture, shared)


def test_keys_switch_policy_and_budget():
    st = ViewState(num_levels=4)
    assert st.handle_key("G") and st.mode == "image"
    assert st.handle_key(">") and st.block_budget == 256
    assert st.handle_key("<") and st.handle_key("<") and st.block_budget == 64
    assert "64" in st.message
    assert st.handle_key("G") and st.mode == "projected-size"
    assert st.handle_key(".") and st.mode == "image" and st.block_budget == 128
    assert st.handle_key("M") and st.mode == MODES[0]
    for _ in range(20):
        st.handle_key("<")
    assert st.block_budget == 1


def test_window_image_policy_and_hud(xdisplay, tmp_path):
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.open import open_store
    from clipvol.viewer.window import Viewer

    path = tmp_path / "h.zarr"
    brick_volume(ct_head((32, 32, 32)), path, brick=8, progress=False)
    with Viewer(open_store(path), size=(64, 64), visible=False) as v:
        v.key("G")
        v.key("<")
        v.step()
        assert v.session.params.policy == "image" and v.session.params.block_budget == 64
        assert v.session.frame_stats.bricks_distinct <= 64
        v._draw_hud(64, 64)
        text = " ".join(v._hud_text)
        assert "64 blocks" in text and "est.err" in text
    bare = tmp_path / "bare.zarr"
    brick_volume(ct_head((32, 32, 32)), bare, brick=8, progress=False, summary=False)
    with Viewer(open_store(bare), size=(64, 64), visible=False) as v:
        v.key("G")
        v.step()  # falls back instead of failing
        assert v.session.params.policy != "image" and "clipvol summarize" in v.state.message
        assert np.asarray(v.read_screen()).size


def test_window_keeps_the_error_budget_for_the_image_policy_only(xdisplay, tmp_path):
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.open import open_store
    from clipvol.scene.params import RenderParams
    from clipvol.viewer.window import Viewer

    path = tmp_path / "h.zarr"
    brick_volume(ct_head((32, 32, 32)), path, brick=8, progress=False)
    params = RenderParams(policy="image", max_error="5%", jitter=True)
    with Viewer(open_store(path), size=(64, 64), visible=False, params=params) as v:
        v.step()
        assert v.session.params.policy == "image" and v.session.params.max_error == 0.05
        v._draw_hud(64, 64)
        assert "max.err" in " ".join(v._hud_text)
        v.key("G")  # to the projected-size policy: no error budget (it would be refused there)
        v.step()
        assert v.session.params.policy != "image" and v.session.params.max_error is None
        v.key("G")
        v.step()
        assert v.session.params.policy == "image" and v.session.params.max_error == 0.05
