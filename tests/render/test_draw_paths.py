"""The draw-path registry (clipvol.render.paths): a path registered there is the one
``RenderParams.path`` selects - the registry is the only place a new path is named - a path that
declines a cut hands it to the per-brick path, a registered path is run by every test that holds
for all paths (those taking ``draw_path``), and a path is handed a frame context through which it
cannot reach the action.

The test paths draw through the shared set-up (target, read-back); their images are checked
against values computed here (8-bit rounding of a constant colour) and against the per-brick
path's or the single pass's own image of the same cut.
"""

from __future__ import annotations

import ast
import gc
import inspect
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from clipvol.loaders.numpy_array import NumpyLoader
from render_helpers import every_draw_path
from toy_draw_path import ReversedCutPath

from clipvol.errors import ParameterError
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render import paths
from clipvol.render.paths import DrawPath, FrameContext
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

COLOUR = (0.2, 0.4, 0.6, 1.0)  # premultiplied, opaque
TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (1.0, (1, 0, 0, 0.4))])


class FlatPath(DrawPath):
    """Fills the image with one opaque colour; records the cut it was handed."""

    name = "test-flat"

    def __init__(self, setup) -> None:
        super().__init__(setup)
        self.cuts: list[int] = []

    def draw(self, frame):
        self.cuts.append(len(frame.items))
        _fbo, previous, t0 = self.setup.begin(frame, COLOUR)
        return self.setup.read_back(frame, previous, True, t0, boxes_drawn=7)


class DecliningPath(DrawPath):
    """Declines every cut (as the single pass does for a cut its page table cannot hold)."""

    name = "test-declines"

    def draw(self, frame):
        return None


@pytest.fixture
def registered():
    added = []

    def register(cls):
        paths.register(cls)
        added.append(cls.name)

    yield register
    for name in added:
        paths.unregister(name)


@pytest.fixture
def action(ctx):
    z, y, x = np.mgrid[0:16, 0:16, 0:16].astype(np.float32)
    clip = ClipTexture(NumpyLoader((x + y + z) / 45.0, brick=8), "16MB", threads=1)
    made = []

    def make(**kw):
        from clipvol.render.action import ClipRenderAction

        a = ClipRenderAction(ctx, clip, policy="fixed", level=0, **kw)
        made.append(a)
        return a

    yield make
    for a in made:
        a.close()
    clip.close()
    assert ctx.error == "GL_NO_ERROR"


def camera():
    return Camera.perspective((30.0, 25.0, -30.0), (7.5, 7.5, 7.5), size=(32, 24), fov_y=40)


def test_a_registered_path_is_the_one_render_params_path_selects(registered, action):
    with pytest.raises(ParameterError, match="test-flat"):
        RenderParams(path="test-flat")  # not a path before it is registered
    registered(FlatPath)
    a = action(path="test-flat")
    img = a.render(camera(), TF, wait=True, timeout=20)
    assert a.path_drawn == "test-flat"
    flat = a._paths["test-flat"]
    assert flat.cuts and flat.cuts[-1] >= 1  # it was handed the frame's cut
    expected = np.rint(np.array(COLOUR) * 255.0).astype(np.uint8)
    assert img.shape == (24, 32, 4)
    assert (img == expected).all()
    assert a.last_frame_stats.bricks_distinct == 8  # the frame's bookkeeping is the action's, not the path's
    # what the path drew is what it returned, folded by the action
    assert a.boxes_drawn == a.last_frame_stats.boxes_drawn == 7 and a.last_frame_stats.path == "test-flat"


def test_a_declined_cut_is_drawn_by_the_per_brick_path(registered, action):
    registered(DecliningPath)
    declines = action(path="test-declines")
    bricks = action(path="bricks")
    img = declines.render(camera(), TF, wait=True, timeout=20)
    assert declines.path_drawn == "bricks"
    ref = bricks.render(camera(), TF, wait=True, timeout=20)
    assert (img[..., 3] > 0).mean() > 0.2  # the volume is on the image
    assert np.array_equal(img, ref)


def test_unregistered_and_reserved_names_are_refused(registered):
    registered(FlatPath)
    assert RenderParams(path="test-flat").path == "test-flat"
    paths.unregister("test-flat")
    with pytest.raises(ParameterError, match="path: expected one of"):
        RenderParams(path="test-flat")

    class Auto(DrawPath):
        name = "auto"

    with pytest.raises(ParameterError, match="Auto"):
        paths.register(Auto)
    assert paths.DRAW_PATHS["bricks"] is paths.bricks.BricksPath  # the built-ins stay
    assert RenderParams(path="bricks").path == "bricks"


@pytest.mark.parametrize("kw", [*(dict(path=p) for p in every_draw_path()), dict(path="bricks", merge_boxes=False),
                                dict(path="bricks", refine_tolerance=0.1), dict(path="test-flat")])
def test_a_step_whose_rays_would_be_cut_short_is_refused_for_every_path(registered, action, kw):
    """The volume is 16 voxels a side (spacing 1): a ray's path through any box is at least a
    little and at most 16 * sqrt(3) voxels, so at step 1e-4 some ray needs far more than the
    loop's 65 536 samples in one box and at step 1e-3 none needs more than about 28 000. The
    action refuses the first, naming ``step``, whichever path draws (a registered one too) and
    however the frame is drawn; the second draws."""
    registered(FlatPath)
    assert 16 / 1e-4 > 65536 and 16 * np.sqrt(3) / 1e-3 * 1.1 < 65536
    with pytest.raises(ParameterError, match="step"):
        action(step=1e-4, **kw).render(camera(), TF, wait=True, timeout=20)
    img = action(step=1e-3, **kw).render(camera(), TF, wait=True, timeout=20)
    assert img.shape == (24, 32, 4)


