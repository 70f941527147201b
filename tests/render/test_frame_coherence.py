"""Frames drawn through the kept cut (clipvol.render.frame_loop, "Coherence") are the frames a fresh
action draws from nothing: an orbit, a transfer-function change, a brick arriving mid-sequence and a
crop-box change, each frame compared bit for bit with a new action (its own GPU cache, no kept
state) rendering the same camera, parameters and residency."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.paging.open import open_store
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.geometry import Shape
from clipvol.scene.transfer import TransferFunction

from counting_loader import ReadThrough

pytestmark = pytest.mark.gl

#: bricks held back until the test lets them load: one of the level-0 cut, one of level 1 (not in it)
GATED = ((0, (1, 2, 2)), (1, (1, 1, 2)))


class GatedLoader(ReadThrough):
    """A store's loader whose bricks :data:`GATED` are read only once their ``gates`` are set."""

    def __init__(self, inner, gates: dict) -> None:
        super().__init__(inner)
        self.gates = gates

    def read_brick(self, level, index):
        gate = self.gates.get((int(level), tuple(int(v) for v in index)))
        if gate is not None:
            gate.wait(30)
        return self._inner.read_brick(level, index)


def blob(n: int = 48) -> np.ndarray:
    """A bright ellipsoid with texture in air of zero: transparent corners the frustum sweeps over."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float32)
    c = (n - 1) / 2.0
    r2 = ((x - c) / 20.0) ** 2 + ((y - c) / 17.0) ** 2 + ((z - c) / 15.0) ** 2
    v = np.where(r2 < 1.0, 0.5 + 0.4 * np.sin(x / 3.0) * np.cos(y / 4.0) + 0.1 * (z / n), 0.0)
    return v.astype(np.float32)


def orbit(deg: float, pyr, size: int = 48, dist: float = 1.15) -> Camera:
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    th = np.radians(deg)
    d = np.array([np.sin(th) * 0.7, 0.45, np.cos(th) * 0.7])
    d /= np.linalg.norm(d)
    return Camera.perspective(tuple(c - d * dist * float(np.linalg.norm(hi - lo))), tuple(c), up=(0, -1, 0),
                              fov_y=35, size=(size, size))


@pytest.mark.slow_paths("bricks")  # (6 s a path; the per-brick path's kept cut also below, slow)
def test_kept_cut_frames_equal_fresh_frames(ctx, draw_path, tmp_path):
    gates = {k: threading.Event() for k in GATED}
    brick_volume(blob(), tmp_path / "blob.zarr", brick=8, progress=False, workers=1)
    loader = GatedLoader(open_store(tmp_path / "blob.zarr"), gates)  # with brick ranges: transparency culls
    clip = ClipTexture(loader, "64MB", threads=2)
    tf1 = TransferFunction.from_points([(0.0, (0, 0, 0, 0.0)), (0.2, (0, 0, 0, 0.0)), (0.6, (1, 0.6, 0.2, 0.3)),
                                        (1.0, (1, 1, 1, 0.8))])
    tf2 = TransferFunction.from_points([(0.0, (0, 0, 0, 0.0)), (0.45, (0, 0, 0, 0.0)), (0.7, (0.2, 0.5, 1, 0.5)),
                                        (1.0, (1, 1, 1, 1.0))])
    a = ClipRenderAction(ctx, clip, policy="fixed", level=0, path=draw_path)
    pyr = a.pyramid
    made = [a]

    def fresh(cam, tf, wait: bool, wait_s: float):
        b = ClipRenderAction(ctx, clip, a.params)
        made.append(b)
        img = b.render(cam, tf, wait=wait, timeout=wait_s)
        b.close()
        return img

    try:
        replayed = []

        def frame(deg, tf, wait: bool = False, wait_s: float = 30.0):
            cam = orbit(deg, pyr)
            img = a.render(cam, tf, wait=wait, timeout=wait_s)
            replayed.append(a.last_frame_stats.replayed)
            ref = fresh(cam, tf, wait, wait_s)
            assert np.array_equal(img, ref), f"frame at {deg} deg differs from a fresh action's"
            assert img[..., 3].any()
            return img

        frame(0, tf1, wait=True, wait_s=1.0)  # the gated brick never comes: a fallback cut, not kept
        assert not a.last_frame_stats.converged
        frame(1, tf1)
        gates[GATED[0]].set()  # the cut's brick arrives mid-sequence
        # every brick but the held-back level-1 one in RAM: no arrival but that one from here on
        others = [(L, tuple(int(v) for v in b)) for L in range(pyr.num_levels)
                  for b in np.argwhere(np.ones(pyr.grid(L), dtype=bool))]
        assert clip.wait_for([k for k in others if k != GATED[1]], timeout=30)
        frame(2, tf1, wait=True)
        assert a.last_frame_stats.converged
        for deg in (3, 4, 4, 6):  # an orbit, a static camera
            frame(deg, tf1)
        gates[GATED[1]].set()  # a brick arrives while the cut is kept: the next frame selects again
        assert clip.wait_until_idle(30)
        frame(7, tf1)
        frame(8, tf1)
        frame(9, tf2)  # a new table: a new cut (other bricks are transparent)
        frame(10, tf2)
        lo, hi = pyr.volume_box()
        crop = Shape(box=(tuple(lo), tuple(lo + (hi - lo) * np.array([0.8, 0.7, 1.0]))))
        a.set_params(dataclasses.replace(a.params, shape=crop))  # a crop box: a new cut
        frame(11, tf2, wait=True)
        frame(12, tf2)
        # the cut was drawn again exactly where nothing but the camera changed since a converged frame
        assert replayed == [False, False, False, True, True, True, True, False, True, False, True, False, True]
    finally:
        for x in made:
            x.close()
        for g in gates.values():
            g.set()
        clip.close()


def test_page_table_texture_takes_changed_rows_only(ctx):
    """The page-table texture after a sub-write of the changed rows holds the new table, read back
    from the GL and compared with the numpy array it was given; unchanged tables write nothing."""
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.render.paths.single_pass import PAGE_TABLE_WIDTH, SinglePassPath

    clip = ClipTexture(NumpyLoader(blob(16), brick=8), "16MB", threads=1)
    a = ClipRenderAction(ctx, clip, policy="fixed", level=0, path="single-pass")
    try:
        path = SinglePassPath(a.setup)  # a path is made with the shared set-up alone
        rng = np.random.default_rng(1)
        first = rng.integers(0, 2**32 - 1, size=5 * PAGE_TABLE_WIDTH - 100, dtype=np.uint64).astype(np.uint32)
        path._page_table_texture(first)
        assert path.rows_written == 5
        second = first.copy()
        second[2 * PAGE_TABLE_WIDTH + 7] ^= 0xFFFF  # one entry of row 2 and one of row 3
        second[3 * PAGE_TABLE_WIDTH + 1000] += 1
        tex = path._page_table_texture(second)
        assert path.rows_written == 2
        held = np.frombuffer(tex.read(), dtype=np.uint32)[:len(second)]
        np.testing.assert_array_equal(held, second)
        path._page_table_texture(second)
        assert path.rows_written == 0
        path.release()
    finally:
        a.close()
        clip.close()


def test_page_table_texture_takes_the_updated_entries_only(ctx):
    """An updated table's changed entries (:func:`clipvol.scene.page_table.update_page_table`) are
    written as rectangles of their rows: the texture read back from the GL holds the new table,
    entry for entry, and only the rows holding a change were written; where the texture does not
    hold the table the update started from, the rows are compared instead."""
    from types import SimpleNamespace

    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.render.paths.single_pass import PAGE_TABLE_WIDTH, SinglePassPath

    clip = ClipTexture(NumpyLoader(blob(16), brick=8), "16MB", threads=1)
    a = ClipRenderAction(ctx, clip, policy="fixed", level=0, path="single-pass")
    try:
        path = SinglePassPath(a.setup)
        rng = np.random.default_rng(3)
        n = 6 * PAGE_TABLE_WIDTH - 50
        first = SimpleNamespace(entries=rng.integers(0, 2**32 - 1, size=n, dtype=np.uint64).astype(np.uint32))
        path._upload(first)
        assert path.rows_written == 6
        entries = first.entries.copy()
        changed = np.sort(rng.choice(np.r_[PAGE_TABLE_WIDTH:3 * PAGE_TABLE_WIDTH, 5 * PAGE_TABLE_WIDTH:n], 40,
                                     replace=False))
        entries[changed] ^= 0x5A5A
        second = SimpleNamespace(entries=entries)
        tex = path._upload(second, changed, first)
        assert path.rows_written == 3  # rows 1-2 and 5, no compare of the table
        np.testing.assert_array_equal(np.frombuffer(tex.read(), dtype=np.uint32)[:n], second.entries)
        third = SimpleNamespace(entries=entries.copy())
        third.entries[[7, 4 * PAGE_TABLE_WIDTH + 3]] += 1
        path._upload(third, np.array([7, 4 * PAGE_TABLE_WIDTH + 3]), first)  # (it holds second, not first)
        assert path.rows_written == 5  # the band of rows 0-4, found by comparing
        np.testing.assert_array_equal(np.frombuffer(tex.read(), dtype=np.uint32)[:n], third.entries)
        path.release()
    finally:
        a.close()
        clip.close()


@pytest.mark.parametrize("path", ["single-pass", pytest.param("bricks", marks=pytest.mark.slow)])
def test_updated_projected_size_frames_equal_fresh_frames(ctx, path, tmp_path):
    """A projected-size cut kept and updated per camera (clipvol.scene.selection.kept_cut): every
    frame of an orbit and a fly-in equals a new action's frame from nothing, bit for bit, and the
    cut did change along the way (so the update, not a replay, drew it)."""
    brick_volume(blob(), tmp_path / "blob.zarr", brick=8, progress=False, workers=1)
    clip = ClipTexture(open_store(tmp_path / "blob.zarr"), "64MB", threads=2)
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0.0)), (0.2, (0, 0, 0, 0.0)), (0.6, (1, 0.6, 0.2, 0.3)),
                                       (1.0, (1, 1, 1, 0.8))])
    a = ClipRenderAction(ctx, clip, policy="projected-size", lod_threshold=1.5, path=path)
    pyr = a.pyramid
    made = [a]
    try:
        every = [(L, tuple(int(v) for v in b)) for L in range(pyr.num_levels)
                 for b in np.argwhere(np.ones(pyr.grid(L), dtype=bool))]
        assert clip.wait_for(every, timeout=30)
        updated, cuts = [], []
        for k, (deg, dist) in enumerate([(0, 1.15), (1, 1.15), (2, 1.15), (3, 1.1), (4, 1.0), (5, 0.9), (6, 0.9),
                                         (6, 0.9), (40, 1.2)]):
            cam = orbit(deg, pyr, dist=dist)
            img = a.render(cam, tf, wait=k == 0, timeout=30)
            sel = a.last_selection
            updated.append(a.last_frame_stats.updated or a.last_frame_stats.replayed)
            cuts.append(sorted(map(tuple, sel.item_keys().tolist())))
            b = ClipRenderAction(ctx, clip, a.params)
            made.append(b)
            ref = b.render(cam, tf, wait=True, timeout=30)
            assert np.array_equal(img, ref), f"frame {k} ({deg} deg, {dist}) differs from a fresh action's"
            assert img[..., 3].any()
            fresh_keys = b.last_selection.item_keys().tolist()
            assert sorted(map(tuple, sel.item_keys().tolist())) == sorted(map(tuple, fresh_keys))
            # the frame's statistics of its cut (kept from the frame before where its items are the
            # same object) are this cut's: counted here row by row
            st, rows = a.last_frame_stats, sel.item_keys().tolist()
            per: dict = {}
            for r in rows:
                per[r[0]] = per.get(r[0], 0) + 1
            assert st.bricks_drawn == per and st.items_drawn == len(rows)
            assert st.bricks_distinct == len(set(map(tuple, rows)))
        # the first frame selects from nothing; a frame whose cut needs a brick not yet on the GPU
        # does too (it uploads); the others update the kept cut, and some of those changed it
        assert updated[0] is False and sum(updated) >= 4, updated
        assert any(updated[k] and cuts[k] != cuts[k - 1] for k in range(1, len(cuts))), updated
    finally:
        for x in made:
            x.close()
        clip.close()


@pytest.mark.slow
def test_frames_through_a_page_table_updated_in_place_equal_fresh_frames(ctx, tmp_path):
    """A kept projected-size cut whose leaves change while every level's box holds: the single
    pass updates its page table from the frame before's (only the changed entries written to the
    texture), and every frame equals a new action's frame from nothing, bit for bit."""
    brick_volume(blob(64), tmp_path / "blob.zarr", brick=8, progress=False, workers=1)
    clip = ClipTexture(open_store(tmp_path / "blob.zarr"), "64MB", threads=2)
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0.0)), (0.2, (0, 0, 0, 0.0)), (0.6, (1, 0.6, 0.2, 0.3)),
                                       (1.0, (1, 1, 1, 0.8))])
    a = ClipRenderAction(ctx, clip, policy="projected-size", lod_threshold=2.0, path="single-pass")
    pyr = a.pyramid
    made = [a]
    try:
        every = [(L, tuple(int(v) for v in b)) for L in range(pyr.num_levels)
                 for b in np.argwhere(np.ones(pyr.grid(L), dtype=bool))]
        assert clip.wait_for(every, timeout=30)
        for k in range(3, 9):
            cam = orbit(3 * k, pyr, dist=1.0 - 0.01 * k)
            img = a.render(cam, tf, wait=k == 3, timeout=30)
            b = ClipRenderAction(ctx, clip, a.params)
            made.append(b)
            ref = b.render(cam, tf, wait=True, timeout=30)
            assert np.array_equal(img, ref), f"frame {k} differs from a fresh action's"
            assert img[..., 3].any()
        assert a._path("single-pass").tables_updated >= 1
    finally:
        for x in made:
            x.close()
        clip.close()


