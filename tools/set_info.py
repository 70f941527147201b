"""``clipvol info ROOT`` of an image set (what ``clipvol brick`` writes for a 4-D input).

The set is described first (its axis, how many members, the 4-D arrays other readers open), then
each member (each ``c`` or ``t``): whether it verifies against its manifest, whether it is complete,
its value range and statistics; the exit status is the worst of the members' (an incomplete or
unverified member makes it 1). A set written before the 4-D layout (one store per member) is
described member store by member store. A root behind a URL is described the same way. See
:mod:`clipvol.bricking.channels` for the layout.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def run_set_info(args: argparse.Namespace, path: Path, axis: str, n: int) -> int:
    """Describe the set rooted at ``path`` (``axis`` ``"c"`` or ``"t"``, ``n`` members)."""
    from clipvol.bricking.channels import set_version
    from clipvol.tools import cmd_info

    if set_version(path) != 1:
        return run_image_info(args, path)

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


def run_image_info(args: argparse.Namespace, where) -> int:
    """``clipvol info`` of a version-2 set (one 4-D OME-Zarr image) at a path or URL; None-free:
    returns the exit status (0, or 1 when a member is incomplete, unverified or its statistics
    disagree with its manifest)."""
    from clipvol.tools import cmd_info
    from clipvol.tools.cmd_check import set_members
    from clipvol.tools.remote_args import remote_kwargs

    _stats_problems, trust_line = cmd_info._stats_problems, cmd_info.trust_line

    members = set_members(where, **remote_kwargs(args))
    rc = 0
    for k, (label, opened) in enumerate(members):
        meta, loader = opened()
        try:
            pyr = meta.pyramid
            if k == 0:
                axis = label.split(" ")[0]
                what = "channel set" if axis == "c" else "time series"
                print(f"store      {where}")
                print(f"kind       {what}: one OME-Zarr 0.5 image, axes {axis}, z, y, x; arrays 0 .. {pyr.num_levels - 1} "
                      f"of shape ({len(members)}, Z, Y, X), chunks 1 x {'x'.join(map(str, pyr.brick_shape))}; "
                      f"per-{axis} statistics and manifests under clipvol_members/{axis}")
                print(f"dtype      {pyr.dtype}")
                print(f"levels     {', '.join('x'.join(map(str, lv.shape)) for lv in pyr.levels)} (z, y, x)")
                print(f"spacing    {', '.join(f'{v:g}' for v in pyr.spacing)} {meta.unit} (z, y, x)")
            print()
            print(f"--- {label}")
            bad = _stats_problems(loader, pyr.num_levels) if meta.complete else []
            print(f"trust      {trust_line(loader if meta.complete else None)}")
            print(f"complete   {'yes' if meta.complete else 'no (interrupted build: re-run the same clipvol brick command)'}")
            print(f"statistics {'do not match the manifest: ' + '; '.join(bad) if bad else 'per brick, matching the manifest'}")
            print(f"value range {pyr.value_range[0]:g} .. {pyr.value_range[1]:g}")
            if not meta.complete or bad or not loader.verified:
                import sys

                why = ("incomplete (an interrupted build: re-run the same clipvol brick command)" if not meta.complete
                       else "statistics do not match the manifest" if bad else loader.trust)
                print(f"clipvol info: {where} ({label}): {why}", file=sys.stderr)
                rc = 1
        finally:
            close = getattr(loader, "close", None)
            if close is not None:
                close()
    return rc
