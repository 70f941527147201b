"""A second channel is drawn at the level of the first: its texture budget is the one the first
channel is drawn under (``--texture-budget``), not an overlay's small default. Reference: the
level sizes read with zarr-python (the finest level whose float32 texture fits the budget)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import zarr

from clipvol.tools.cli import main


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    d = tmp_path_factory.mktemp("chan")
    data = (np.random.default_rng(2).random((2, 48, 96, 96)) * 4000).astype(np.uint16)
    np.save(d / "s.npy", data)
    assert main(["brick", str(d / "s.npy"), str(d / "s.zarr"), "--brick", "16", "--quiet"]) == 0
    return d / "s.zarr"


def _finest_fitting(root, budget: int) -> int:
    g = zarr.open_group(str(root), mode="r")
    shapes = [g[str(L)].shape[1:] for L in range(len(g.attrs["ome"]["multiscales"][0]["datasets"]))]
    return next(L for L, s in enumerate(shapes) if int(np.prod(s)) * 4 <= budget)


@pytest.mark.gl
@pytest.mark.parametrize("budget,nbytes", [("2MB", 2_000_000), ("300KB", 300_000)])
def test_second_channel_follows_the_texture_budget(stack, tmp_path, capsys, budget, nbytes):
    assert main(["render", str(stack), "--channels", "0:green,1:magenta", "--out", str(tmp_path / "c.png"),
                 "--size", "48x48", "--texture-budget", budget]
                + (["--allow-partial"] if budget == "300KB" else [])) == 0  # the first channel cannot be whole in 300 KB
    err = capsys.readouterr().err
    level = int(re.search(r"channel 1 \(level (\d+)\)", err).group(1))
    assert level == _finest_fitting(stack, nbytes)
    if budget == "2MB":  # level 0 fits whole: the second channel is never coarser than the first
        first = [int(v) for v in re.findall(r"L(\d+): \d+", err.split("bricks drawn", 1)[1].split("\n", 1)[0])]
        assert level == 0 and level <= min(first)


@pytest.mark.gl
def test_an_explicit_overlay_budget_still_rules(stack, tmp_path, capsys):
    assert main(["render", str(stack), "--channels", "0:green,1:magenta", "--out", str(tmp_path / "c.png"),
                 "--size", "48x48", "--texture-budget", "2MB", "--overlay-budget", "300KB"]) == 0
    assert f"channel 1 (level {_finest_fitting(stack, 300_000)})" in capsys.readouterr().err
