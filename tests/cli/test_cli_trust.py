"""The CLI and the store manifest: ``info`` says verified or unverified in its first line, ``check``
fails an unverified store and statistics that differ from the manifest, ``render`` draws an
unverified store only with ``--unverified`` (a foreign OME-Zarr after one note), ``repair``
restores statistics and writes the manifest. References: the source array (numpy) and the
statistics as the build wrote them."""

from __future__ import annotations

import os
import shutil
import threading

import numpy as np
import pytest
import zarr
from PIL import Image

from clipvol.tools.cli import main

B = 16


@pytest.fixture
def built(tmp_path):
    z, y, x = np.indices((36, 40, 34))
    vol = np.clip(2000 + 1500 * np.sin(z / 4.0) * np.cos(y / 5.0) + 400 * np.sin(x / 3.0), 1, 4095).astype(np.uint16)
    vol[:16] = 0
    src = tmp_path / "v.npy"
    np.save(src, vol)
    out = tmp_path / "o.zarr"
    assert main(["brick", str(src), str(out), "--brick", str(B), "--quiet"]) == 0
    return src, out, vol


def _drop_manifest(out):
    g = zarr.open_group(str(out), mode="r+")
    g.attrs["clipvol"] = {k: v for k, v in g.attrs["clipvol"].items() if k != "manifest"}


def _stats(out, L=0):
    return {n: zarr.open_array(str(out / "clipvol_stats" / str(L) / n), mode="r")[...]
            for n in ("min", "max", "mean", "std", "histogram", "chunk_crc32c")}


def test_a_store_without_a_manifest_is_unverified_until_repair_writes_one(built, tmp_path, capsys):
    src, out, vol = built
    _drop_manifest(out)
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith(f"store      {out} (unverified: no manifest") and "clipvol repair" in first
    assert main(["check", str(out), "--all", "--quiet"]) == 1
    assert "unverified: no manifest" in capsys.readouterr().err
    png = tmp_path / "x.png"
    assert main(["render", str(out), "--out", str(png), "--size", "32x32"]) == 2
    err = capsys.readouterr().err
    assert "unverified" in err and "--unverified" in err and "Traceback" not in err and not png.exists()
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert "wrote the manifest" in capsys.readouterr().out
    assert main(["info", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[0].startswith(f"store      {out} (verified: manifest sha256")
    assert main(["check", str(out), "--all", "--quiet"]) == 0


def test_deleted_statistics_fail_info_and_check_and_repair_restores_them(built, capsys):
    src, out, vol = built
    before = {L: _stats(out, L) for L in range(3)}
    shutil.rmtree(out / "clipvol_stats")
    capsys.readouterr()
    assert main(["info", str(out)]) == 1
    cap = capsys.readouterr()
    assert "kind       clipvol store (statistics do not match the manifest)" in cap.out
    assert "clipvol_stats/0 is missing" in cap.err
    assert main(["check", str(out), "--quiet"]) == 1
    assert "level 0: clipvol_stats/0 is missing" in capsys.readouterr().err
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert "recomputed the statistics of levels 0, 1, 2" in capsys.readouterr().out
    for L in range(3):
        after = _stats(out, L)
        for n, a in before[L].items():
            np.testing.assert_array_equal(after[n], a, err_msg=f"level {L} {n}")
    mx = _stats(out, 0)["max"]
    ref = vol[:32, :32, :32].reshape(2, B, 2, B, 2, B).max(axis=(1, 3, 5))
    np.testing.assert_array_equal(mx[:2, :2, :2], ref)
    assert main(["check", str(out), "--all", "--quiet"]) == 0


def test_a_replaced_statistics_chunk_fails_check_naming_the_array(built, capsys):
    src, out, vol = built
    c = out / "clipvol_stats" / "0" / "max" / "c"
    shutil.copyfile(c / "0" / "0" / "0", c / "1" / "0" / "0")
    capsys.readouterr()
    assert main(["check", str(out), "--quiet"]) == 1
    assert "clipvol_stats/0/max differs from the manifest" in capsys.readouterr().err
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert main(["check", str(out), "--all", "--quiet"]) == 0


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_check_of_a_fifo_chunk_fails_naming_it_without_blocking(built, capsys):
    src, out, vol = built
    chunk = out / "0" / "c" / "1" / "1" / "1"
    chunk.unlink()
    os.mkfifo(chunk)
    capsys.readouterr()
    res = {}
    t = threading.Thread(target=lambda: res.setdefault("rc", main(["check", str(out), "--all", "--quiet"])), daemon=True)
    t.start()
    t.join(120)
    assert not t.is_alive() and res["rc"] == 1
    err = capsys.readouterr().err
    assert "level 0 brick (1, 1, 1)" in err and "chunk file 0/c/1/1/1: a FIFO, not a regular file" in err, err


@pytest.mark.gl
def test_render_draws_an_unverified_store_only_with_the_flag_and_the_same_image(built, tmp_path, capsys):
    src, out, vol = built
    args = ["--size", "48x40", "--view", "iso", "--tf", "viridis", "--memory-budget", "16MB"]
    assert main(["render", str(out), "--out", str(tmp_path / "a.png"), *args]) == 0
    _drop_manifest(out)
    capsys.readouterr()
    assert main(["render", str(out), "--out", str(tmp_path / "b.png"), "--unverified", *args]) == 0
    err = capsys.readouterr().err
    assert len([ln for ln in err.splitlines() if "unverified" in ln]) == 1, err
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "b.png")), np.asarray(Image.open(tmp_path / "a.png")))


