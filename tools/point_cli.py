"""The command-line hooks of the point data kind (:class:`clipvol.app.point_kind.PointKind`):
`clipvol info`, `check`, `render`, `view` and `report` on a point store.

The commands hand a point store over here through :func:`clipvol.tools.kind_cli.kind_command`;
the hooks follow :class:`clipvol.app.kinds.KindCommands`, as the volume kind's
(:mod:`clipvol.tools.volume_cli`) do. There is no ``slice`` hook: ``clipvol slice`` refuses a point
store in one line.
"""

from __future__ import annotations

import sys


def info(args) -> int:
    """Print a point store's summary: points, nodes per depth, bytes on disk, values."""
    import os

    import numpy as np

    from clipvol.bricking.point_store import open_point_store, read_node_table
    from clipvol.units import format_bytes

    path = args.store
    meta, g = open_point_store(path, require_complete=False)
    print(f"store      {path}")
    print("kind       points (octree, Meredith & Ma 2001)")
    print(f"complete   {'yes' if meta.complete else 'no (interrupted build: run clipvol brick-points again)'}")
    print(f"points     {meta.num_points:,} ({meta.num_stored:,} stored with representatives)")
    print(f"max points {meta.max_points} per node")
    print(f"cube       origin {', '.join(f'{v:g}' for v in meta.origin)} (x, y, z), edge {meta.edge:g}")
    print(f"spacing    {meta.point_spacing:g} (mean point spacing)")
    for name, (lo, hi) in zip(meta.value_names, meta.value_ranges):
        print(f"value      {name}: {lo:g} .. {hi:g}")
    if meta.complete:
        t = read_node_table(g)
        print(f"{'depth':>5} {'nodes':>10} {'leaves':>10} {'points':>12}")
        for d in np.unique(t["depth"]):
            m = t["depth"] == d
            print(f"{int(d):>5} {int(m.sum()):>10} {int((m & (t['child_mask'] == 0)).sum()):>10} {int(t['count'][m].sum()):>12}")
    size = sum(os.path.getsize(os.path.join(r, f)) for r, _, fs in os.walk(path) for f in fs)
    print(f"total      {format_bytes(size)} on disk")
    return 0


def check(args) -> int:
    """Validate a point store's octree invariants; exit 1 naming each problem."""
    from clipvol.bricking.point_store import check_point_store

    path = args.store
    problems = check_point_store(path)
    for p in problems:
        print(f"{path}: {p}", file=sys.stderr)
    if problems:
        return 1
    print(f"{path}: ok (node table, leaf counts, weights, point boxes)")
    return 0


def render(args) -> int:
    """`clipvol render` on a point store: splats at --tolerance (:func:`clipvol.app.render_png.render_points_to_png`)."""
    from clipvol.app.outputs import check_output_file, check_outputs
    from clipvol.app.render_png import render_points_to_png
    from clipvol.loaders.point_store import PointStoreLoader
    from clipvol.scene.transfer import TransferFunction
    from clipvol.scene.views import view_camera

    check_output_file(args.out, ".png", "--out")
    check_outputs([("--out", args.out)], [args.source])
    loader = PointStoreLoader(args.source)
    lo, hi = loader.world_box()

    class _Box:  # the framing view_camera expects (volume_box)
        def volume_box(self):
            return lo, hi

    cam = view_camera(_Box(), args.view, args.size, eye=args.eye, target=args.target, up=args.up, fov=args.fov,
                      distance=args.distance, ortho=args.ortho)
    if getattr(args, "tf", None) == "auto" and getattr(args, "tf_range", None) is None:
        tf = TransferFunction.preset("viridis", value_range=loader.meta.value_ranges[0])  # no histogram of points yet
    else:
        from clipvol.tools.tf_args import transfer_function_from_args

        tf = transfer_function_from_args(args, loader)
    render_points_to_png(loader, args.out, cam, tf, tolerance=args.tolerance, mode=args.mode,
                         background=args.background, shading=getattr(args, "shading", False),
                         light=getattr(args, "light", (0.3, 0.7, 0.3, 20.0)), memory_budget=args.memory_budget,
                         threads=args.threads, wait=not args.no_wait, timeout=args.timeout,
                         log=lambda line: print(line, file=sys.stderr))
    return 0


def view(args) -> int:
    """`clipvol view` on a point store: the splat viewer window ([ ] change the tolerance)."""
    from clipvol.errors import ParameterError
    from clipvol.viewer.point_window import PointViewer

    if args.offscreen:
        raise ParameterError(f"--offscreen: {args.source} is a point store; draw it offscreen with clipvol render --tolerance")
    tf = "viridis" if getattr(args, "tf", None) in (None, "auto") else args.tf
    if getattr(args, "tf", None) not in (None, "auto"):
        from clipvol.loaders.point_store import PointStoreLoader
        from clipvol.tools.tf_args import transfer_function_from_args

        tf = transfer_function_from_args(args, PointStoreLoader(args.source))
    with PointViewer(args.source, size=args.size or (960, 640), tolerance=args.tolerance, memory_budget=args.memory_budget,
                     threads=args.threads, mode=args.mode, tf=tf, screenshot_dir=args.screenshot_dir, shading=args.shading,
                     title=f"clipvol - {args.source}") as viewer:
        return viewer.run(max_frames=args.max_frames)


def report(args, source, out) -> int:
    """`clipvol report` on a point store: frame time and image error against tolerance."""
    from clipvol.app.point_report import DEFAULT_TOLERANCES, run_point_report

    tols = DEFAULT_TOLERANCES if args.tolerances is None else [t.strip() for t in args.tolerances.split(",") if t.strip()]
    tf = None
    if getattr(args, "tf", None) not in (None, "auto"):
        from clipvol.loaders.point_store import PointStoreLoader
        from clipvol.tools.tf_args import transfer_function_from_args

        tf = transfer_function_from_args(args, PointStoreLoader(source))
    res = run_point_report(source, out, tolerances=tols, size=args.size, views=args.views, tf=tf, mode=args.mode,
                           threads=args.threads, timeout=args.timeout, plots=not args.no_plots)
    print(f"wrote {res.csv}, {res.markdown}" + "".join(f", {p}" for p in res.plots))
    return 0
