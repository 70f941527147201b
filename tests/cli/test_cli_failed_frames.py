"""A frame command whose view lost bricks says so: exit status 3 naming the bricks and causes, no
image written; ``--allow-partial`` writes it with the holes hatched and says so on stderr.

References: the damage done on disk here (chunk files overwritten, a level's ``zarr.json``
edited with json), the PNG read back with pillow.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from PIL import Image

from clipvol.bricking.pipeline import brick_volume
from clipvol.render.failures import HATCH_RGBA
from clipvol.tools.cli import main

pytestmark = pytest.mark.gl

FIXED = ["--policy", "fixed", "--level", "0", "--size", "32x32", "--ortho", "--view", "front", "--tf", "grey"]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("frames") / "v.zarr"
    vol = np.random.default_rng(5).integers(10, 250, size=(32, 32, 32)).astype(np.uint8)
    brick_volume(vol, out, brick=8, progress=False, workers=1, summary=False)
    return out


@pytest.fixture
def store(built, tmp_path):
    dst = tmp_path / "s.zarr"
    shutil.copytree(built, dst)
    return dst


def _damage_chunks(root, level, pick=lambda z, y, x: True):
    n = 0
    for f in sorted((root / str(level) / "c").rglob("*")):
        if f.is_file() and pick(*(int(p) for p in f.relative_to(root / str(level) / "c").parts)):
            f.write_bytes(b"garbage")
            n += 1
    return n


def _swap_codecs(root, level):
    p = root / str(level) / "zarr.json"
    meta = json.loads(p.read_text())
    meta["codecs"] = [meta["codecs"][1], meta["codecs"][0], *meta["codecs"][2:]]
    p.write_text(json.dumps(meta))


def _err(capsys):
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def test_a_level_whose_zarr_json_is_edited_is_refused_naming_the_level(store, tmp_path, capsys):
    """The manifest pins each level's metadata: an edited codec chain is refused on opening (it
    was once drawn wholly from the next level, exit 0)."""
    _swap_codecs(store, 0)
    out = tmp_path / "a.png"
    assert main(["render", str(store), "-o", str(out), *FIXED]) == 2
    err = _err(capsys)
    assert "metadata differs from the store's manifest: level 0: codecs differ" in err
    assert not out.exists()


def test_failed_bricks_drawn_from_ancestors_exit_3_unless_allow_partial(store, tmp_path, capsys):
    """A one-shot render promises what was asked: level 0. Corrupt level-0 chunks with sound
    ancestors are refused (exit 3); --allow-partial draws the ancestors and says so."""
    n = _damage_chunks(store, 0, lambda z, y, x: z == 0)
    out = tmp_path / "a.png"
    assert main(["render", str(store), "-o", str(out), *FIXED]) == 3
    err = _err(capsys)
    assert f"{n} brick(s) of the view failed ({n} drawn from a coarser verified ancestor, not at the level asked)" in err
    assert "--allow-partial" in err and not out.exists()
    assert main(["render", str(store), "-o", str(out), *FIXED, "--allow-partial"]) == 0
    assert f"note: {n} failed brick(s) drawn from a coarser verified ancestor" in _err(capsys)
    assert out.exists()


@pytest.mark.parametrize("key,value,needle", [("data_type", "uint16", "dtype"), ("chunk_grid", None, "chunks")])
def test_a_level_zarr_json_with_another_dtype_or_chunk_shape_is_one_line(store, tmp_path, capsys, key, value, needle):
    p = store / "1" / "zarr.json"
    meta = json.loads(p.read_text())
    if key == "chunk_grid":
        meta["chunk_grid"]["configuration"]["chunk_shape"] = [4, 8, 8]
    else:
        meta[key] = value
    p.write_text(json.dumps(meta))
    assert main(["render", str(store), "-o", str(tmp_path / "a.png"), *FIXED]) == 2
    err = _err(capsys).strip()
    assert len(err.splitlines()) == 1 and "level 1" in err and needle in err
    assert not (tmp_path / "a.png").exists()


def test_every_level_broken_exits_3_naming_bricks_and_writes_nothing(store, tmp_path, capsys):
    for L in range(3):
        _damage_chunks(store, L)
    out = tmp_path / "a.png"
    assert main(["render", str(store), "-o", str(out), *FIXED]) == 3
    err = _err(capsys)
    line = [ln for ln in err.splitlines() if "error" in ln]
    assert len(line) == 1 and "64 brick(s)" in line[0] and "brick (level 0, " in line[0] and "and 61 more" in line[0]
    assert "0/c/" in line[0]  # the cause names the chunk
    assert not out.exists()


def test_every_chunk_of_every_level_corrupt_exits_3(store, tmp_path, capsys):
    for L in range(3):
        _damage_chunks(store, L)
    assert main(["render", str(store), "-o", str(tmp_path / "a.png"), *FIXED]) == 3
    err = _err(capsys)
    # the cause: each 7-byte chunk is refused by its size in the store's manifest before its checksum
    assert "7 bytes" in err and "manifest says" in err, err


def test_a_brick_and_its_ancestors_corrupt_exit_3_and_allow_partial_hatches_it(store, tmp_path, capsys):
    # the column of bricks (z, 1, 2) and their ancestors: its pixels have nothing to draw
    _damage_chunks(store, 0, lambda z, y, x: (y, x) == (1, 2))
    _damage_chunks(store, 1, lambda z, y, x: (y, x) == (0, 1))
    _damage_chunks(store, 2)
    out = tmp_path / "a.png"
    assert main(["render", str(store), "-o", str(out), *FIXED]) == 3
    err = _err(capsys)
    assert "4 brick(s) of the view failed and no verified ancestor stands in" in err
    assert "brick (level 0, 0, 1, 2)" in err and not out.exists()
    assert main(["render", str(store), "-o", str(out), *FIXED, "--allow-partial"]) == 0
    err = _err(capsys)
    assert "warning" in err and "hatched" in err and "brick (level 0, 0, 1, 2)" in err
    img = np.asarray(Image.open(out))
    red = np.all(img == HATCH_RGBA, axis=-1)
    assert red.any() and red.mean() < 0.25  # the column's footprint only (1/16 of the volume's face)


def test_slice_exits_3_and_allow_partial_writes(store, tmp_path, capsys):
    for L in range(3):
        _damage_chunks(store, L, lambda z, y, x: z == 0)
    out = tmp_path / "s.png"
    assert main(["slice", str(store), "--plane", "z=3", "-o", str(out), "--level", "0"]) == 3
    assert "no verified ancestor" in _err(capsys) and not out.exists()
    assert main(["slice", str(store), "--plane", "z=3", "-o", str(out), "--level", "0", "--allow-partial",
                 "--stats", str(tmp_path / "s.json")]) == 0
    assert "hatched" in _err(capsys) and out.exists()
    doc = json.loads((tmp_path / "s.json").read_text())
    assert len(doc["failed_bricks"]) == 16 and all(f["stand_in"] is None for f in doc["failed_bricks"])


def test_view_offscreen_exits_3(store, tmp_path, capsys):
    for L in range(3):
        _damage_chunks(store, L)
    out = tmp_path / "frames"
    assert main(["view", str(store), "--offscreen", "--frames", "2", "--size", "32x32", "--converged",
                 "--out", str(out)]) == 3
    assert "frame 0" in _err(capsys) and not list(out.glob("*.png"))
    assert main(["view", str(store), "--offscreen", "--frames", "2", "--size", "32x32", "--converged",
                 "--out", str(out), "--allow-partial"]) == 0
    assert "hatched" in _err(capsys) and len(list(out.glob("*.png"))) == 2


def test_report_exits_3(store, tmp_path, capsys):
    for L in range(3):
        _damage_chunks(store, L)
    assert main(["report", str(store), "--out", str(tmp_path / "r"), "--views", "1", "--size", "32x32",
                 "--no-plots", "--thresholds", "1", "--block-budgets", "none"]) == 3
    assert "no verified ancestor" in _err(capsys)


def test_sort_last_render_exits_3_and_allow_partial_hatches(store, tmp_path, capsys):
    for L in range(3):
        _damage_chunks(store, L, lambda z, y, x: x == 0)
    out = tmp_path / "a.png"
    sl = ["--workers", "2", "--scheduler", "inline"]
    assert main(["render", str(store), "-o", str(out), *FIXED, *sl]) == 3
    assert "no verified ancestor" in _err(capsys) and not out.exists()
    assert main(["render", str(store), "-o", str(out), *FIXED, *sl, "--allow-partial"]) == 0
    assert "hatched" in _err(capsys)
    assert np.all(np.asarray(Image.open(out)) == HATCH_RGBA, axis=-1).any()


def test_report_policy_comparison_exits_3_on_coarse_failures(tmp_path, capsys):
    """Only the coarse levels are damaged: the full-resolution reference and the threshold setting
    draw level 0, but the policy comparison's 2-brick cuts are drawn from levels 1-2 - a hole measured
    as data there would make its error figures wrong, so the report stops there too."""
    store = tmp_path / "s.zarr"
    vol = np.random.default_rng(5).integers(10, 250, size=(32, 32, 32)).astype(np.uint8)
    brick_volume(vol, store, brick=8, progress=False, workers=1)  # with the summary tables the policies need
    for L in (1, 2):
        _damage_chunks(store, L)
    args = ["report", str(store), "--out", str(tmp_path / "r"), "--views", "1", "--size", "32x32", "--no-plots",
            "--tf", "grey", "--thresholds", "0.25", "--memory-budgets", "none", "--texture-budgets", "none", "--max-errors", "none",
            "--refine", "none", "--block-budgets", "2"]
    assert main(args) == 3
    err = _err(capsys)
    assert "b=2 view 0" in err and "no verified ancestor" in err
