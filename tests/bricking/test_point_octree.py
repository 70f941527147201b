"""Point octree build: the invariant on hard input, Morton keys, representatives, readers, bad input.

References are independent of the code under test: the input arrays themselves, a bit-by-bit
Morton loop, a brute-force nearest-point search, and files written by each format's own library.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.point_sources import ArrayPointSource, open_point_source
from clipvol.bricking.point_store import build_point_store, check_point_store, open_point_store, read_node_table
from clipvol.bricking.points import GEO_BITS, morton_decode, morton_encode, node_box
from clipvol.errors import ClipvolError, InputFormatError, OutputExistsError

from optional import POINT_READERS


def _hard_points(rng, n=6000):
    """Clustered points with exact duplicates, a pile of 300 coincident points and near-coincident ones."""
    c = rng.random((6, 3))
    xyz = c[rng.integers(0, 6, n)] + rng.normal(scale=0.01, size=(n, 3))
    xyz[:300] = (0.3, 0.6, 0.2)  # 300 coincident points: more than max_points, so they need the duplicate levels
    xyz[300:600] = xyz[600:900]  # exact duplicates of other points
    xyz[900:950] = xyz[950] + rng.normal(scale=1e-9, size=(50, 3))  # closer than the quantum
    vals = rng.random((n, 2)).astype(np.float32)
    return xyz, vals


def _leaf_points(path):
    meta, g = open_point_store(path)
    t = read_node_table(g)
    xyz = np.asarray(g["points/xyz"][:], np.float64) + np.asarray(meta.origin)
    vals = np.asarray(g["points/values"][:])
    leaf = t["child_mask"] == 0
    rows = np.concatenate([np.arange(o, o + c) for o, c in zip(t["offset"][leaf], t["count"][leaf])])
    node = np.repeat(np.flatnonzero(leaf), t["count"][leaf])
    return meta, t, xyz, vals, rows, node


def _sorted_rows(a):
    a = np.asarray(a, np.float64)
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("memory_points", [1 << 20, 700])  # in memory, and partitioned out of core (recursing)
def test_octree_invariant_on_clustered_duplicate_and_coincident_points(tmp_path, rng, memory_points):
    xyz, vals = _hard_points(rng)
    N = 8
    build_point_store(ArrayPointSource(xyz, vals), tmp_path / "p.zarr", max_points=N, progress=False,
                      memory_points=memory_points)
    meta, t, sxyz, svals, rows, node = _leaf_points(tmp_path / "p.zarr")
    assert meta.num_points == len(xyz)
    assert t["count"].max() <= N  # every node, leaves and inner ones
    assert (t["count"][t["child_mask"] == 0] >= 1).all()
    # every input point is in exactly one leaf: the leaves' points are the input, as a multiset
    assert len(rows) == len(xyz)
    got = np.concatenate([sxyz[rows], svals[rows]], axis=1)
    want = np.concatenate([xyz - meta.origin, vals], axis=1)
    want = np.concatenate([np.asarray(want[:, :3], np.float32).astype(np.float64) + meta.origin, want[:, 3:]], axis=1)
    np.testing.assert_allclose(_sorted_rows(got), _sorted_rows(want), rtol=0, atol=1e-6)
    # ... and inside that leaf's box, up to the quantum edge / 2**GEO_BITS (coincident points)
    lo, hi = node_box(t["depth"][node], t["code"][node], meta.origin, meta.edge)
    q = meta.edge / 2**GEO_BITS + 1e-6
    p = sxyz[rows]
    assert np.all((p >= lo - q) & (p <= hi + q))
    assert check_point_store(tmp_path / "p.zarr") == []


def test_out_of_core_build_equals_in_memory_build(tmp_path, rng):
    xyz, vals = _hard_points(rng, 4000)
    for name, mem in (("a", 1 << 20), ("b", 500)):
        build_point_store(ArrayPointSource(xyz, vals), tmp_path / name, max_points=16, progress=False, memory_points=mem)
    ta = read_node_table(open_point_store(tmp_path / "a")[1])
    tb = read_node_table(open_point_store(tmp_path / "b")[1])
    for k in ("code", "depth", "count", "weight", "child_mask"):
        np.testing.assert_array_equal(ta[k], tb[k], err_msg=k)


def test_morton_against_a_bit_loop(rng):
    ix, iy, iz = (rng.integers(0, 1 << 21, 200) for _ in range(3))
    ref = np.zeros(200, np.int64)
    for b in range(21):
        ref |= ((ix >> b) & 1) << (3 * b) | ((iy >> b) & 1) << (3 * b + 1) | ((iz >> b) & 1) << (3 * b + 2)
    np.testing.assert_array_equal(morton_encode(ix, iy, iz), ref)
    np.testing.assert_array_equal(morton_decode(ref), np.stack([ix, iy, iz], 1))


def test_representatives_are_input_points_nearest_their_cell_centre(tmp_path, rng):
    xyz = rng.random((3000, 3))
    vals = rng.random(3000).astype(np.float32)
    build_point_store(ArrayPointSource(xyz, vals), tmp_path / "p", max_points=8, progress=False)
    meta, g = open_point_store(tmp_path / "p")
    t = read_node_table(g)
    sx = np.asarray(g["points/xyz"][:], np.float64) + meta.origin
    sv = np.asarray(g["points/values"][:])
    ids = {(int(d), int(c)): i for i, (d, c) in enumerate(zip(t["depth"], t["code"]))}
    inner = np.flatnonzero(t["child_mask"] > 0)
    checked = 0
    for i in inner[:40]:
        d, c = int(t["depth"][i]), int(t["code"][i])
        reps = sx[t["offset"][i]:t["offset"][i] + t["count"][i]]
        rep_vals = sv[t["offset"][i]:t["offset"][i] + t["count"][i], 0]
        # each representative is an input point with its own value
        for p, v in zip(reps, rep_vals):
            j = np.argmin(((xyz - p) ** 2).sum(1))
            assert np.abs(xyz[j] - p).max() < 1e-5 and vals[j] == v
        # one per child (N = 8: cells one level down), the child's stored point nearest the child's centre
        for o in range(8):
            if not t["child_mask"][i] >> o & 1:
                continue
            k = ids[(d + 1, c * 8 + o)]
            cand = sx[t["offset"][k]:t["offset"][k] + t["count"][k]]
            lo, hi = node_box(np.array([d + 1]), np.array([c * 8 + o]), meta.origin, meta.edge)
            best = cand[np.argmin(((cand - (lo + hi)[0] / 2) ** 2).sum(1))]
            assert np.any(np.all(np.abs(reps - best) < 1e-6, axis=1))
            checked += 1
    assert checked > 40


@POINT_READERS
def test_readers_match_the_files_their_libraries_wrote(tmp_path, rng):
    import meshio
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq
    from plyfile import PlyData, PlyElement

    n = 500
    xyz = rng.random((n, 3))
    rho = rng.random(n)
    pd.DataFrame({"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "rho": rho, "other": rho * 2}).to_csv(tmp_path / "p.csv", index=False)
    pq.write_table(pa.table({"px": xyz[:, 0], "py": xyz[:, 1], "pz": xyz[:, 2], "rho": rho}), tmp_path / "p.parquet")
    v = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("rho", "f4")])
    v["x"], v["y"], v["z"], v["rho"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], rho
    PlyData([PlyElement.describe(v, "vertex")]).write(str(tmp_path / "p.ply"))
    cells = [("vertex", np.arange(n).reshape(-1, 1))]
    meshio.write(tmp_path / "p.vtu", meshio.Mesh(xyz, cells, point_data={"rho": rho}))
    for name, xyzn in (("p.csv", "xyz"), ("p.parquet", ("px", "py", "pz")), ("p.ply", "xyz"), ("p.vtu", "xyz")):
        src = open_point_source(tmp_path / name, ["rho"], tuple(xyzn))
        got = list(src.chunks(128))
        gx = np.concatenate([a for a, _ in got])
        gv = np.concatenate([b for _, b in got])[:, 0]
        tol = 1e-6 if name == "p.ply" else 1e-12
        np.testing.assert_allclose(gx, xyz, atol=tol, err_msg=name)
        np.testing.assert_allclose(gv, rho, atol=1e-6, err_msg=name)
        assert src.value_names == ("rho",) and src.count == n


@POINT_READERS
def test_bad_input_gets_a_clear_error(tmp_path, rng):
    import pandas as pd

    xyz = rng.random((100, 4))
    xyz[37, 1] = np.nan
    np.save(tmp_path / "nan.npy", xyz)
    with pytest.raises(InputFormatError, match=r"nan\.npy.*finite.*row 37"):
        build_point_store(open_point_source(tmp_path / "nan.npy"), tmp_path / "o1", progress=False)
    assert not (tmp_path / "o1").exists() or not open_point_store(tmp_path / "o1", require_complete=False)[0].complete
    np.save(tmp_path / "empty.npy", np.zeros((0, 4)))
    with pytest.raises(InputFormatError, match=r"empty\.npy.*at least one point"):
        open_point_source(tmp_path / "empty.npy")
    pd.DataFrame({"x": [0.0], "y": [1.0], "z": [2.0], "rho": [3.0]}).to_csv(tmp_path / "c.csv", index=False)
    with pytest.raises(InputFormatError, match=r"c\.csv.*'temperature'.*x, y, z, rho"):
        open_point_source(tmp_path / "c.csv", ["temperature"])
    np.save(tmp_path / "ok.npy", rng.random((50, 4)))
    build_point_store(open_point_source(tmp_path / "ok.npy"), tmp_path / "ok.zarr", progress=False)
    with pytest.raises(OutputExistsError, match="ok.zarr"):
        build_point_store(open_point_source(tmp_path / "ok.npy"), tmp_path / "ok.zarr", progress=False)
    with pytest.raises(ClipvolError, match="max-points"):
        build_point_store(open_point_source(tmp_path / "ok.npy"), tmp_path / "x.zarr", max_points=4, progress=False)


def test_too_many_coincident_points_are_refused_by_name(tmp_path):
    """8**DUP_BITS * N coincident points still split into leaves of N; one more cannot."""
    from clipvol.bricking.points import DUP_BITS

    n = 8**DUP_BITS * 8
    xyz = np.zeros((n + 1, 3))
    xyz[0] = (1.0, 1.0, 1.0)  # a second position, so the cube has an extent
    xyz_ok = xyz[:n].copy()
    xyz_ok[0] = (1.0, 1.0, 1.0)
    build_point_store(ArrayPointSource(xyz_ok, np.zeros(n)), tmp_path / "ok", max_points=8, progress=False)
    assert check_point_store(tmp_path / "ok") == []
    extra = np.concatenate([xyz, np.zeros((1, 3))])
    with pytest.raises(InputFormatError, match="coincident points.*--max-points"):
        build_point_store(ArrayPointSource(extra, np.zeros(len(extra))), tmp_path / "bad", max_points=8, progress=False)


def test_mean_representatives_average_their_cell(tmp_path, rng):
    """``representative="mean"``: an inner node's point for a cell carries the mean value of the
    candidates in that cell (N = 8: a cell is a child octant, the candidates that child's points)."""
    xyz = rng.random((2000, 3))
    vals = rng.random((2000, 2)).astype(np.float32)
    build_point_store(ArrayPointSource(xyz, vals), tmp_path / "p", max_points=8, progress=False, representative="mean")
    meta, t, sxyz, svals, rows, _ = _leaf_points(tmp_path / "p")
    np.testing.assert_allclose(_sorted_rows(svals[rows]), _sorted_rows(vals), atol=0)  # leaves keep the input
    ids = {(int(d), int(c)): i for i, (d, c) in enumerate(zip(t["depth"], t["code"]))}
    inner = np.flatnonzero(t["child_mask"] > 0)
    for i in inner[:60]:
        d, c = int(t["depth"][i]), int(t["code"][i])
        got = svals[t["offset"][i]:t["offset"][i] + t["count"][i]]
        want = []
        for o in range(8):
            if t["child_mask"][i] >> o & 1:
                k = ids[(d + 1, c * 8 + o)]
                want.append(svals[t["offset"][k]:t["offset"][k] + t["count"][k]].astype(np.float64).mean(axis=0))
        np.testing.assert_allclose(got, np.array(want), rtol=1e-5)
    assert check_point_store(tmp_path / "p") == []
