"""The first five minutes on the command line: transfer-function flags, tf save/load, camera
files, info on any OME-Zarr, output paths checked before work, and user-facing words.

References: files written by zarr-python itself, numpy counts of the voxels and of the chunk
files' bytes (``os.stat``), the JSON documents read back with the ``json`` module.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[2]


def _help_texts() -> str:
    parser = build_parser()
    out = [parser.format_help()]
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, p in sub.choices.items():
        out.append(p.format_help())
        for a in p._actions:
            if a.__class__.__name__ == "_SubParsersAction":
                out += [q.format_help() for q in a.choices.values()]
    return "\n".join(out)


SEED_CITATION = re.compile(r"\bseeds?\b[\s_']*(0\d\d|\d{3}\b|'s)", re.I)


def test_no_seed_numbers_in_docs_or_cli_help():
    """Papers are cited by authors and year; no "seed 00N" a user cannot look up."""
    for p in sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]:
        for i, line in enumerate(p.read_text().splitlines(), 1):
            assert not SEED_CITATION.search(line), f"{p.name}:{i}: {line.strip()}"
            assert "seeds/" not in line, f"{p.name}:{i}: {line.strip()}"
    text = _help_texts()
    assert "tf-points" in text and "--window" in text  # the help really was collected
    assert not SEED_CITATION.search(text)
    assert "References" in (ROOT / "docs" / "guide.md").read_text()


def test_render_with_points_window_and_camera_file(tmp_path, capsys):
    src = "procedural:fractal?size=32"
    cam = tmp_path / "cam.json"
    from clipvol.scene.bookmarks import save_camera
    from clipvol.scene.camera import Camera

    save_camera(Camera.orthographic((15.5, 15.5, 15.5), (0, 0, 1), (0, -1, 0), 32, 32, size=(32, 32)), cam)
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    # --tf-points with a first point of alpha 0 at 0.5: every ray whose maximum is <= 0.5 is empty
    assert main(["render", src, "--brick", "16", "-o", str(a), "--camera", str(cam), "--size", "32x32", "--mode", "mip",
                 "--policy", "fixed", "--tf-points", "0.5:0,0,0,0;1:1,1,1,1"]) == 0
    assert "transfer function points" in capsys.readouterr().err
    # the same window as --window centre,width with the grey preset and a step opacity at 0.75
    assert main(["render", src, "--brick", "16", "-o", str(b), "--camera", str(cam), "--size", "32x32", "--mode", "mip",
                 "--policy", "fixed", "--tf", "grey", "--window", "0.75,0.5", "--opacity", "step"]) == 0
    from clipvol.bricking.generators import parse_procedural

    mip = parse_procedural(src).region(0, (0, 0, 0), (32, 32, 32)).max(axis=0)  # (y, x), camera rows follow +y
    ia, ib = np.asarray(Image.open(a))[..., 3], np.asarray(Image.open(b))[..., 3]
    # pixel centres sit on voxel centres here (orthographic, 32 px over 32 voxels), so the ray's
    # maximum is numpy's max; away from the threshold (a texel's width) the image must agree
    assert (mip < 0.5).any() and (mip > 0.52).any()
    assert (ia[mip < 0.5] == 0).all() and (ia[mip > 0.52] > 0).all()
    assert (mip < 0.74).any() and (mip > 0.76).any()
    assert (ib[mip < 0.74] == 0).all() and (ib[mip > 0.76] == 255).all()


def test_tf_save_then_load_round_trips_through_the_cli(tmp_path, capsys):
    f = tmp_path / "t.json"
    assert main(["tf", "save", "procedural:fractal?size=24", str(f), "--tf", "magma", "--tf-range", "0.2,0.9",
                 "--opacity", "flat"]) == 0
    doc = json.loads(f.read_text())
    assert doc["value_range"] == [0.2, 0.9] and doc["name"] == "magma (flat)"
    from clipvol.scene.transfer import TransferFunction

    np.testing.assert_array_equal(np.array([p[1:] for p in doc["points"]], dtype=np.float32),
                                  TransferFunction.preset("magma", (0.2, 0.9), opacity="flat").table)
    capsys.readouterr()
    assert main(["tf", "load", str(f)]) == 0
    assert "0.2 .. 0.9" in capsys.readouterr().out
    (tmp_path / "bad.json").write_text("[1, 2]")
    assert main(["tf", "load", str(tmp_path / "bad.json")]) == 2
    assert "bad.json" in capsys.readouterr().err


def test_output_in_a_missing_folder_fails_before_any_work(tmp_path, capsys):
    for argv in (["render", "procedural:fractal?size=16", "-o", str(tmp_path / "no" / "x.png")],
                 ["tf", "save", "procedural:fractal?size=16", str(tmp_path / "no" / "t.json")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "does not exist" in err and str(tmp_path / "no") in err
    assert not (tmp_path / "no").exists()


def test_bad_tf_flags_are_one_line_errors(capsys):
    for extra in (["--tf-points", "0:1,1,1"], ["--tf-range", "0,1", "--window", "0.5,1"], ["--tf", "nope"],
                  ["--tf", "missing.json"]):
        assert main(["render", "procedural:fractal?size=16", "-o", "x.png"] + extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "error" in err, err


@pytest.fixture(scope="module")
def ome_zarr(tmp_path_factory):
    """An OME-Zarr 0.5 image written by zarr-python (not by clipvol), chunks that pad the edges."""
    zarr = pytest.importorskip("zarr")
    path = tmp_path_factory.mktemp("ome") / "img.zarr"
    g = zarr.open_group(str(path), mode="w")
    a = (np.arange(50 * 40 * 30) % 251).astype(np.uint16).reshape(50, 40, 30)
    g.create_array("s0", data=a, chunks=(16, 16, 16))
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{
        "axes": [{"name": n, "type": "space"} for n in "zyx"],
        "datasets": [{"path": "s0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}
    return path, a


def test_info_describes_an_ome_zarr_it_did_not_write(ome_zarr, capsys):
    path, a = ome_zarr
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "OME-Zarr image" in out and "50x40x30" in out and "derived" in out
    files = [p for p in (path / "s0").rglob("*") if p.is_file() and p.name != "zarr.json"]
    disk = sum(p.stat().st_size for p in files)
    ratio = a.nbytes / disk  # every chunk is written; the true ratio counts the level's voxels only
    assert f"compression ratio {ratio:.2f}" in out


def test_info_compression_ratio_ignores_padding_and_shows_nan_counts(tmp_path, capsys):
    from clipvol.bricking.pipeline import brick_volume

    rng = np.random.default_rng(1)
    v = rng.normal(size=(20, 20, 20)).astype(np.float32)  # 16^3 bricks: most of the grid is padding
    v[:3] = np.nan
    v[5, 5, 5] = np.inf
    path = tmp_path / "s.zarr"
    brick_volume(v, path, brick=16, progress=False, workers=1)
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    files = [p for p in (path / "0").rglob("*") if p.is_file() and p.name != "zarr.json"]
    assert len(files) == 8
    line0 = next(l for l in out.splitlines() if l.split()[:1] == ["0"])
    assert line0.split()[-1] == f"{v.nbytes / sum(p.stat().st_size for p in files):.2f}"
    assert f"{int(np.isnan(v).sum()):,} NaN and 1 Inf" in out


def test_check_prints_no_runtime_warning_on_all_nan_bricks(tmp_path):
    from clipvol.bricking.pipeline import brick_volume

    v = np.full((16, 16, 16), np.nan, dtype=np.float32)
    v[:8, :8, :8] = 1.0  # bricks of 8: seven of the eight level-0 bricks hold NaN only
    path = tmp_path / "n.zarr"
    brick_volume(v, path, brick=8, progress=False, workers=1)
    r = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "clipvol.tools.cli", "check", str(path),
                        "--samples", "64"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Warning" not in r.stderr and "ok" in r.stdout


def test_every_command_is_listed():
    assert "tf" in COMMANDS
