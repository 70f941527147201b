"""``--overwrite`` never destroys what is not clipvol's own (issue 40, item 1): the five cases of the
issue, each checked by comparing the user's files with the bytes this test wrote before the command.

References: the bytes written here (``Path.read_bytes``), and numpy for the one export that replaces
an earlier .npy.
"""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from clipvol.tools.cli import main
from test_cli_brick import _one_error_line  # one line, no traceback, naming what is wrong


def _snapshot(root):
    """Every file under ``root`` with its bytes (the reference the tests compare against)."""
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def work(tmp_path, rng):
    v = rng.integers(0, 1000, size=(16, 16, 16)).astype(np.uint16)
    np.save(tmp_path / "u.npy", v)
    assert main(["brick", str(tmp_path / "u.npy"), str(tmp_path / "S.zarr"), "--quiet", "--brick", "8"]) == 0
    return tmp_path


def _thesis(folder):
    folder.mkdir()
    (folder / "thesis.txt").write_text("three years of work\n")
    (folder / "notes").mkdir()
    (folder / "notes" / "ch1.md").write_bytes(b"# chapter one\n")
    return {"thesis.txt": "three years of work\n"}


def test_export_onto_its_own_source_store_is_refused(work, capsys):
    before = _snapshot(work / "S.zarr")
    assert main(["export", str(work / "S.zarr"), "--box", "0:8,0:8,0:8", "--out", str(work / "S.zarr"),
                 "--overwrite", "--quiet"]) == 2
    _one_error_line(capsys, "S.zarr", "is the input")
    assert _snapshot(work / "S.zarr") == before


def test_export_inside_its_source_store_is_refused(work, capsys):
    before = _snapshot(work / "S.zarr")
    assert main(["export", str(work / "S.zarr"), "--box", "0:8,0:8,0:8", "--out", str(work / "S.zarr" / "crop.npy"),
                 "--quiet"]) == 2
    _one_error_line(capsys, "crop.npy", "inside the input")
    assert _snapshot(work / "S.zarr") == before


def test_brick_npy_onto_itself_is_refused(work, capsys):
    before = (work / "u.npy").read_bytes()
    assert main(["brick", str(work / "u.npy"), str(work / "u.npy"), "--overwrite", "--quiet"]) == 2
    _one_error_line(capsys, "u.npy", "is the input")
    assert (work / "u.npy").read_bytes() == before
    assert not (work / "u.npy.lock").exists()


def test_brick_nifti_onto_itself_is_refused(tmp_path, capsys):
    nib = pytest.importorskip("nibabel")
    p = tmp_path / "head.nii.gz"
    nib.save(nib.Nifti1Image(np.arange(8 * 8 * 8, dtype=np.int16).reshape(8, 8, 8), np.eye(4)), p)
    before = p.read_bytes()
    for extra in ([], ["--overwrite"]):
        assert main(["brick", str(p), str(p), "--quiet", *extra]) == 2
        _one_error_line(capsys, "head.nii.gz", "is the input")
        assert p.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["head.nii.gz"]


@pytest.mark.parametrize("command", ["brick", "export"])
def test_a_folder_that_is_not_a_store_is_never_removed(work, capsys, command):
    out = work / ("notes" if command == "brick" else "notes.zarr")
    _thesis(out)
    before = _snapshot(out)
    args = (["brick", str(work / "u.npy"), str(out), "--quiet"] if command == "brick" else
            ["export", str(work / "S.zarr"), "--box", "0:8,0:8,0:8", "--out", str(out), "--quiet"])
    assert main(args) == 2  # without the flag: the flag is not suggested, since it would be refused
    err = capsys.readouterr().err
    assert "--overwrite" not in err and "thesis.txt" in err and "notes/" in err, err
    assert main(args + ["--overwrite"]) == 2
    _one_error_line(capsys, "refusing to overwrite", "not a clipvol store", "thesis.txt", "notes/")
    assert _snapshot(out) == before


def test_a_folder_holding_the_input_is_never_removed(work, capsys):
    out = work / "proj"
    out.mkdir()
    (out / "in.npy").write_bytes((work / "u.npy").read_bytes())
    assert main(["brick", str(out / "in.npy"), str(out), "--overwrite", "--quiet"]) == 2
    _one_error_line(capsys, "holds the input", "in.npy")
    assert (out / "in.npy").read_bytes() == (work / "u.npy").read_bytes()


