"""A one-shot output is what was asked, or the exit is non-zero: ``slice --level 0`` and a fixed-level
``render`` on a store larger than ``--memory-budget`` once drew tiles from coarser levels with exit
0; they now exit 3 naming the budget and what to raise it to, ``--allow-partial`` keeps the coarser
picture and says so, and at the budget suggested the output is the full-resolution one.

References: the source array (numpy) for the slice's values; for the render, the same render with a
budget that holds the whole store.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("complete")
    z, y, x = np.indices((48, 64, 56))
    vol = (1000 + 500 * np.sin(z / 5.0) * np.cos(y / 7.0) + 300 * np.sin(x / 4.0)).astype(np.float32)
    np.save(root / "v.npy", vol)
    assert main(["brick", str(root / "v.npy"), str(root / "v.zarr"), "--brick", "8", "--quiet"]) == 0
    return root / "v.zarr", vol


def _suggested(err: str) -> str:
    m = re.search(r"raise --memory-budget .*?try ([\d.]+) ([kMG]B)\)", err)
    assert m, err
    return m[1] + m[2]


def test_slice_at_level_0_beyond_the_budget_exits_3_naming_it_and_the_suggestion_is_exact(built, tmp_path, capsys):
    store, vol = built
    npy = tmp_path / "s.npy"
    args = ["slice", str(store), "--axis", "axial", "--index", "20", "--level", "0", "--npy", str(npy)]
    capsys.readouterr()
    assert main([*args, "--memory-budget", "64KB"]) == 3
    err = capsys.readouterr().err
    assert "not complete at the level asked" in err and "--memory-budget" in err and "Traceback" not in err
    assert not npy.exists()
    budget = _suggested(err)
    assert main([*args, "--memory-budget", "64KB", "--allow-partial"]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "written with the coarser bricks (--allow-partial)" in err
    coarse = np.load(npy)
    assert not np.array_equal(coarse, vol[20])  # what --allow-partial keeps: not the full-resolution slice
    npy.unlink()
    assert main([*args, "--memory-budget", budget]) == 0
    np.testing.assert_array_equal(np.load(npy), vol[20])


def test_fixed_level_render_beyond_the_budget_exits_3_and_the_suggestion_completes_it(built, tmp_path, capsys):
    store, vol = built
    common = ["render", str(store), "--size", "64x64", "--policy", "fixed", "--level", "0", "--view", "front",
              "--ortho", "--tf", "grey"]
    capsys.readouterr()
    assert main([*common, "--out", str(tmp_path / "a.png"), "--memory-budget", "64KB"]) == 3
    err = capsys.readouterr().err
    assert "not complete at the level asked" in err and "lie outside the clip-texture's windows" in err
    assert not (tmp_path / "a.png").exists()
    assert main([*common, "--out", str(tmp_path / "a.png"), "--memory-budget", _suggested(err)]) == 0
    assert main([*common, "--out", str(tmp_path / "ref.png"), "--memory-budget", "256MB"]) == 0
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "a.png")),
                                  np.asarray(Image.open(tmp_path / "ref.png")))
