"""``--tf-range -5,5`` (no ``=``) on a statistical map keeps the diverging colour map the automatic
transfer function picks for signed data, with the user's window: blue where numpy says the map is
strongly negative, red where strongly positive (before: a grey ramp, "a grey fog").
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.tools.cli import main

nib = pytest.importorskip("nibabel")
pytest.importorskip("moderngl")


def test_a_window_on_a_zmap_keeps_the_diverging_map(tmp_path):
    i, j, k = np.meshgrid(*(np.arange(32, dtype=np.float64),) * 3, indexing="ij")
    z = 6 * np.exp(-((i - 10) ** 2 + (j - 16) ** 2 + (k - 16) ** 2) / 18) \
        - 6 * np.exp(-((i - 22) ** 2 + (j - 16) ** 2 + (k - 16) ** 2) / 18)  # + blob at low i, - at high i
    nib.save(nib.Nifti1Image(z.astype(np.float32), np.eye(4)), tmp_path / "z.nii.gz")
    out = tmp_path / "z.png"
    assert main(["render", str(tmp_path / "z.nii.gz"), "--store", str(tmp_path / "z.zarr"), "--tf-range", "-5,5",
                 "--view", "anterior", "--ortho", "--size", "64x64", "--no-labels", "--out", str(out)]) == 0
    img = np.asarray(Image.open(out).convert("RGBA")).astype(int)
    seen = img[..., 3] > 60
    red = seen & (img[..., 0] - img[..., 2] > 60)
    blue = seen & (img[..., 2] - img[..., 0] > 60)
    assert red.sum() > 20 and blue.sum() > 20
    # identity affine: low i is low RAS x, the patient's left, on the image's right in the anterior view
    assert np.nonzero(red)[1].mean() > np.nonzero(blue)[1].mean() + 5
