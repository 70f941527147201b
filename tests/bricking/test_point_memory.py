"""The out-of-core point build holds nothing proportional to the input between groups.

What a partitioned build keeps from one group to the next is the stored sets of the groups' roots
(at most ``8 ** k <= max_points`` points each, until the root's inner nodes are built from them).
A stored set that was a *view* of its group's whole value array kept that array alive for the whole
build - about 5 bytes per input point, the peak memory that grew with N. Checked here on the
arrays themselves (numpy's own ownership flags and sizes), not on timings or resident memory.
"""

from __future__ import annotations

from clipvol.bricking import point_store
from clipvol.bricking.point_sources import ClusteredPointSource
from clipvol.bricking.point_store import build_point_store
from clipvol.bricking.points import rep_depth_step

MAX_POINTS = 16
MEM = 3000


def test_stored_sets_hold_only_their_own_points(tmp_path, monkeypatch):
    sets = []
    in_memory = point_store._Build.in_memory

    def spy(self, *a, **kw):
        out = in_memory(self, *a, **kw)
        sets.extend(out)
        return out

    monkeypatch.setattr(point_store._Build, "in_memory", spy)
    m = build_point_store(ClusteredPointSource(40_000, seed=5), tmp_path / "p.zarr", max_points=MAX_POINTS,
                          memory_points=MEM, progress=False)
    assert m.num_points == 40_000 and len(sets) > 20  # partitioned: many groups, many roots
    cap = 8 ** rep_depth_step(MAX_POINTS)
    for keys, xyz, vals, count in sets:
        # a leaf keeps its points, an inner node one per cell k levels down
        assert len(keys) == len(xyz) == len(vals) <= (count if count <= MAX_POINTS else cap)
        for a in (keys, xyz, vals):
            # its own buffer (no view keeping a group-sized array alive), of its own size
            assert a.base is None and a.flags.owndata, "a stored set is a view into a larger array"
            assert a.nbytes == a.size * a.itemsize
