"""Overlays of any affine: a map stored flipped (LAS under a RAS scan), with permuted axes, or on a
grid rotated by 15 degrees lands where it belongs.

References: nibabel's ``apply_affine`` with the two files' affines says which overlay voxel each
primary voxel meets (against the texture transform the shader uses); scipy's
``ndimage.affine_transform`` resamples the rotated copy's array onto the primary's grid for a
reference of where its marker lies; and the rendered marker of every copy must sit within half a
voxel of the marker of the primary drawn as its own overlay.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import affine_transform, center_of_mass

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import ParameterError
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.scene.overlay import Overlay, check_overlay, overlay_texture_transform
from clipvol.scene.transfer import TransferFunction

nib = pytest.importorskip("nibabel")
from nibabel.affines import apply_affine  # noqa: E402

SHAPE = (24, 20, 16)  # (i, j, k)
RAS = np.array([[2.0, 0, 0, -23], [0, 2.0, 0, -19], [0, 0, 2.0, -15], [0, 0, 0, 1]])


def _marker() -> np.ndarray:
    v = np.zeros(SHAPE, dtype=np.float32)
    v[3:7, 12:16, 9:13] = 1.0  # left, anterior, superior of the centre
    return v


def _rotation_about_centre(deg: float) -> np.ndarray:
    """Voxel-space rotation about the volume centre (about k, i.e. the superior axis)."""
    t = np.radians(deg)
    r = np.eye(4)
    r[:2, :2] = [[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]
    c = (np.array(SHAPE) - 1) / 2.0
    m = np.eye(4)
    m[:3, 3] = c
    back = np.eye(4)
    back[:3, 3] = -c
    return m @ r @ back


def _copy(name: str):
    """``(array (i, j, k), affine)`` of a copy of the marker volume: the same patient, another grid."""
    v = _marker()
    if name == "ras":
        return v, RAS
    if name == "las":
        flip = np.array([[-1.0, 0, 0, SHAPE[0] - 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        return v[::-1].copy(), RAS @ flip
    if name == "perm":
        perm = np.array([[0.0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])  # new (a, b, c) = old (k, i, j)
        return np.ascontiguousarray(v.transpose(2, 0, 1)), RAS @ perm
    rot = _rotation_about_centre(15.0)  # new voxel -> old voxel
    return affine_transform(v, rot[:3, :3], rot[:3, 3], order=1).astype(np.float32), RAS @ rot


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    d = tmp_path_factory.mktemp("affine_overlays")
    out = {}
    for name in ("ras", "las", "perm", "rot"):
        v, a = _copy(name)
        nib.save(nib.Nifti1Image(v, a), d / f"{name}.nii.gz")
        brick_volume(str(d / f"{name}.nii.gz"), d / f"{name}.zarr", brick=8, progress=False, workers=1, summary=False)
        out[name] = d / f"{name}.zarr"
    return out


def test_copies_are_what_nibabel_says():
    assert nib.aff2axcodes(_copy("las")[1]) == ("L", "A", "S")
    assert nib.aff2axcodes(_copy("perm")[1]) == ("S", "R", "A")


@pytest.mark.parametrize("name", ["las", "perm", "rot"])
def test_texture_transform_meets_the_voxel_nibabel_names(stores, name):
    primary = ZarrLoader(stores["ras"])
    ov = Overlay(ZarrLoader(stores[name]), "grey")
    m = overlay_texture_transform(ov, 0, primary)
    idx = np.stack(np.meshgrid(*(np.arange(0, n, 3) for n in SHAPE), indexing="ij"), -1).reshape(-1, 3).astype(float)
    drawn = idx * np.linalg.norm(RAS[:3, :3], axis=0)  # the primary's drawing frame: voxel i at i * spacing
    tex = drawn @ m[:3, :3].T + m[:3, 3]
    n_o = np.array(ZarrLoader(stores[name]).pyramid.shape[::-1], dtype=float)
    got = tex * n_o - 0.5  # texture coordinate -> overlay voxel index (x, y, z)
    want = apply_affine(np.linalg.inv(_copy(name)[1]) @ RAS, idx)
    np.testing.assert_allclose(got, want, atol=1e-5)  # NIfTI keeps its affine in float32
    if name != "rot":  # a flip or permutation: voxel centres onto voxel centres, nothing resampled
        np.testing.assert_allclose(got, np.round(got), atol=1e-9)


def _render_overlay(ctx, primary_path, overlay_path):
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.camera import Camera

    loader = ZarrLoader(primary_path)
    lo, hi = loader.pyramid.volume_box()
    c = (lo + hi) / 2
    ext = float((hi - lo).max()) * 1.1
    cam = Camera.orthographic(tuple(c), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), ext, ext, size=(96, 96)).fit_depth(lo, hi)
    hidden = TransferFunction.preset("grey", value_range=(10.0, 11.0), opacity="ramp")  # the primary: not drawn
    ov = Overlay(ZarrLoader(overlay_path), TransferFunction.preset("grey", value_range=(0.0, 0.6)))
    clip = ClipTexture(loader, "64MB", threads=2)
    try:
        with ClipRenderAction(ctx, clip, policy="fixed", level=0, overlays=(ov,)) as action:
            img = action.render(cam, hidden, wait=True, timeout=30)
    finally:
        clip.close()
    return img.astype(np.float64), ext / 96  # image and world units per pixel


@pytest.mark.gl
@pytest.mark.parametrize("name", ["las", "perm", "rot"])
def test_copies_drawn_as_overlays_coincide_with_the_primary(ctx, stores, name):
    ref, px = _render_overlay(ctx, stores["ras"], stores["ras"])
    img, _ = _render_overlay(ctx, stores["ras"], stores[name])
    a_ref, a = ref[..., 3], img[..., 3]
    assert a_ref.max() > 100 and a.max() > 100
    shift = np.subtract(center_of_mass(a), center_of_mass(a_ref)) * px  # world units
    assert np.all(np.abs(shift) < 0.5 * 2.0), f"{name}: marker moved by {shift} (voxel 2.0)"
    if name != "rot":  # exact placement: the same picture up to float rounding
        assert np.abs(img - ref).max() <= 2.0
    else:  # the rotated copy, resampled twice, against scipy's resampling of it back onto the primary grid
        v_rot, a_rot = _copy("rot")
        back = np.linalg.inv(a_rot) @ RAS  # primary voxel -> rotated-copy voxel
        res = affine_transform(v_rot, back[:3, :3], back[:3, 3], order=1)
        moved = np.subtract(center_of_mass(res), center_of_mass(_marker())) * 2.0
        assert np.all(np.abs(moved) < 0.5 * 2.0)  # the reference itself is within half a voxel


def test_overlay_in_another_unit_or_elsewhere_is_refused_naming_it(stores, tmp_path):
    primary = ZarrLoader(stores["ras"])
    far = tmp_path / "far.nii.gz"
    shifted = RAS.copy()
    shifted[:3, 3] += 500.0
    nib.save(nib.Nifti1Image(_marker(), shifted), far)
    brick_volume(str(far), tmp_path / "far.zarr", brick=8, progress=False, workers=1, summary=False)
    with pytest.raises(ParameterError, match=r"overlay .*far\.zarr.*overlap the primary"):
        check_overlay(Overlay(ZarrLoader(tmp_path / "far.zarr"), "grey"), primary)
    with pytest.raises(ParameterError, match="expected the primary's unit 'millimeter', got 'micrometer'"):
        check_overlay(Overlay(ZarrLoader(stores["las"]), "grey", unit="micrometer"), primary)


def test_label_image_of_a_mirrored_store_sits_on_its_voxels(stores, tmp_path):
    # a store's own label image shares its frame (OME image-label) without recording it: under an
    # LAS store, --label-overlay must put label voxel i on image voxel i (not mirrored, not refused)
    import argparse
    import shutil

    from clipvol.bricking.labels import brick_labels
    from clipvol.tools.overlay_args import overlays_from_args

    img = tmp_path / "las.zarr"
    shutil.copytree(stores["las"], img)
    zyx = _copy("las")[0].transpose(2, 1, 0)  # the store's (z, y, x) array
    brick_labels(img, (zyx > 0.5).astype(np.uint8), "marker", progress=False)
    primary = ZarrLoader(img)
    args = argparse.Namespace(label_overlay=["marker"], overlay=[], label_colors=None, label_opacity=0.5,
                              overlay_budget=64 << 20)
    (ov,) = overlays_from_args(args, img, primary)
    check_overlay(ov, primary)
    m = overlay_texture_transform(ov, 0, primary)
    idx = np.stack(np.meshgrid(*(np.arange(0, n, 3) for n in SHAPE), indexing="ij"), -1).reshape(-1, 3).astype(float)
    got = (idx * 2.0) @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(got * np.array(SHAPE) - 0.5, idx, atol=1e-9)
