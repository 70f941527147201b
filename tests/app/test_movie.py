"""Movies of offscreen flythroughs, and a DICOM series shown the right way up with its labels.

References: the PNG frames of the same converged path (decoded movie frames must match them up to
compression), and anatomy placed by hand in the written slices (a bright block at the patient's
left and head must appear at screen right and top of the frontal view).
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import MissingExtraError

pytest.importorskip("moderngl")
iio = pytest.importorskip("imageio.v3")
pytest.importorskip("imageio_ffmpeg")


def _over_black(img):
    a = img[..., 3:4] / 255.0
    return img[..., :3] * a


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.bricking.generators import parse_procedural

    d = tmp_path_factory.mktemp("movie")
    out = d / "fractal.zarr"
    g = parse_procedural("procedural:fractal?size=32")
    brick_volume(g.region(0, (0, 0, 0), g.shape), out, brick=16, progress=False)
    return out


def test_movie_matches_png_frames(store, tmp_path, ctx):
    from PIL import Image

    from clipvol.app.flythrough import render_path

    kw = dict(path="turntable", frames=5, size=(63, 48), converged=True, ctx=ctx)
    pngs = render_path(store, tmp_path / "png", **kw)
    res = render_path(store, tmp_path / "spin.mp4", fps=10, quality=10, **kw)
    assert res.movie == tmp_path / "spin.mp4" and res.csv == tmp_path / "spin.mp4.csv" and res.csv.is_file()
    frames = iio.imread(tmp_path / "spin.mp4")
    assert frames.shape == (5, 48, 64, 3)  # odd width padded to even for H.264
    meta = iio.immeta(tmp_path / "spin.mp4")
    assert meta["fps"] == pytest.approx(10)
    for k, f in enumerate(pngs.files):
        ref = _over_black(np.asarray(Image.open(f)).astype(np.float64))
        got = frames[k, :, :63].astype(np.float64)
        assert ref.max() > 50  # not blank
        assert np.abs(got - ref).mean() < 4.0, k  # lossy, but the same picture
    assert not list(tmp_path.glob(".*partial*"))


def test_a_gif_and_a_movie_of_one_name_keep_their_own_csv(store, tmp_path, ctx):
    import csv

    from clipvol.app.flythrough import render_path

    gif = render_path(store, tmp_path / "spin.gif", path="turntable", frames=3, size=(32, 32), ctx=ctx)
    mp4 = render_path(store, tmp_path / "spin.mp4", path="turntable", frames=5, size=(32, 32), ctx=ctx)
    assert gif.csv != mp4.csv  # before: both spin.csv, the movie's overwrote the GIF's
    rows = [list(csv.DictReader(open(r.csv))) for r in (gif, mp4)]
    assert [len(r) for r in rows] == [3, 5]  # each its own run's frames


def test_movie_error_leaves_no_file(store, tmp_path, ctx):
    from clipvol.app.flythrough import render_path

    def boom(row):
        if row["frame"] == 1:
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        render_path(store, tmp_path / "x.mp4", frames=4, size=(32, 32), ctx=ctx, progress=boom)
    assert not (tmp_path / "x.mp4").exists() and not list(tmp_path.glob(".*partial*"))


def test_movie_without_imageio_names_the_extra(store, tmp_path, ctx, monkeypatch):
    import sys

    from clipvol.app.flythrough import render_path

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(MissingExtraError, match=r"clipvol\[movie\]"):
        render_path(store, tmp_path / "x.mp4", frames=1, size=(16, 16), ctx=ctx)


def test_dicom_series_to_labelled_frontal_view(tmp_path, capsys):
    pytest.importorskip("pydicom")
    from format_files import write_dicom_series

    from clipvol.tools.cli import main

    vol = np.zeros((24, 24, 24), np.uint16)  # z (S), y (P), x (L) for an axial LPS series
    vol[16:22, 6:18, 16:22] = 1000  # high x = patient's left, high z = superior
    vol[2:5, 8:16, 3:6] = 300  # a faint marker at the right and inferior
    write_dicom_series(tmp_path / "ct", vol, spacing=(1.0, 1.0, 1.0))
    store = tmp_path / "ct.zarr"
    assert main(["brick", str(tmp_path / "ct"), str(store), "--brick", "8", "--quiet"]) == 0
    assert main(["info", str(store)]) == 0
    assert "orientation LPS" in capsys.readouterr().out
    out = tmp_path / "front"
    assert main(["view", str(store), "--offscreen", "--path", "turntable", "--frames", "4", "--size", "96x96",
                 "--converged", "--mode", "mip", "--tf", "grey", "--no-labels", "--out", str(out)]) == 0
    from PIL import Image

    img = np.asarray(Image.open(out / "frame_0000.png")).astype(np.float64)[..., 0]
    ys, xs = np.nonzero(img > 0.8 * img.max())
    assert xs.mean() > 48 and ys.mean() < 48  # patient's left on screen right, head at the top
    # with labels: the same view carries R on the left edge and L on the right edge
    lab = tmp_path / "lab"
    assert main(["view", str(store), "--offscreen", "--path", "turntable", "--frames", "1", "--size", "96x96",
                 "--converged", "--mode", "mip", "--tf", "grey", "--out", str(lab)]) == 0
    with_labels = np.asarray(Image.open(lab / "frame_0000.png")).astype(np.int16)
    plain = np.asarray(Image.open(out / "frame_0000.png")).astype(np.int16)
    changed = np.any(with_labels != plain, axis=-1)
    assert changed[40:56, :10].any() and changed[40:56, -10:].any() and changed[:10, 40:56].any()
    assert not changed[30:66, 30:66].any()  # labels stay at the edges


def test_png_frame_interrupted_mid_write_leaves_no_file(tmp_path, monkeypatch):
    """A frame file that exists is whole: a Ctrl-C while PIL writes it leaves neither the frame nor
    its part file; a finished one reads back as written."""
    from PIL import Image

    from clipvol.app.flythrough import save_png

    img = np.random.default_rng(0).integers(0, 256, size=(8, 6, 4), dtype=np.uint8)
    f = tmp_path / "frame_0000.png"
    save_png(img, f)
    np.testing.assert_array_equal(np.asarray(Image.open(f)), img)
    real_save = Image.Image.save

    def save_then_interrupt(self, fp, *a, **k):
        real_save(self, fp, *a, **k)
        with open(fp, "r+b") as fh:  # as if cut off half-way
            fh.truncate(10)
        raise KeyboardInterrupt

    monkeypatch.setattr(Image.Image, "save", save_then_interrupt)
    g = tmp_path / "frame_0001.png"
    with pytest.raises(KeyboardInterrupt):
        save_png(img, g)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_0000.png"]
