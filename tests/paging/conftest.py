"""Shared by the zarr loader's integrity tests: a store bricked from the test module's ``vol``
fixture with the module's brick edge ``B``."""

import pytest

from clipvol.bricking.pipeline import brick_volume


@pytest.fixture
def store(tmp_path, vol, request):
    path = tmp_path / "s.zarr"
    brick_volume(vol, path, brick=request.module.B, progress=False, workers=1)
    return path