def test_a_still_camera_costs_a_redraw(ctx, tmp_path):
    """A camera equal to the last one (a new object, as a viewer or a script makes one per frame):
    the frame re-tests no node of the kept cut, asks the merge nothing again and draws the same
    merged boxes through the same page table - and its image is a fresh action's, bit for bit."""
    brick_volume(blob(), tmp_path / "blob.zarr", brick=8, progress=False, workers=1)
    clip = ClipTexture(open_store(tmp_path / "blob.zarr"), "64MB", threads=2)
    tf = TransferFunction.preset("bone", value_range=(0.0, 1.0))
    a = ClipRenderAction(ctx, clip, policy="projected-size", lod_threshold=1.5, path="single-pass")
    made = [a]
    try:
        a.render(orbit(0, a.pyramid), tf, wait=True, timeout=30)
        a.render(orbit(1, a.pyramid), tf)  # an updated frame: the kept cut holds from here on
        assert a.last_frame_stats.updated or a.last_frame_stats.replayed
        first = a.render(orbit(2, a.pyramid), tf)
        cut, merged = a.frame_loop._cut[1], a._merged_kept[2]
        table = a._path("single-pass")._table[2]
        asked = []
        hold = a._kept_merge.answers_hold
        a._kept_merge.answers_hold = lambda *args: asked.append(args) or hold(*args)  # the merge's questions
        again = a.render(orbit(2, a.pyramid), tf)
        assert cut.retested == 0 and not asked
        assert a._merged_kept[2] is merged and a._path("single-pass")._table[2] is table
        assert a._path("single-pass").rows_written == 0
        b = ClipRenderAction(ctx, clip, a.params)
        made.append(b)
        ref = b.render(orbit(2, a.pyramid), tf, wait=True, timeout=30)
        assert np.array_equal(again, first) and np.array_equal(again, ref)
        assert again[..., 3].any()
    finally:
        for x in made:
            x.close()
        clip.close()


