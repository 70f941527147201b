"""Cutting the volume open, drawn: a crop box and clip planes given in the store's world frame or in
voxels (``clipvol.scene.cut``, ``clipvol render --crop/--crop-voxels/--clip-plane``) against the
independent numpy ray caster (``reference_raycast``) with the same box and planes written out by
hand in the render frame, on both draw paths; and bricks outside the cut are never read.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from PIL import Image

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.scene.camera import Camera
from clipvol.scene.cut import cut_shape
from clipvol.scene.transfer import TransferFunction

from counting_loader import Counting

pytestmark = pytest.mark.gl

SHAPE = (32, 32, 32)
TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (0.5, (0, 1, 0, 0.05)), (1.0, (1, 0, 0, 0.3))])


@pytest.fixture(autouse=True)
def _gl_clean(ctx):
    assert ctx.error == "GL_NO_ERROR"
    yield
    assert ctx.error == "GL_NO_ERROR"


def smooth_volume(shape=SHAPE) -> np.ndarray:
    z, y, x = np.mgrid[0 : shape[0], 0 : shape[1], 0 : shape[2]].astype(np.float64)
    return ((np.sin(x / 3.0) + np.cos(y / 4.0) + np.sin(z / 2.5) + 3.0) / 6.0).astype(np.float32)


def camera():
    return Camera.perspective((-20.0, -14.0, -30.0), (15.5, 15.5, 15.5), size=(64, 64), fov_y=45)


def diff(a, b):
    return np.abs(a.astype(int) - b.astype(int))


def test_voxel_crop_and_world_plane_equal_the_reference_on_both_paths(ctx, draw_path):
    from clipvol.app.session import RenderSession
    from clipvol.scene.params import RenderParams

    vol = smooth_volume()
    loader = Counting(NumpyLoader(vol, brick=8))
    pyr = loader.pyramid
    # level-0 voxels z 4:24, y 2:30, x 6:28 and the half-space x + y >= 30 (world = render frame: no affine)
    shape = cut_shape(pyr, None, crop_voxels=((4, 2, 6), (24, 30, 28)), clip_planes=[(15, 15, 0, 1, 1, 0)])
    box_lo, box_hi = (5.5, 1.5, 3.5), (27.5, 29.5, 23.5)  # the voxels' cells, (x, y, z), by hand
    planes = ((1 / np.sqrt(2), 1 / np.sqrt(2), 0.0, -30 / np.sqrt(2)),)
    cam = camera()
    fc = cam.fit_depth(*pyr.volume_box())
    r = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, TF.table, TF.window(pyr.value_range), 0.5,
                                 shape=(box_lo, box_hi, planes)))
    full = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, TF.table, TF.window(pyr.value_range), 0.5))
    assert diff(r, full).max() > 50  # the cut matters
    params = RenderParams(policy="fixed", level=0, shape=shape, path=draw_path)
    with RenderSession(loader, ctx, params=params, tf=TF, threads=2, memory_budget="64MB") as s:
        img = s.render(cam, wait=True, timeout=30)
        assert s.frame_stats.converged and s.action.path_drawn == draw_path
        assert s.frame_stats.counts["culled_shape"] > 0
        assert diff(img, r).max() <= 2
        s.clip_texture.wait_until_idle(30)
        # bricks that no sample inside the cut can use (their node grown by the one voxel trilinear
        # interpolation reaches, tested corner by corner here) are never read
        outside = {(L, (z, y, x)) for L in range(pyr.num_levels) for z, y, x in np.ndindex(*pyr.grid(L))
                   if not _meets(pyr.node_box(L, (z, y, x)), 2.0 ** L, (box_lo, box_hi), planes)}
        assert len(outside) >= 10 and not outside & set(loader.reads), sorted(outside & set(loader.reads))[:5]
        # the whole volume again: the bricks that were outside are read now, and the image is the uncut one
        s.update(shape=None)
        img = s.render(cam, wait=True, timeout=30)
        assert {ix for L, ix in outside if L == 0} <= {ix for L, ix in loader.reads if L == 0}
        assert diff(img, full).max() <= 2


def _meets(node, voxel, box, planes) -> bool:
    """Does the box ``node`` grown by ``voxel`` meet the cut? Its 8 corners against the planes, its
    extent against the box."""
    lo, hi = (np.asarray(v) - voxel for v in node)
    hi = hi + 2 * voxel
    if np.any(hi < box[0]) or np.any(lo > box[1]):
        return False
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return all(np.any(corners @ np.array(p[:3]) + p[3] >= 0) for p in planes)


def test_cli_render_crop_in_world_units_equals_the_reference(tmp_path):
    from clipvol.tools.cli import main

    vol = smooth_volume()
    np.save(tmp_path / "v.npy", vol)
    store = tmp_path / "v.zarr"
    origin = (-4.0, 2.0, 3.0)  # z, y, x: the world position of voxel 0
    assert main(["brick", str(tmp_path / "v.npy"), str(store), "--brick", "8", "--quiet", "--no-summary",
                 "--origin=" + ",".join(map(str, origin[::-1]))]) == 0  # typed x,y,z
    out = tmp_path / "cut.png"
    # world box x 8..30, y 4..26, z -2..14 (x, y, z), a plane keeping world x - z >= 10
    assert main(["render", str(store), "--out", str(out), "--size", "64x64", "--policy", "fixed", "--level", "0",
                 "--eye=-17,-12,-34", "--target", "18.5,17.5,11.5", "--up", "0,-1,0", "--fov", "45",  # world = render + origin
                 "--tf", "viridis", "--tf-range", "0.2,1", "--crop=8,4,-2,30,26,14",
                 "--clip-plane", "13,0,3,1,0,-1"]) == 0
    img = np.asarray(Image.open(out))
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.views import view_camera

    pyr = ZarrLoader(store).pyramid
    cam = view_camera(pyr, "iso", (64, 64), eye=(-20, -14, -30), target=(15.5, 15.5, 15.5), up=(0, -1, 0), fov=45)
    tf = TransferFunction.preset("viridis", value_range=(0.2, 1.0))
    ox, oy, oz = origin[::-1]  # render frame = world - origin (x, y, z)
    box = ((8 - ox, 4 - oy, -2 - oz), (30 - ox, 26 - oy, 14 - oz))
    planes = ((1 / np.sqrt(2), 0.0, -1 / np.sqrt(2), ((13 - ox) * -1 + (3 - oz)) / np.sqrt(2)),)  # n.(p - q) >= 0
    fc = cam.fit_depth(*pyr.volume_box())
    r = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, tf.table, (0.2, 1.0), 0.5, shape=(box[0], box[1], planes)))
    full = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, tf.table, (0.2, 1.0), 0.5))
    assert diff(r, full).max() > 50
    d = diff(img, r)
    assert d.max() <= 3 and (d > 1).mean() < 0.01, (d.max(), (d > 1).mean())


def test_cli_refuses_bad_cuts_with_exit_2(tmp_path, capsys):
    from clipvol.tools.cli import main

    np.save(tmp_path / "v.npy", smooth_volume((8, 8, 8)))
    base = ["render", str(tmp_path / "v.npy"), "--out", str(tmp_path / "o.png"), "--size", "16x16", "--brick", "8"]
    for extra, word in ((["--crop-voxels", ":,:,0:9"], "--crop-voxels"), (["--crop", "1,2,3"], "--crop"),
                        (["--clip-plane", "0,0,0,0,0,0"], "clip-plane"), (["--crop=100,100,100,200,200,200"], "outside")):
        assert main(base + extra) == 2, extra
        assert word in capsys.readouterr().err


def test_cli_render_crop_in_patient_millimetres_of_a_mirrored_nifti(tmp_path):
    """A LAS NIfTI (x flipped, anisotropic voxels, an origin): ``--crop`` in RAS mm draws the box that
    nibabel's affine maps to voxels, and the PNG (flipped back left-right for the mirrored storage)
    equals the reference cast with that box."""
    nib = pytest.importorskip("nibabel")
    from nibabel.affines import apply_affine

    from clipvol.tools.cli import main

    vol = smooth_volume((24, 28, 32))  # z, y, x as the store keeps it
    affine = np.array([[-1.5, 0, 0, 40.0], [0, 1.0, 0, -10.0], [0, 0, 2.0, 5.0], [0, 0, 0, 1]])  # LAS
    nii = tmp_path / "scan.nii.gz"
    nib.save(nib.Nifti1Image(vol.T.copy(), affine), nii)
    out = tmp_path / "cut.png"
    crop = ((10.0, -2.0, 12.0), (34.0, 20.0, 40.0))  # two RAS corners, mm
    assert main(["render", str(nii), "--store", str(tmp_path / "scan.zarr"), "--out", str(out), "--size", "64x64",
                 "--policy", "fixed", "--level", "0", "--no-labels", "--eye=-25,-20,-40", "--target", "24,14,24",
                 "--up", "0,-1,0", "--fov", "45", "--tf", "viridis", "--tf-range", "0.2,1",
                 "--crop=" + ",".join(map(str, crop[0] + crop[1]))]) == 0
    img = np.asarray(Image.open(out))
    import clipvol
    from clipvol.scene.views import view_camera

    v = clipvol.open(tmp_path / "scan.zarr")
    assert np.array_equal(np.asarray(v.level(0)[:, :, :]), vol)  # the array as stored
    sp = np.array([1.5, 1.0, 2.0])  # voxel size along the array's x, y, z
    # the box by nibabel: RAS corners -> voxel indices (x, y, z) -> render frame (index * spacing)
    corners = np.array([[a, b, c] for a in (crop[0][0], crop[1][0]) for b in (crop[0][1], crop[1][1])
                        for c in (crop[0][2], crop[1][2])])
    r = apply_affine(np.linalg.inv(affine), corners) * sp
    box = (tuple(r.min(axis=0)), tuple(r.max(axis=0)))
    from clipvol.loaders.zarr_store import ZarrLoader

    store = ZarrLoader(tmp_path / "scan.zarr")
    pyr = store.pyramid
    cam = view_camera(pyr, "iso", (64, 64), eye=(-25, -20, -40), target=(24, 14, 24), up=(0, -1, 0), fov=45,
                      frame=store.frame)
    tf = TransferFunction.preset("viridis", value_range=(0.2, 1.0))
    fc = cam.fit_depth(*pyr.volume_box())
    want = ref.to_uint8(ref.raycast(vol, (2.0, 1.0, 1.5), fc, tf.table, (0.2, 1.0), 0.5, shape=(box[0], box[1], ())))
    full = ref.to_uint8(ref.raycast(vol, (2.0, 1.0, 1.5), fc, tf.table, (0.2, 1.0), 0.5))
    want, full = want[:, ::-1], full[:, ::-1]  # a mirrored store's image is shown flipped back
    assert diff(want, full).max() > 50
    d = diff(img, want)
    assert d.max() <= 3 and (d > 1).mean() < 0.01, (d.max(), (d > 1).mean())
