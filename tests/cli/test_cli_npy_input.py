"""A ``.npy`` that cannot be mapped is one line naming the file and the fault, wherever a ``.npy`` is
read (issue 40, item 4): as the input of ``brick`` (3-D and 4-D), of ``export`` and ``info`` (the numpy
loader), with nothing written.

References: the files are made here with ``np.save`` and cut with plain byte slicing; the expected
byte counts come from the array's own ``nbytes``.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.tools.cli import main
from test_cli_brick import _one_error_line  # one line, no traceback, naming what is wrong


def _object_npy(path):
    np.save(path, np.array([[[1, "a"], [None, 2.5]]], dtype=object), allow_pickle=True)


def _truncated_npy(path, shape=(6, 8, 8)):
    np.save(path, np.arange(np.prod(shape), dtype=np.float32).reshape(shape))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 100])


def _cut_header(path):
    np.save(path, np.zeros((4, 4, 4), np.uint8))
    path.write_bytes(path.read_bytes()[:30])


CASES = {"object": (_object_npy, "Python objects"), "truncated": (_truncated_npy, "truncated"),
         "header": (_cut_header, "header is cut short")}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("command", ["brick", "export", "render"])
def test_a_bad_npy_is_one_line_and_nothing_is_written(tmp_path, capsys, case, command):
    make, words = CASES[case]
    src = tmp_path / "bad.npy"
    make(src)
    before = set(tmp_path.iterdir())
    args = {"brick": ["brick", str(src), str(tmp_path / "o.zarr"), "--quiet"],
            "export": ["export", str(src), "--box", "0:2,0:2,0:2", "--out", str(tmp_path / "e.npy"), "--quiet"],
            "render": ["render", str(src), "--size", "16x16", "-o", str(tmp_path / "a.png")]}[command]
    assert main(args) == 2
    _one_error_line(capsys, "bad.npy", words)
    assert set(tmp_path.iterdir()) == before


def test_truncated_npy_names_the_bytes_it_lacks(tmp_path):
    from clipvol.bricking.npy import npy_header
    from clipvol.errors import InputFormatError

    p = tmp_path / "t.npy"
    _truncated_npy(p, (6, 8, 8))
    need = np.zeros((6, 8, 8), np.float32).nbytes
    with pytest.raises(InputFormatError, match=f"{need} bytes of data, but it holds {need - 100}"):
        npy_header(p)


def test_a_4d_npy_that_is_truncated_is_refused_by_the_channel_build(tmp_path, capsys):
    _truncated_npy(tmp_path / "c.npy", (2, 4, 8, 8))
    assert main(["brick", str(tmp_path / "c.npy"), str(tmp_path / "o.zarr"), "--quiet"]) == 2
    _one_error_line(capsys, "c.npy", "truncated")
    assert not (tmp_path / "o.zarr").exists()