@pytest.mark.gl
def test_render_of_a_foreign_ome_zarr_notes_it_once_and_draws(tmp_path, capsys):
    rng = np.random.default_rng(0)
    g = zarr.open_group(str(tmp_path / "img.zarr"), mode="w", zarr_format=3)
    g.create_array("0", data=(rng.random((32, 32, 32)) * 1000).astype(np.uint16), chunks=(B, B, B))
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{"axes": [{"name": a, "type": "space"} for a in "zyx"],
                      "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}
    capsys.readouterr()
    assert main(["render", str(tmp_path / "img.zarr"), "--out", str(tmp_path / "f.png"), "--size", "32x32"]) == 0
    err = capsys.readouterr().err
    assert err.count("unverified, foreign") == 1, err
    assert (np.asarray(Image.open(tmp_path / "f.png"))[..., 3] > 0).any()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_root_zarr_json_that_is_a_fifo_or_dev_zero_exits_2_without_blocking(tmp_path, capsys):
    store = tmp_path / "x.zarr"
    store.mkdir()
    for make, what in ((lambda p: os.mkfifo(p), "FIFO"), (lambda p: p.symlink_to("/dev/zero"), "")):
        meta = store / "zarr.json"
        if meta.exists() or meta.is_symlink():
            meta.unlink()
        make(meta)
        for argv in (["info", str(store)], ["check", str(store)], ["render", str(store), "--out", str(tmp_path / "a.png")]):
            res = {}
            t = threading.Thread(target=lambda: res.setdefault("rc", main(argv)), daemon=True)
            t.start()
            t.join(60)
            assert not t.is_alive() and res["rc"] == 2, argv
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and str(store) in err and what in err, err


@pytest.mark.gl
def test_slice_view_and_report_refuse_an_unverified_store_without_the_flag(built, tmp_path, capsys):
    src, out, vol = built
    _drop_manifest(out)
    commands = {
        "slice": ["slice", str(out), "--out", str(tmp_path / "s.png"), "--size", "32x32"],
        "view": ["view", str(out), "--offscreen", "--frames", "1", "--size", "32x32", "--out", str(tmp_path / "v.gif")],
        "report": ["report", str(out), "--out", str(tmp_path / "r"), "--views", "1", "--size", "32x32", "--rounds", "1",
                   "--no-plots"],
    }
    for name, argv in commands.items():
        capsys.readouterr()
        assert main(argv) == 2, name
        err = capsys.readouterr().err
        assert "--unverified" in err and str(out) in err and "Traceback" not in err, (name, err)
    # with the flag the slice is drawn and equals the one of the verified store (the manifest back)
    assert main([*commands["slice"], "--unverified"]) == 0
    unverified = np.asarray(Image.open(tmp_path / "s.png"))
    assert main(["repair", str(out), "--source", str(src), "--quiet"]) == 0
    assert main([*commands["slice"][:3], str(tmp_path / "t.png"), *commands["slice"][4:]]) == 0
    np.testing.assert_array_equal(unverified, np.asarray(Image.open(tmp_path / "t.png")))
