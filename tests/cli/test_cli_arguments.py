"""Absurd or misplaced arguments end in one line and a non-zero exit, never a traceback or a
silently clamped value: a store given ``--brick``, a damaged summary table, ``--threads`` and
``--frames`` out of bounds, point coordinates beyond float range.

References: the store and the files on disk (checked to be absent or untouched after a refusal).
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.tools.cli import main


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert "Traceback" not in err
    assert len(lines) == 1, err
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("args") / "v.zarr"
    vol = np.random.default_rng(1).integers(0, 255, size=(32, 32, 32)).astype(np.uint8)
    brick_volume(vol, out, brick=8, progress=False, workers=1)
    return out


def test_brick_option_for_a_store_is_refused(built, tmp_path, capsys):
    assert main(["render", str(built), "-o", str(tmp_path / "a.png"), "--brick", "16", "--size", "16x16"]) == 2
    _one_error_line(capsys, "v.zarr", "--brick")
    assert main(["slice", str(built), "-o", str(tmp_path / "a.png"), "--brick", "16"]) == 2
    _one_error_line(capsys, "--brick")
    assert not (tmp_path / "a.png").exists()


@pytest.mark.gl
def test_image_policy_with_a_summary_level_missing_is_one_line(built, tmp_path, capsys):
    store = tmp_path / "s.zarr"
    shutil.copytree(built, store)
    shutil.rmtree(store / "clipvol_summary" / "1")
    assert main(["render", str(store), "-o", str(tmp_path / "a.png"), "--policy", "image", "--size", "16x16"]) == 2
    _one_error_line(capsys, "clipvol_summary", "missing", "clipvol summarize --overwrite")


@pytest.mark.parametrize("command", ["render", "slice"])
@pytest.mark.parametrize("threads", ["100000", "0"])
def test_threads_out_of_bounds(built, tmp_path, capsys, command, threads):
    assert main([command, str(built), "-o", str(tmp_path / "a.png"), "--threads", threads]) == 2
    _one_error_line(capsys, "threads", "1..256", threads)


@pytest.mark.parametrize("frames,out,needles", [
    ("100000000", "frames", ["--frames", "1..86400"]),
    ("0", "frames", ["--frames", "1..86400"]),
    ("40000", "a.gif", ["--frames", "GIF", "in memory"]),
])
def test_frames_out_of_bounds(built, tmp_path, capsys, frames, out, needles):
    assert main(["view", str(built), "--offscreen", "--frames", frames, "--out", str(tmp_path / out)]) == 2
    _one_error_line(capsys, *needles)
    assert not (tmp_path / out).exists()


@pytest.mark.parametrize("bad", [1e300, -1e300, 1e31, np.inf, np.nan])
def test_points_beyond_float_range_are_refused_not_stored_as_inf(tmp_path, capsys, bad):
    pts = np.random.default_rng(0).random((500, 4))
    pts[7, 1] = bad
    np.save(tmp_path / "p.npy", pts)
    assert main(["brick-points", str(tmp_path / "p.npy"), str(tmp_path / "p.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "p.npy", "row 7", "1e+30")
    assert not (tmp_path / "p.zarr").exists()


@pytest.mark.parametrize("argv, dest, want", [
    (["render", "s.zarr", "--tf-range", "-5,5"], "tf_range", (-5.0, 5.0)),
    (["render", "s.zarr", "--tf-range", "-1e-3,.5"], "tf_range", (-1e-3, 0.5)),
    (["render", "s.zarr", "--crop", "-60,-40,-30,60,80,40"], "crop", "-60,-40,-30,60,80,40"),
    (["render", "s.zarr", "--eye", "-300,0,20"], "eye", (-300.0, 0.0, 20.0)),
    (["slice", "s.zarr", "--through", "-2,5,46"], "through", (-2.0, 5.0, 46.0)),
    (["slice", "s.zarr", "--poi", "-.5,0,1"], "poi", (-0.5, 0.0, 1.0)),
    (["render", "s.zarr", "--tf-points", "-200:0,0,0,0;300:1,1,1,1"], "tf_points", "-200:0,0,0,0;300:1,1,1,1"),
])
def test_values_starting_with_a_minus_need_no_equals_sign(argv, dest, want):
    # argparse alone reads "-5,5" as an unknown option: "expected one argument"
    from clipvol.tools.cli import build_parser

    args = build_parser().parse_args(argv + ["-o", "a.png"])
    assert getattr(args, dest) == want


def test_a_real_short_option_after_a_value_flag_is_still_an_option(capsys):
    from clipvol.tools.cli import build_parser

    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(["render", "s.zarr", "--tf-range", "-o", "a.png"])
    assert e.value.code == 2
    _one_error_line(capsys, "--tf-range")
