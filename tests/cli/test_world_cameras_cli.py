"""Explicit cameras and camera paths in the patient's world: ``render --eye/--target/--up`` take RAS
millimetres (what nibabel's ``apply_affine`` gives for a voxel), and the fly and zoom paths of
``view --offscreen`` are head-up, whatever the storage order of the file.

The synthetic patient of ``world_volumes`` carries a bright marker at its left-anterior-superior
corner; the RAS and LAS copies hold the same patient, so the same world camera must show the marker
at the same place in both.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

nib = pytest.importorskip("nibabel")
pytest.importorskip("moderngl")

from nibabel.affines import apply_affine  # noqa: E402
from world_volumes import RAS, SHAPE, write_copy as _write  # noqa: E402

#: world (RAS mm) of the volume centre and of the marker's middle voxel (voxel (1, 14, 10) of the RAS copy)
CENTRE = apply_affine(RAS, (np.array(SHAPE) - 1) / 2.0)
MARKER = apply_affine(RAS, (1, SHAPE[1] - 2, SHAPE[2] - 2))
MIP = ("--mode", "mip", "--tf", "grey", "--tf-range", "0,1000", "--no-labels")


def _triple(v) -> str:
    return ",".join(f"{float(x):g}" for x in v)


def _marker_centre(img: np.ndarray) -> np.ndarray:
    bright = img[..., 0] > 200
    assert bright.any(), "the marker is not in the picture"
    rows, cols = np.nonzero(bright)
    return np.array([rows.mean(), cols.mean()])


def _render(tmp_path, name: str, *camera: str) -> np.ndarray:
    src = _write(tmp_path, name)
    out = tmp_path / f"{name}.png"
    assert main(["render", src, "--store", str(tmp_path / f"{name}.zarr"), "--out", str(out), "--size", "64x64",
                 "--ortho", *MIP, *camera]) == 0
    return np.asarray(Image.open(out).convert("RGBA"), dtype=np.float64)


def test_the_copies_hold_the_marker_at_one_world_point(tmp_path):
    # independent of clipvol: the LAS copy's marker voxel lands on the RAS copy's world point
    las = nib.load(_write(tmp_path, "las"))
    v = np.asarray(las.dataobj)
    idx = np.argwhere(v == v.max()).mean(axis=0)
    np.testing.assert_allclose(apply_affine(las.affine, idx), MARKER, atol=1e-9)


def test_eye_target_up_are_patient_world_millimetres(tmp_path):
    # from the patient's left (eye at world x - 300 mm), head up (+S): anterior is on the image's
    # left, so the left-anterior-superior marker is top left, in both storage orders
    cam = (f"--eye={_triple(CENTRE + [-300.0, 0.0, 0.0])}", f"--target={_triple(CENTRE)}", "--up=0,0,1")
    imgs = {n: _render(tmp_path, n, *cam) for n in ("ras", "las")}
    for n, img in imgs.items():
        r, c = _marker_centre(img)
        assert r < 28 and c < 28, f"{n}: marker at row {r:.1f}, column {c:.1f}, expected top left"
    np.testing.assert_allclose(_marker_centre(imgs["las"]), _marker_centre(imgs["ras"]), atol=1.0)


def test_target_at_the_marker_centres_it(tmp_path):
    # an orthographic view is centred on --target: the marker's world point lands mid-image
    for n in ("ras", "las"):
        r, c = _marker_centre(_render(tmp_path, n, "--view", "anterior", f"--target={_triple(MARKER)}"))
        assert abs(r - 31.5) < 3 and abs(c - 31.5) < 3, f"{n}: marker at row {r:.1f}, column {c:.1f}, expected the centre"


def test_up_is_a_world_direction(tmp_path):
    # anterior view with the patient's left (-x in RAS) up: the image turns a quarter, the marker
    # (left, superior) goes to the top left
    for n in ("ras", "las"):
        r, c = _marker_centre(_render(tmp_path, n, "--view", "anterior", "--up=-1,0,0"))
        assert r < 28 and c < 28, f"{n}: marker at row {r:.1f}, column {c:.1f}, expected top left"


def _frames(tmp_path, name: str, path: str, frames: int, *extra: str) -> list[np.ndarray]:
    src, store = _write(tmp_path, name), tmp_path / f"{name}.zarr"
    out = tmp_path / f"{name}_{path}{'_'.join(extra)}"
    if "--workers" in extra:  # sort-last: bricks of 8 voxels, so that two workers each draw a part
        assert main(["brick", src, str(store), "--brick", "8", "--quiet"]) == 0
        src = str(store)
    assert main(["view", src, "--store", str(store), "--offscreen", "--converged", "--path", path,
                 "--frames", str(frames), "--size", "64x64", *MIP, "--out", str(out), *extra]) == 0
    return [np.asarray(Image.open(out / f"frame_{k:04d}.png").convert("RGBA"), dtype=np.float64) for k in range(frames)]


@pytest.mark.parametrize("extra", [(), ("--workers", "2", "--scheduler", "inline")], ids=["one", "sort-last"])
def test_zoom_path_starts_head_up_from_anterior_left_superior(tmp_path, extra):
    # the whole view of the zoom looks from azimuth 30 degrees (towards the patient's left) and
    # elevation 25 degrees off anterior, superior up. Where the marker lands, from the world alone:
    az, el = np.radians(30.0), np.radians(25.0)
    A, L, S = np.array([0.0, 1, 0]), np.array([-1.0, 0, 0]), np.array([0.0, 0, 1])
    to_eye = np.cos(el) * (np.cos(az) * A + np.sin(az) * L) + np.sin(el) * S
    fwd = -to_eye
    up = S - (S @ fwd) * fwd
    up /= np.linalg.norm(up)
    right = np.cross(fwd, up)
    m = MARKER - CENTRE
    assert m @ right > 5.0 and abs(m @ up) < 1.0  # right of the centre, about level with it
    for n in ("ras", "las"):
        r, c = _marker_centre(_frames(tmp_path, n, "zoom", 2, *extra)[0])
        assert c > 40 and abs(r - 31.5) < 8, f"{n}: marker at row {r:.1f}, column {c:.1f}, expected right of the centre"


def test_fly_path_is_head_up_in_every_storage_order(tmp_path):
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.orientation import anatomical_axes
    from clipvol.scene.paths import fly

    imgs = {}
    for n in ("ras", "las", "perm"):
        imgs[n] = _frames(tmp_path, n, "fly", 1)[0]
        loader = ZarrLoader(tmp_path / f"{n}.zarr")
        aff = nib.load(_write(tmp_path, n)).affine
        up, front = anatomical_axes(loader.frame.affine)
        sp = np.asarray(loader.pyramid.spacing, dtype=np.float64)[::-1]
        eyes, ups = [], []
        for cam, _ in fly(loader.pyramid, 24, up=tuple(up), front=tuple(front)):
            eyes.append(apply_affine(aff, cam.eye / sp))  # the drawing frame is voxel * spacing
            ups.append(apply_affine(aff, (cam.eye + cam.up) / sp) - eyes[-1])
        eyes, ups = np.array(eyes), np.array(ups)
        ups /= np.linalg.norm(ups, axis=1, keepdims=True)
        assert ups[:, 2].min() > 0.85, f"{n}: screen up is not superior (world up {ups[np.argmin(ups[:, 2])]})"
        spread = eyes.max(axis=0) - eyes.min(axis=0)
        assert spread[2] < 0.5 * min(spread[0], spread[1]), f"{n}: the loop is not axial (spread {spread})"
    for n in ("las", "perm"):  # the presented frames agree
        assert np.abs(imgs[n] - imgs["ras"]).mean() < 4.0, n


def test_turntable_turns_the_same_way_through_the_anatomy_in_every_storage_order(tmp_path):
    # a quarter turn on: the LAS copy (its array axes a mirror of the patient) shows what the RAS does
    ras, las = (_frames(tmp_path, n, "turntable", 4) for n in ("ras", "las"))
    for k in range(4):
        np.testing.assert_allclose(_marker_centre(las[k]), _marker_centre(ras[k]), atol=1.0, err_msg=f"frame {k}")
        assert np.abs(las[k] - ras[k]).mean() < 4.0, k


def test_eye_and_target_of_a_store_with_an_origin_are_world_points(tmp_path):
    """A non-anatomical store bricked with ``--origin 100,0,0`` (x, y, z): its world centre is
    (111.5, 11.5, 11.5) (numpy: origin + (n - 1) / 2 * spacing); --target there equals the default
    target (the volume's centre), and --eye there looks at it from the same place."""

    vol = np.random.default_rng(0).random((24, 24, 24)).astype(np.float32)
    np.save(tmp_path / "o.npy", vol)
    store = tmp_path / "o.zarr"
    assert main(["brick", str(tmp_path / "o.npy"), str(store), "--brick", "8", "--quiet", "--origin", "100,0,0"]) == 0
    centre = np.array([100.0, 0.0, 0.0]) + (np.array(vol.shape[::-1]) - 1) / 2.0
    eye = centre + np.array([30.0, -20.0, -60.0])
    imgs = []
    for extra in ([], ["--target", ",".join(map(str, centre))]):
        out = tmp_path / f"c{len(extra)}.png"
        assert main(["render", str(store), "--eye", ",".join(map(str, eye)), *extra, "--size", "48x48",
                     "--tf", "viridis", "--out", str(out)]) == 0
        imgs.append(np.asarray(Image.open(out)))
    assert imgs[0][..., 3].astype(bool).mean() > 0.1  # the volume is in view
    np.testing.assert_array_equal(imgs[0], imgs[1])
