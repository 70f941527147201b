"""``clipvol info ROOT`` of an image set (what ``clipvol brick`` writes for a 4-D input).

The set is described in one line (its axis, how many members, where they are), then each member
is described as any store is; the exit status is the worst of the members' (an incomplete member
makes the set incomplete). See :mod:`clipvol.bricking.channels` for the layout.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def run_set_info(args: argparse.Namespace, path: Path, axis: str, n: int) -> int:
    """Describe the set rooted at ``path`` (``axis`` ``"c"`` or ``"t"``, ``n`` members)."""
    from clipvol.tools import cmd_info

    what = "channel set" if axis == "c" else "time series"
    print(f"store      {path}")
    print(f"kind       {what} of {n} clipvol stores ({path}/{axis}/0 .. {path}/{axis}/{n - 1}); "
          f"OME-Zarr 0.5 collection (bioformats2raw.layout, series in {path}/OME)")
    rc = 0
    for k in range(n):
        print()
        print(f"--- {axis} = {k}")
        member = argparse.Namespace(**{**vars(args), "store": str(path / axis / str(k))})
        rc = max(rc, int(cmd_info.run(member) or 0))
    return rc