def test_a_registered_path_is_run_by_the_every_path_tests_until_unregistered(registered, action):
    """The toy path (the single pass's code handed the cut reversed, tests/toy_draw_path.py) joins
    the names the ``draw_path`` tests are parametrised over when it is registered, draws what the
    single pass draws bit for bit, and leaves both when it is unregistered."""
    assert ReversedCutPath.name not in every_draw_path()
    registered(ReversedCutPath)
    assert every_draw_path()[-1] == ReversedCutPath.name
    toy, single = action(path=ReversedCutPath.name), action(path="single-pass")
    img = toy.render(camera(), TF, wait=True, timeout=20)
    assert toy.path_drawn == ReversedCutPath.name and toy.last_frame_stats.page_table_nodes >= 1
    assert (img[..., 3] > 0).mean() > 0.2
    assert np.array_equal(img, single.render(camera(), TF, wait=True, timeout=20))
    paths.unregister(ReversedCutPath.name)
    assert ReversedCutPath.name not in every_draw_path()
    with pytest.raises(ParameterError, match="path: expected one of"):
        RenderParams(path=ReversedCutPath.name)


@pytest.mark.slow
def test_the_every_path_tests_collect_and_pass_a_path_registered_by_a_plugin():
    """Run a few files of every-path tests in a fresh pytest with the toy path registered before
    collection (``-p toy_draw_path``): each of their tests runs for it too, and passes."""
    tests = Path(__file__).resolve().parents[1]
    files = [str(tests / "render" / f) for f in ("test_edge_voxels.py", "test_nan_sampling.py", "test_modes.py")]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tests), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "toy_draw_path", "-p", "no:cacheprovider",
                          "-k", ReversedCutPath.name, *files], capture_output=True, text=True, env=env, timeout=600,
                         cwd=tests.parent)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    summary = out.stdout.strip().splitlines()[-1]
    passed = int(summary.split(" passed")[0].split()[-1])
    assert passed >= 10 and "failed" not in summary and "skipped" not in summary, summary


def _reachable(roots, target, limit: int = 2_000_000) -> bool:
    """Is ``target`` reachable from ``roots`` through object references (``gc.get_referents``)?
    Modules, classes and a function's globals are not followed (from them everything is
    reachable); a function's closure cells and a bound method's ``__self__`` are."""
    seen, todo = set(), list(roots)
    while todo:
        obj = todo.pop()
        if obj is target:
            return True
        if id(obj) in seen or isinstance(obj, (types.ModuleType, type)):
            continue
        seen.add(id(obj))
        assert len(seen) < limit, "the walk did not end: the answer would mean nothing"
        if isinstance(obj, types.FunctionType):
            todo.extend(c.cell_contents for c in (obj.__closure__ or ()) if c.cell_contents is not None)
            continue
        todo.extend(gc.get_referents(obj))
    return False


def test_a_path_is_handed_a_frame_context_through_which_the_action_is_out_of_reach(draw_path, action):
    """Whatever a path holds or is handed - the frame context, its own state, the shared set-up -
    leads to no :class:`ClipRenderAction`, and no draw-path module imports the action: what a path
    reads is in the context, and what it drew is its return value."""
    a = action(path=draw_path)
    path = a._path(draw_path)
    handed = []

    def spy(frame):
        handed.append(frame)
        return type(path).draw(path, frame)

    path.draw = spy
    img = a.render(camera(), TF, wait=True, timeout=20)
    assert (img[..., 3] > 0).mean() > 0.2
    (frame,) = handed
    assert isinstance(frame, FrameContext) and not hasattr(frame, "action")
    del path.draw  # (the spy's closure holds the path, not the action; the walk checks it)
    assert not _reachable([frame, path, path.setup], a)
    assert _reachable([frame, types.SimpleNamespace(held=[{"k": (a.setup, a)}])], a)  # (the walk finds what is)
    for cls in {type(path), *paths.DRAW_PATHS.values(), paths.DrawSetup, FrameContext}:
        tree = ast.parse(inspect.getsource(inspect.getmodule(cls)))
        imported = {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        imported |= {al.name for n in ast.walk(tree) if isinstance(n, ast.Import) for al in n.names}
        assert not any(m.split(".")[-1] == "action" for m in imported), (cls, imported)


def test_draw_stats_are_folded_into_the_frame_stats(draw_path, action):
    """The counts a path returns (:class:`DrawStats`) are the frame's: boxes, page-table nodes and
    occlusion passes in :class:`FrameStats`, the same on the action; the 8 unmerged boxes of the
    volume drawn per brick take an opacity snapshot before every box but the first (8 / 32 boxes
    rounds up to 1)."""
    a = action(path=draw_path, merge_boxes=False)
    a.render(camera(), TF, wait=True, timeout=20)
    st = a.last_frame_stats
    assert st.path == a.path_drawn == draw_path and st.items_drawn == 8
    assert (st.boxes_drawn, st.page_table_nodes) == (a.boxes_drawn, a.page_table_nodes)
    if draw_path == "bricks":
        assert st.boxes_drawn == 8 and st.page_table_nodes == 0 and st.occlusion_passes == 7 == a.occlusion_passes
    a.render(camera(), TF)  # the same cut again: counted again
    assert a.last_frame_stats.boxes_drawn == st.boxes_drawn