def test_brick_inside_its_input_store_is_named_as_such(work, capsys):
    """``brick S S/inner.zarr`` used to build into the input and then blame "the input changed"."""
    before = _snapshot(work / "S.zarr")
    assert main(["brick", str(work / "S.zarr"), str(work / "S.zarr" / "inner.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "inner.zarr", "lies inside the input")
    assert _snapshot(work / "S.zarr") == before


def test_a_store_with_a_foreign_file_is_not_replaced(work, capsys):
    (work / "S.zarr" / "notes").mkdir()
    (work / "S.zarr" / "notes" / "a.txt").write_bytes(b"mine")
    assert main(["brick", str(work / "u.npy"), str(work / "S.zarr"), "--overwrite", "--quiet", "--brick", "8"]) == 2
    _one_error_line(capsys, "refusing to overwrite", "notes/")
    assert (work / "S.zarr" / "notes" / "a.txt").read_bytes() == b"mine"


def test_what_overwrite_does_replace(work, capsys):
    """A clipvol store, an empty folder and a file of the output's kind are replaced."""
    assert main(["brick", str(work / "u.npy"), str(work / "S.zarr"), "--overwrite", "--quiet", "--brick", "8"]) == 0
    (work / "empty").mkdir()
    assert main(["brick", str(work / "u.npy"), str(work / "empty"), "--overwrite", "--quiet", "--brick", "8"]) == 0
    v = np.load(work / "u.npy")
    np.save(work / "old.npy", np.zeros(3))
    assert main(["export", str(work / "S.zarr"), "--box", "0:8,0:8,0:8", "--out", str(work / "old.npy"),
                 "--quiet"]) == 2
    _one_error_line(capsys, "old.npy", "pass --overwrite")
    assert main(["export", str(work / "S.zarr"), "--box", "0:8,0:8,0:8", "--out", str(work / "old.npy"),
                 "--overwrite", "--quiet"]) == 0
    np.testing.assert_array_equal(np.load(work / "old.npy"), v[:8, :8, :8])


@pytest.mark.parametrize("suffix,other", [(".nii.gz", b"not gzip"), (".tif", b"\x93NUMPY fake"), (".npy", b"II*\x00tiff")])
def test_a_file_of_another_kind_is_not_replaced(work, capsys, suffix, other):
    out = work / f"x{suffix}"
    out.write_bytes(other)
    assert main(["export", str(work / "S.zarr"), "--box", "0:8,0:8,0:8", "--out", str(out), "--overwrite",
                 "--quiet"]) == 2
    _one_error_line(capsys, "refusing to overwrite", out.name)
    assert out.read_bytes() == other


def test_a_gzipped_nifti_is_recognised_as_its_kind(work):
    from clipvol.bricking.output_guard import replace_refusal

    nib = pytest.importorskip("nibabel")
    p = work / "a.nii.gz"
    nib.save(nib.Nifti1Image(np.zeros((2, 2, 2), np.int16), np.eye(4)), p)
    assert replace_refusal(p, "nii.gz") is None
    assert replace_refusal(p, "npy") is not None
    (work / "b.nii.gz").write_bytes(gzip.compress(b"plain text, not a header" * 20))
    assert "not a gzipped NIfTI" in replace_refusal(work / "b.nii.gz", "nii.gz")


@pytest.mark.parametrize("args", [
    ["slice", "{npy}", "--npy", "{npy}"],  # wrote the slice over its own input, exit 0
    ["slice", "{store}", "--out", "{store}/z.png"],
    ["render", "{store}", "--size", "16x16", "-o", "{store}/a.png"],
    ["report", "{store}", "--out", "{store}"],
    ["view", "{store}", "--offscreen", "--frames", "1", "--size", "16x16", "--out", "{store}/frames"],
], ids=["slice-npy-over-input", "slice-png-in-store", "render-in-store", "report-into-store", "view-into-store"])
def test_drawing_commands_never_write_into_or_over_their_input(work, capsys, args):
    before = _snapshot(work)
    argv = [a.format(npy=work / "u.npy", store=work / "S.zarr") for a in args]
    assert main(argv) == 2
    _one_error_line(capsys, "the input")
    assert _snapshot(work) == before
