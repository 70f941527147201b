"""One command from a scan to a view: `clipvol view scan.nii.gz` bricks it once, then reuses the store."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from clipvol.tools.cli import main

nib = pytest.importorskip("nibabel")
pytest.importorskip("moderngl")


def test_view_bricks_a_nifti_once_then_reuses_it(tmp_path, capsys):
    data = np.random.default_rng(1).integers(0, 400, size=(20, 18, 16)).astype(np.int16)
    p = tmp_path / "scan.nii.gz"
    nib.save(nib.Nifti1Image(data, np.diag([1.0, 1.0, 2.0, 1.0])), p)
    store = tmp_path / "scan.zarr"
    args = ["view", str(p), "--store", str(store), "--offscreen", "--frames", "1", "--size", "32x32", "--out", str(tmp_path / "f")]
    assert main(args) == 0
    assert f"bricking {p} into {store}" in capsys.readouterr().out
    np.testing.assert_array_equal(zarr.open_group(str(store), mode="r")["0"][:], data.transpose(2, 1, 0))
    assert main(args) == 0
    assert f"using {store}" in capsys.readouterr().out
    # a different input aimed at the same store is refused, naming it (never overwritten silently)
    q = tmp_path / "other.nii"
    nib.save(nib.Nifti1Image(data[:8], np.eye(4)), q)
    assert main(["view", str(q), "--store", str(store), "--offscreen", "--frames", "1", "--out", str(tmp_path / "g")]) == 2
    assert str(store) in capsys.readouterr().err
