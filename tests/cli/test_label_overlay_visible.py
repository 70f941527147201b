"""``--label-overlay NAME`` with the automatic transfer function: the labels inside a head show, the
primary drawn as translucent context (as ``--overlay`` does), instead of buried under the scalp.

Reference: the label volume itself (numpy): the labelled block sits in the middle, under an opaque
bright shell; the pixel over it must carry the label's colour (red), the one beside it not.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

pytest.importorskip("moderngl")

N = 40


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    d = tmp_path_factory.mktemp("labels")
    z, y, x = np.meshgrid(*(np.arange(N, dtype=np.float64),) * 3, indexing="ij")
    r = np.sqrt((x - 19.5) ** 2 + (y - 19.5) ** 2 + (z - 19.5) ** 2)
    img = np.where(r < 17, np.where(r > 13, 100.0, 30.0), 0.0).astype(np.float32)  # a bright scalp, dim inside
    lab = np.zeros((N, N, N), np.uint8)
    lab[14:26, 14:26, 14:26] = 1  # a block deep inside
    np.save(d / "img.npy", img)
    np.save(d / "lab.npy", lab)
    assert main(["brick", str(d / "img.npy"), str(d / "head.zarr"), "--brick", "16", "--quiet",
                 "--labels", f"{d / 'lab.npy'}:organs"]) == 0
    return d / "head.zarr"


def test_labels_inside_an_opaque_shell_show_by_default(head, tmp_path):
    out = tmp_path / "l.png"
    assert main(["render", str(head), "--label-overlay", "organs", "--label-colors", "1=#ff0000", "--view", "front",
                 "--ortho", "--size", "64x64", "--out", str(out)]) == 0
    img = np.asarray(Image.open(out).convert("RGBA")).astype(int)
    centre, beside = img[32, 32], img[32, 12]  # over the block; over the shell only
    assert centre[0] - max(centre[1], centre[2]) > 60, centre  # the label's red shows (before: the scalp's colour)
    assert abs(beside[0] - beside[1]) < 30, beside  # grey context where there is no label
