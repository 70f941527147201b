"""Every registered data kind (``clipvol.app.kinds.KINDS``) claims its source, opens it and draws one
small image through its own session that equals an independent reference; every kind's
command-line hooks are found the same way, the volume's included.

References: the numpy ray caster ``tests/reference_raycast.py`` (a volume), the numpy splatter
``tests/reference_splats.py`` drawing every point (a point store), the source array's own plane (a
slice). A kind registered without a case here fails the test by name, so a new kind is tested the
moment it is registered.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from reference_splats import splat_every_point
from scipy.ndimage import gaussian_filter

from clipvol.app.kinds import KINDS, kind_of
from clipvol.scene.metrics import percent_delta_e
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction
from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

N = 16  # the point lattice's edge, a power of two: every leaf holds 2 x 2 x 2 points, splat size 1


def _smooth(shape=(20, 20, 20), seed=5) -> np.ndarray:
    v = gaussian_filter(np.random.default_rng(seed).random(shape), 2.0)
    return ((v - v.min()) / np.ptp(v)).astype(np.float32)


def _volume_case(tmp_path):
    """A 20^3 ``.npy`` drawn composite at level 0; reference: the numpy ray caster."""
    from clipvol.scene.params import RenderParams

    vol = _smooth()
    np.save(tmp_path / "v.npy", vol)
    tf = TransferFunction.preset("viridis", value_range=(0.2, 1.0))
    cam = Camera.perspective((34.0, 27.0, -26.0), (10.0, 10.0, 10.0), fov_y=40, size=(64, 64))
    kwargs = dict(params=RenderParams(policy="fixed", level=0, step=0.5), tf=tf, memory_budget="32MB")

    def reference(loader):
        fc = cam.fit_depth(*loader.pyramid.volume_box())
        return ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, tf.table, (0.2, 1.0), 0.5))

    def check(img, want):
        d = np.abs(img.astype(int) - want.astype(int)).max(axis=-1)
        assert d.max() <= 3 and (d > 1).mean() < 0.01, (d.max(), (d > 1).mean())

    return str(tmp_path / "v.npy"), dict(brick=8), cam, kwargs, reference, check


def _points_case(tmp_path):
    """A 16^3 lattice of points with a linear value, every leaf drawn (tolerance 1 px); reference:
    the numpy splatter drawing every point."""
    from clipvol.bricking.point_sources import ArrayPointSource
    from clipvol.bricking.point_store_build import build_point_store

    z, y, x = np.meshgrid(*(np.arange(N),) * 3, indexing="ij")
    xyz = np.stack([x.ravel(), y.ravel(), z.ravel()], 1) + 0.5
    vals = (xyz @ np.array([0.03, -0.02, 0.04]) + 0.3).astype(np.float32)
    path = tmp_path / "p.zarr"
    build_point_store(ArrayPointSource(xyz, vals), path, max_points=8, progress=False, box=((0, 0, 0), (N, N, N)))
    tab = TransferFunction.preset("viridis", value_range=(0.0, 1.0)).table.copy()
    tab[:, 3] = 0.35
    tf = TransferFunction(tab, (0.0, 1.0))
    c = N / 2.0
    cam = Camera.perspective((c + 26, c - 18, c - 34), (c, c, c), fov_y=40, size=(64, 64))
    kwargs = dict(tf=tf, tolerance="1px", memory_budget="32MB")

    def reference(loader):
        return splat_every_point(xyz, vals, 1.0, cam, tf.table, (0.0, 1.0), unit=loader.meta.point_spacing)

    def check(img, want):
        assert percent_delta_e(img, want, premultiplied=False) < 1.0

    return str(path), {}, cam, kwargs, reference, check


#: one case per registered kind: ``case(tmp_path) -> (source, open kwargs, camera, session kwargs,
#: reference(loader), check(image, reference))``
CASES = {"volume": _volume_case, "points": _points_case}


@pytest.mark.parametrize("name", sorted(KINDS))
def test_each_kind_opens_and_draws_its_reference(name, gl, tmp_path):
    assert name in CASES, f"data kind {name!r} is registered without a case in {__name__}.CASES"
    kind = KINDS[name]
    source, open_kwargs, cam, session_kwargs, reference, check = CASES[name](tmp_path)
    assert kind_of(source) is kind
    loader = kind.open(source, **open_kwargs)
    with kind.session(loader, gl, **session_kwargs) as session:
        img = session.render(cam, wait=True, timeout=60)
    want = reference(loader)
    assert img.shape == want.shape == (64, 64, 4)
    assert (img[..., 3] > 0).mean() > 0.05  # something is drawn, so the comparison means something
    check(img, want)


class _Recorder:
    """Command-line hooks that record which command reached them."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, command):
        if command.startswith("_"):
            raise AttributeError(command)

        def hook(args, *rest):
            self.calls.append(command)
            return 0
        return hook


@pytest.mark.parametrize("name", sorted(KINDS))
def test_every_command_hands_each_kind_to_its_hooks(name, tmp_path, monkeypatch):
    """The volume is no special case: render, slice, view, info, check and report all reach the
    kind's hooks (before, a volume ran the commands' own code and never its kind's)."""
    source = CASES[name](tmp_path)[0]
    rec = _Recorder()
    monkeypatch.setattr(KINDS[name], "cli", rec)
    out = tmp_path / "o.png"
    assert main(["render", source, "--out", str(out)]) == 0
    assert main(["slice", source, "--out", str(out)]) == 0
    assert main(["view", source, "--offscreen", "--out", str(tmp_path / "frames")]) == 0
    assert main(["report", source, "--out", str(tmp_path / "rep")]) == 0
    assert main(["info", source]) == 0
    assert main(["check", source]) == 0
    assert rec.calls == ["render", "slice", "view", "report", "info", "check"]


def test_a_kind_without_a_slice_hook_is_refused_by_name(tmp_path, capsys):
    source = _points_case(tmp_path)[0]
    assert main(["slice", source, "--out", str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err
    assert source in err and "points" in err and "`clipvol slice` does not take this kind" in err


def test_a_slice_session_draws_the_source_plane(gl, tmp_path):
    """``SliceSession`` (the volume kind's cutting planes): an axial plane through voxel centres at
    level 0 holds the source array's own values."""
    from clipvol.app.slice_session import SliceSession
    from clipvol.scene.params import RenderParams
    from clipvol.scene.plane import Plane

    vol = _smooth((16, 24, 20), seed=7)
    np.save(tmp_path / "v.npy", vol)
    loader = KINDS["volume"].open(str(tmp_path / "v.npy"), brick=8)
    plane = Plane.axis(loader.pyramid, "axial", 9)
    with SliceSession(loader, gl, RenderParams(policy="plane", level=0), memory_budget="32MB") as s:
        rgba, values = s.render(plane, wait=True, timeout=60)
        assert s.stats.converged
    assert values.shape == (24, 20) and rgba.shape == (24, 20, 4)
    np.testing.assert_allclose(values, vol[9], atol=1e-5)
