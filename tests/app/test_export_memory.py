"""``export_region`` streams: exporting a 64 MiB region to ``.npy`` or ``.nii.gz`` raises the process's
peak resident memory by about one slab of bricks (8 MiB here), far below the region's size (the
kernel's own peak counter, ``VmHWM`` after a reset, against the region's bytes)."""

from __future__ import annotations

import numpy as np
import pytest

import clipvol
from clipvol.app.export import export_region, region_from_voxels

pytestmark = pytest.mark.slow

N = 256  # 256^3 float32 = 64 MiB


def _status(key: str) -> int:
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(key)


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    path = tmp_path_factory.mktemp("mem") / "big.npy"
    mm = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(N, N, N))
    for z in range(0, N, 32):
        mm[z:z + 32] = np.random.default_rng(z).random((32, N, N), dtype=np.float32)
    mm.flush()
    del mm
    return path


@pytest.mark.parametrize("suffix", [".npy", ".nii.gz"])
def test_peak_memory_is_a_slab_not_the_region(big, tmp_path, suffix):
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")  # reset VmHWM to the current resident size
    except OSError:
        pytest.skip("needs Linux's /proc/self/clear_refs to reset the peak resident size")
    vol = clipvol.open(big, brick=32)
    region = region_from_voxels(vol, (0, 0, 0), (N, N, N))
    vol.level(0)[0:1, 0:1, 0:1]  # imports and first-brick set-up before the baseline
    import nibabel  # noqa: F401  (imported before the baseline, not counted)
    import tifffile  # noqa: F401
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    before = _status("VmRSS")
    export_region(vol, region, tmp_path / f"out{suffix}")
    growth = _status("VmHWM") - before
    assert growth < 24 * 2**20, f"peak grew by {growth / 2**20:.1f} MiB for a {N ** 3 * 4 / 2**20:.0f} MiB region"
    if suffix == ".npy":
        out = np.load(tmp_path / "out.npy", mmap_mode="r")
        src = np.load(big, mmap_mode="r")
        np.testing.assert_array_equal(out[::37, ::41], src[::37, ::41])
