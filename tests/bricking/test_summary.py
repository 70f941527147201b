"""Summary tables: histograms and parent-child correspondence tables equal numpy counts of the
store's own voxels (read with zarr-python), NaN kept apart, resumable per level, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.summary import SUMMARY_GROUP, SummaryMissingError, build_summary, open_summary


def _levels(path, n):
    g = zarr.open_group(str(path), mode="r")
    return [np.asarray(g[str(L)][...]) for L in range(n)]


def _quantise_uniform(v, lo, hi):
    t = np.floor((np.asarray(v, np.float64) - lo) / (hi - lo) * 256)
    return np.clip(np.nan_to_num(t, nan=0, posinf=255, neginf=0), 0, 255).astype(np.int64)


def _check_tables(path, quant):
    tabs = open_summary(path)
    pyr = tabs.pyramid
    levels = _levels(path, pyr.num_levels)
    B = pyr.brick_shape
    for L in range(pyr.num_levels):
        full = levels[L]
        for idx in np.ndindex(*pyr.grid(L)):
            sl = tuple(slice(i * b, (i + 1) * b) for i, b in zip(idx, B))
            vals = full[sl].reshape(-1)
            nan = np.isnan(vals) if vals.dtype.kind == "f" else np.zeros(vals.shape, bool)
            ref = np.bincount(quant(vals[~nan]), minlength=256)
            np.testing.assert_array_equal(tabs.histogram[L][idx], ref, err_msg=f"histogram of brick {L} {idx}")
            assert tabs.nan_count[L][idx] == nan.sum()
            if L == pyr.num_levels - 1:
                continue
            # the parent voxel of child voxel g (global index at level L) is g // 2 at level L + 1
            g = [np.arange(i * b, min((i + 1) * b, s)) for i, b, s in zip(idx, B, full.shape)]
            child = full[np.ix_(*g)].reshape(-1)
            parent = levels[L + 1][np.ix_(*(a // 2 for a in g))].reshape(-1)
            ok = np.ones(child.shape, bool)
            if child.dtype.kind == "f":
                ok = ~np.isnan(child) & ~np.isnan(parent)
            want = {}
            for p, c in zip(quant(parent[ok]).tolist(), quant(child[ok]).tolist()):
                want[(p, c)] = want.get((p, c), 0) + 1
            p, c, n = tabs.pairs(L, idx)
            got = {(int(a), int(b)): int(k) for a, b, k in zip(p, c, n)}
            assert got == want, f"correspondence table of brick {L} {idx}"


def test_uint8_tables_equal_numpy_counts(tmp_path, rng):
    vol = rng.integers(0, 256, size=(21, 17, 30), dtype=np.uint8)
    vol[:8] = 0  # flat background
    path = tmp_path / "u8.zarr"
    brick_volume(vol, path, brick=8, progress=False)
    tabs = open_summary(path)
    assert tabs.quantiser.method == "identity"
    _check_tables(path, lambda v: np.asarray(v).astype(np.int64))


def test_float_tables_are_uniform_with_nan_apart(tmp_path, rng):
    vol = rng.normal(size=(18, 16, 20)).astype(np.float32)
    vol[2:5, 3:9, 1:4] = np.nan
    vol[10, 10, 10] = np.inf
    path = tmp_path / "f.zarr"
    brick_volume(vol, path, brick=8, progress=False)
    tabs = open_summary(path)
    lo, hi = tabs.pyramid.value_range
    assert tabs.quantiser.method == "uniform" and (tabs.quantiser.lo, tabs.quantiser.hi) == (lo, hi)
    _check_tables(path, lambda v: _quantise_uniform(v, lo, hi))
    assert sum(int(n.sum()) for n in tabs.nan_count[:1]) == int(np.isnan(vol).sum())


def test_summarize_resumes_an_interrupted_build(tmp_path, rng):
    vol = rng.integers(0, 200, size=(32, 32, 32), dtype=np.uint8)
    path = tmp_path / "s.zarr"
    brick_volume(vol, path, brick=8, progress=False)
    before = open_summary(path)
    # simulate an interruption after level 0: later levels gone, completion marker not written
    zj = path / SUMMARY_GROUP / "zarr.json"
    meta = json.loads(zj.read_text())
    meta["attributes"].update(levels_done=[0], complete=False)
    zj.write_text(json.dumps(meta))
    import shutil

    shutil.rmtree(path / SUMMARY_GROUP / "1")
    with pytest.raises(SummaryMissingError, match="clipvol summarize"):
        open_summary(path)
    stamp = (path / SUMMARY_GROUP / "0" / "histogram" / "zarr.json").stat().st_mtime_ns
    build_summary(path, progress=False)
    assert (path / SUMMARY_GROUP / "0" / "histogram" / "zarr.json").stat().st_mtime_ns == stamp  # kept, not redone
    after = open_summary(path)
    for L in range(before.pyramid.num_levels):
        np.testing.assert_array_equal(after.histogram[L], before.histogram[L])
        if before.pairs_code[L] is not None:
            np.testing.assert_array_equal(after.pairs_code[L], before.pairs_code[L])
            np.testing.assert_array_equal(after.pairs_count[L], before.pairs_count[L])


def test_store_without_tables_names_the_command(tmp_path):
    path = tmp_path / "n.zarr"
    brick_volume(np.zeros((8, 8, 8), np.uint8), path, brick=8, progress=False, summary=False)
    with pytest.raises(SummaryMissingError, match=r"clipvol summarize .*n\.zarr"):
        open_summary(path)


def test_cli_summarize_and_info(tmp_path, capsys, rng):
    from clipvol.tools.cli import main

    path = tmp_path / "c.zarr"
    brick_volume(rng.integers(0, 9, size=(16, 16, 16), dtype=np.uint8), path, brick=8, progress=False, summary=False)
    assert main(["info", str(path)]) == 0
    assert "clipvol summarize" in capsys.readouterr().out
    assert main(["summarize", str(path), "--quiet"]) == 0
    open_summary(path)
    assert main(["info", str(path)]) == 0
    assert "% of the bricks on disk" in capsys.readouterr().out
    assert main(["summarize", str(tmp_path / "missing.zarr"), "--quiet"]) == 2


def test_a_damaged_chunk_is_refused_naming_it(tmp_path, rng):
    """The tables read bricks with their crc32c checked: a flipped byte stops the build, naming the
    chunk, and no complete tables are left as if built from it."""
    from clipvol.errors import BrickIntegrityError

    vol = rng.integers(1, 256, size=(16, 16, 16), dtype=np.uint8)
    path = tmp_path / "bad.zarr"
    brick_volume(vol, path, brick=8, progress=False, summary=False)
    chunk = path / "0" / "c" / "1" / "0" / "1"
    raw = bytearray(chunk.read_bytes())
    raw[len(raw) // 2] ^= 0x55
    chunk.write_bytes(bytes(raw))
    with pytest.raises(BrickIntegrityError, match="0/c/1/0/1"):
        build_summary(path, progress=False)
    with pytest.raises(SummaryMissingError):
        open_summary(path)