def test_the_camera_free_samples_bound_holds_for_every_camera(ctx, tmp_path):
    """The action checks a merged cut's rays against ``MAX_STEPS_PER_BOX`` with a bound that does
    not depend on the camera (a box's diagonal over the step: kept while the boxes are the same):
    it is never below the camera's own estimate (``samples_per_box`` over its rays), so it decides
    as that does wherever it passes."""
    from clipvol.render.paths.setup import samples_per_box

    brick_volume(blob(), tmp_path / "blob.zarr", brick=8, progress=False, workers=1)
    clip = ClipTexture(open_store(tmp_path / "blob.zarr"), "64MB", threads=2)
    tf = TransferFunction.preset("bone", value_range=(0.0, 1.0))
    a = ClipRenderAction(ctx, clip, policy="projected-size", lod_threshold=1.5, step=0.5)
    try:
        for deg, dist in ((0, 1.15), (50, 0.6), (170, 0.3), (250, 2.0)):
            cam = a._selection_camera(orbit(deg, a.pyramid, dist=dist))
            a.render(orbit(deg, a.pyramid, dist=dist), tf, wait=True, timeout=30)
            merged = a._merged_kept[2]
            bound = a._samples(cam, merged)
            assert bound >= samples_per_box(cam, merged, a.pyramid, a.params.step) > 0
            assert a._samples(a._selection_camera(orbit(deg + 90, a.pyramid)), merged) == bound  # (any camera)
    finally:
        a.close()
        clip.close()
