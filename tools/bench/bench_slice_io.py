"""Slice I/O benchmark: bytes read from storage by a multiresolution slice, against the
full-resolution slice and against the cube windows a clip-texture fills for a volume view.

What it measures (one run, one process, ratios only):

* **a slice through the centre of a 1024^3 store** - the bytes the loader reads from storage
  (counted where they are read, :mod:`clipvol.paging.readcount`) until the clip-texture is idle,
  for (a) the multiresolution slice with a point of interest at the centre (LaMar, Hamann & Joy,
  *Multiresolution cutting planes*) paging its slab region at ``--budget`` of memory, (b) the
  same plane at full resolution (``level=0``) paging its slab at ``--full-budget``, (c) the
  multiresolution slice drawn from cube windows (``SliceAction.follow_plane = False``: the
  clip-texture fills its windows around the centre, as it does for a volume view) at each of
  ``--cube-budgets``. Quality: percent of pixels with CIELUV
  Delta E >= 6 between (a) and the exact slice computed from the generator (outside our code
  path; :func:`clipvol.scene.metrics.percent_delta_e`), grey window over the value range.
  Targets: (b)/(a) >= 8, (c)/(a) >= 50, Delta E >= 6 on <= 1 %.
* **scrolling** - bytes read per slice while scrolling ``--steps`` axial slices (``--stride``
  voxels apart) through the centre of a 4096^3 store, ``--scroll-pixels`` pixels a side, the
  point of interest on the plane's centre (``--scroll-distance-factor``): the whole slice in view
  (8 voxels a pixel), and zoomed to full resolution around the point of interest (1 voxel a pixel).

* **never more than full resolution** (``--never-more``, no rendering unless ``--rendered N``) - the
  issue's condition over ``--samples`` random axial and oblique planes, each with a random point of
  interest on it (``--seed``), on the virtual ``--size``^3 stores at ``--bricks`` and the stores on
  disk given with ``--real``: the chunks and bytes of the multiresolution slice's region against
  the full-resolution one's, and what the slice action reads (it draws full resolution where that
  holds no more bytes); ``--rendered N`` draws the first N cases of each store on disk and counts
  the bytes read. Writes ``bench_slice_io_never_more.csv``.

* **coarser data where the colours cannot tell** (``--exact-tols T ...``) - the centre slices (and
  with ``--real`` the stores on disk, with ``--never-more`` the random planes of the stores on
  disk) drawn by distance alone and with the slice action's colour rule at each tolerance
  (:mod:`clipvol.scene.slice_exact`, ``SliceAction.exact_tol``). The virtual stores have no summary
  tables: :func:`slab_tables` builds them for the bricks the slice can touch with the summary
  module's own code. Writes ``bench_slice_io_exact.csv`` (``bench_slice_io_exact_real.csv``).

The stores are *virtual*: a procedural fractal (:mod:`clipvol.bricking.generators`) evaluated
per brick, and each brick read is encoded with the chunk codec ``clipvol brick`` writes (blosc
lz4 + shuffle + crc32c, :func:`clipvol.bricking.pipeline.chunk_encoder`); the bytes read are the
sizes of those encoded chunks - the bytes a store on disk would hand over for the same bricks,
without writing terabytes. Run from the repository root::

    python tools/bench/bench_slice_io.py            # ~2-4 min on 2 shared cores
    python tools/bench/bench_slice_io.py --quick    # smoke run (256^3 / 1024^3 stores)
    python tools/bench/bench_slice_io.py --never-more --rendered 24 --real mni16.zarr mni32.zarr

Writes ``tools/bench/results/bench_slice_io.csv`` and ``bench_slice_io_scroll.csv``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: GPU texture budget of every slice (the full-resolution slab of a 1024^3 float32 store at 64^3
#: bricks is 513 MB of textures; llvmpipe keeps them in main memory)
TEXTURE_BUDGET = "1GB"


class EncodedFractal:
    """A virtual clipvol store: fractal bricks, each read counted as the size of its encoded chunk."""

    def __init__(self, size: int, brick: int) -> None:
        from clipvol.bricking.pipeline import chunk_encoder
        from clipvol.loaders.procedural import ProceduralLoader
        from clipvol.paging.readcount import ReadCounter

        self.base = ProceduralLoader(f"procedural:fractal?size={size}", brick=brick)
        self.pyramid = self.base.pyramid
        self._encode = chunk_encoder("lz4", self.pyramid.dtype)
        self.read_counter = ReadCounter()

    def read_brick(self, level, index):
        brick = self.base.read_brick(level, index)
        self.read_counter.add(len(self._encode(brick)))  # the chunk file's bytes
        return brick


def slab_tables(loader, plane, workers: int = 2):
    """Summary tables of the bricks the slice of ``plane`` can touch on a virtual store: at every level
    below the top, the bricks within half a voxel of the plane (:mod:`clipvol.paging.slab`), built
    from the generator's bricks by the summary module's own code (:func:`clipvol.bricking.summary.summary_of`,
    what ``clipvol brick`` runs over a store on disk). ``(tables, seconds)``."""
    import time

    from clipvol.bricking.summary import summary_of
    from clipvol.paging.slab import slab_bricks
    from clipvol.scene.slice_cover import half_voxel

    pyr = loader.pyramid
    base = getattr(loader, "base", loader)
    n = np.asarray(plane.normal, dtype=np.float64)
    origin = np.asarray(plane.origin, dtype=np.float64)
    children = [slab_bricks(pyr, L, origin, n, half_voxel(pyr, L, n)) for L in range(pyr.num_levels - 1)]

    def read(level, index):
        s, e = pyr.brick_voxel_box(level, index)
        return base.read_brick(level, index)[tuple(slice(0, b - a) for a, b in zip(s, e))]

    t0 = time.perf_counter()
    tables = summary_of(read, pyr, children, workers=workers)
    return tables, time.perf_counter() - t0


def _centre(pyr) -> tuple[float, float, float]:
    lo, hi = pyr.volume_box()
    return tuple(((lo + hi) / 2.0).tolist())


def _slice(ctx, loader, plane, budget, *, threads, follow, size=None, px=None, timeout=600, out=None, then=None,
           prepare=None, **params):
    """Render one converged slice, then let the clip-texture finish what it queued; returns
    ``(rgba, bytes read, chunks read, converged)``. ``out`` (a dict) receives the slice action's
    ``stats``, ``levels``, ``values`` and ``params`` (what it drew: full resolution where that
    reads no more bytes); ``prepare(slice_action)`` runs before the slice (``exact_tol``, ``summary``),
    ``then(slice_action)`` on the warm slice action before it closes."""
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.region import Region
    from clipvol.render.slice_action import SliceAction

    kw = dict(region=Region.empty(loader.pyramid.num_levels)) if follow else {}
    r0 = loader.read_counter.snapshot()
    with ClipTexture(loader, budget, threads, prefault=False, **kw) as ct, \
            SliceAction(ctx, ct, texture_budget=TEXTURE_BUDGET, **params) as sa:
        sa.follow_plane = follow
        if prepare is not None:
            prepare(sa)
        rgba = sa.render(plane, size, px, wait=True, timeout=timeout)
        converged = sa.last_stats.converged
        ct.wait_until_idle(timeout)
        if out is not None:
            out.update(stats=sa.last_stats, levels=sa.last_levels.copy(), values=sa.last_values.copy(),
                       params=sa.last_params)
        if then is not None:
            then(sa)
    d = loader.read_counter.snapshot() - r0
    return rgba, d.bytes, d.reads, converged


def exact_axial(loader, plane) -> np.ndarray:
    """The axial slice at ``plane`` straight from the generator (linear between the two level-0 planes
    around it), as the grey RGBA the slice action draws by default: the quality reference."""
    from clipvol.render.slice_action import window_level_grey

    lo, hi = loader.pyramid.value_range
    return window_level_grey(exact_axial_values(loader, plane), (lo + hi) / 2.0, max(hi - lo, 1e-300))


def exact_axial_values(loader, plane) -> np.ndarray:
    """The values of :func:`exact_axial`, ``(ny, nx)`` float64."""
    pyr = loader.pyramid
    z = plane.origin[2] / pyr.spacing[0]
    z0 = min(int(np.floor(z)), pyr.shape[0] - 2)
    t = z - z0
    ny, nx = pyr.shape[1], pyr.shape[2]
    two = loader.base.generator.region(0, (z0, 0, 0), (z0 + 2, ny, nx)).astype(np.float64)
    return (1.0 - t) * two[0] + t * two[1]


def centre_slice(ctx, args, brick, writer) -> dict:
    from clipvol.scene.metrics import delta_e_luv, percent_delta_e
    from clipvol.scene.plane import Plane

    ld = EncodedFractal(args.size, brick)
    pyr = ld.pyramid
    plane = Plane.axis(pyr, "axial")
    focus = _centre(pyr)
    # the full-resolution slab (2 layers of level 0 at the centre) needs a budget whose slots hold it;
    # the quality reference is the exact slice from the generator, outside our code path
    full, b_full, n_full, ok_full = _slice(ctx, ld, plane, args.full_budget, threads=args.threads, follow=True,
                                           level=0)
    exact = exact_axial(ld, plane)
    de_full = percent_delta_e(full, exact) if ok_full else float("nan")
    rows = {}
    cube: dict = {}
    tables, t_secs = slab_tables(ld, plane, args.threads) if args.exact_tols else (None, 0.0)
    if tables is not None:
        print(f"{args.size}^3 b{brick}: summary tables of the slab's bricks in {t_secs:.1f} s")

    def rule(tol):
        def prepare(sa):
            sa.exact_tol, sa.summary = tol, tables
        return prepare

    for df, tol in [(df, tol) for df in args.distance_factors for tol in [None] + list(args.exact_tols)]:
        multi, b_multi, n_multi, ok_multi = _slice(ctx, ld, plane, args.budget, threads=args.threads, follow=True,
                                                  focus=focus, distance_factor=df, prepare=rule(tol))
        de = percent_delta_e(multi, exact)
        de_max = float(delta_e_luv(multi, exact).max())
        # cube windows around the centre fill the same whatever the distance factor: read once per brick size
        for budget in args.cube_budgets if not cube else ():
            _, b_cube, n_cube, ok_cube = _slice(ctx, ld, plane, budget, threads=args.threads, follow=False,
                                               focus=focus, distance_factor=df)
            cube[budget] = (b_cube, n_cube, ok_cube)
        rows[df, tol] = (b_multi, n_multi, de, cube)
        multi_name = "multires_slab" if tol is None else f"multires_slab_exact_tol={tol:g}"
        for name, b, n, ok, d in [(multi_name, b_multi, n_multi, ok_multi, de),
                                  ("full_resolution_slab", b_full, n_full, ok_full, de_full)] + \
                [(f"multires_cube_{bud}", b_c, n_c, ok_c, "") for bud, (b_c, n_c, ok_c) in cube.items()]:
            row = dict(store=f"fractal {args.size}^3 float32", brick=brick, distance_factor=df,
                       what=name, bytes_read=b, chunks_read=n, converged=ok,
                       ratio_to_multires=round(b / max(b_multi, 1), 2),
                       pct_de6_vs_exact="" if d == "" or d != d else round(d, 3),
                       max_de_vs_exact=round(de_max, 2) if name == multi_name else "")
            if args.exact_tols:
                row.update(exact_tol="" if tol is None else tol, tables_s=round(t_secs, 1))
            writer.writerow(row)
        print(f"{args.size}^3 b{brick} df={df}{'' if tol is None else f' tol={tol:g}'}: "
              f"multires {b_multi / 1e6:.2f} MB ({n_multi} chunks), "
              f"full-res {b_full / 1e6:.2f} MB ({n_full}) = {b_full / max(b_multi, 1):.1f}x, "
              + ", ".join(f"cube@{bud} {b_c / 1e6:.1f} MB ({n_c}) = {b_c / max(b_multi, 1):.1f}x"
                          for bud, (b_c, n_c, _) in cube.items())
              + f"; Delta E>=6 against the exact slice on {de:.2f} % of pixels (max {de_max:.1f})"
              + ("" if ok_multi else " (NOT CONVERGED)"))
    return rows


def scroll(ctx, args, writer, view: str, px: float) -> list:
    """Scroll ``args.steps`` axial slices through the centre at ``px`` voxels a pixel, ``scroll_pixels``
    pixels a side around the plane's centre (the point of interest, moving with the plane)."""
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.region import Region
    from clipvol.render.slice_action import SliceAction
    from clipvol.scene.plane import Plane

    ld = EncodedFractal(args.scroll_size, args.bricks[0])
    pyr = ld.pyramid
    z0 = (pyr.shape[0] - 1) / 2.0
    size = (args.scroll_pixels, args.scroll_pixels)
    out = []
    with ClipTexture(ld, args.budget, args.threads, prefault=False, region=Region.empty(pyr.num_levels)) as ct, \
            SliceAction(ctx, ct, texture_budget=TEXTURE_BUDGET) as sa:
        for i in range(args.steps):
            plane = Plane.axis(pyr, "axial", z0 + i * args.stride)
            sa.set_params(sa.params.__class__.from_kwargs(sa.params, focus=tuple(plane.origin),
                                                          distance_factor=args.scroll_distance_factor))
            r0 = ld.read_counter.snapshot()
            sa.render(plane, size, px, wait=True, timeout=600)
            ok = sa.last_stats.converged
            ct.wait_until_idle(600)  # the prefetch of the next slab is counted with this slice
            d = ld.read_counter.snapshot() - r0
            out.append(d.bytes)
            writer.writerow(dict(store=f"fractal {args.scroll_size}^3 float32", brick=args.bricks[0], view=view,
                                 voxels_per_pixel=px, slice=i, z=round(plane.origin[2], 2), bytes_read=d.bytes,
                                 chunks_read=d.reads, converged=ok))
    later = out[1:] or out
    print(f"scroll {args.scroll_size}^3 b{args.bricks[0]} {view} ({px:g} voxels/px, {args.scroll_pixels}^2 px), "
          f"{args.steps} slices {args.stride:g} voxels apart: first slice {out[0] / 1e6:.2f} MB, then mean "
          f"{np.mean(later) / 1e6:.2f} MB, max {np.max(later) / 1e6:.2f} MB a slice")
    return out


def geometry(args, writer, samples: int = 200, seed: int = 0) -> None:
    """Chunks of the slice region (:func:`clipvol.scene.slice_region.slice_region`, computed from the
    pyramid alone) against the full-resolution slab, for the centre (the benchmark's plane and point
    of interest: on brick faces at every level, where eight nodes meet) and for ``samples`` axial
    planes at random depths with a random point of interest on each, at every distance factor."""
    from clipvol.bricking.pyramid import Pyramid
    from clipvol.scene.params import RenderParams
    from clipvol.scene.plane import Plane
    from clipvol.scene.slice_region import slice_region

    rng = np.random.default_rng(seed)
    n = args.size
    for brick in args.bricks:
        pyr = Pyramid.build((n, n, n), (brick,) * 3, dtype="float32")
        cases = [("centre", (n - 1) / 2.0, ((n - 1) / 2.0, (n - 1) / 2.0))]
        cases += [("random", float(rng.uniform(0, n - 1)), tuple(rng.uniform(0, n - 1, 2).tolist()))
                  for _ in range(samples)]
        for df in args.distance_factors:
            ratios = []
            for kind, z, (x, y) in cases:
                plane = Plane.axis(pyr, "axial", z)
                full = slice_region(pyr, plane, RenderParams(policy="plane", level=0), 1.0, size=(n, n))
                multi = slice_region(pyr, plane, RenderParams(policy="plane", focus=(x, y, z), distance_factor=df),
                                     1.0, size=(n, n))
                per_level = [len(b) for b in multi.bricks]
                nf = sum(len(b) for b in full.bricks)
                ratio = nf / max(sum(per_level), 1)
                if kind == "random":
                    ratios.append(ratio)
                writer.writerow(dict(store=f"{n}^3", brick=brick, distance_factor=df, case=kind, z=round(z, 2),
                                     focus_x=round(x, 2), focus_y=round(y, 2), region_chunks=sum(per_level),
                                     per_level=" ".join(map(str, per_level)), full_resolution_chunks=nf,
                                     ratio=round(ratio, 3)))
                if kind == "centre":
                    print(f"geometry {n}^3 b{brick} df={df} centre: region {sum(per_level)} chunks {per_level}, "
                          f"full resolution {nf}: {ratio:.2f}x")
            r = np.array(ratios)
            print(f"geometry {n}^3 b{brick} df={df}, {len(r)} random planes and points of interest: fewer chunks "
                  f"min {r.min():.2f}x, median {np.median(r):.2f}x, max {r.max():.2f}x; >= 8x on "
                  f"{100 * np.mean(r >= 8):.0f} %")


def _fmt(v, digits: int) -> str:
    return "(" + ", ".join(f"{float(x):.{digits}f}" for x in v) + ")"


def random_slices(pyr, n: int, seed: int = 0) -> list:
    """``n`` random slices of ``pyr``: ``(kind, plane, point of interest)``, axial and oblique in
    turn. A plane passes through a uniform point of the volume (oblique: a normal uniform on the
    sphere); its point of interest is another uniform point projected onto it, redrawn until it
    lies in the volume."""
    from clipvol.scene.plane import Plane

    rng = np.random.default_rng(seed)
    lo, hi = pyr.volume_box()
    out: list = []
    while len(out) < n:
        oblique = len(out) % 2 == 1
        p = rng.uniform(lo, hi)
        normal = rng.normal(size=3) if oblique else np.array([0.0, 0.0, 1.0])
        normal /= np.linalg.norm(normal)
        q = rng.uniform(lo, hi)
        q = q - ((q - p) @ normal) * normal
        if np.all(q >= lo) and np.all(q <= hi):
            out.append(("oblique" if oblique else "axial", Plane.through(tuple(p), tuple(normal)), q))
    return out


def never_more(ctx, args, writer, rendered: int = 0) -> None:
    """The issue's condition "a multiresolution cut never reads more than the full-resolution one"
    over ``--samples`` random planes and points of interest (:func:`random_slices`), the whole
    plane in view at one level-0 voxel a pixel, at every distance factor.

    Priced from the geometry alone (:func:`clipvol.scene.slice_region.slice_region`, no rendering),
    the per-brick cover's region against the full-resolution one, in chunks and in bytes as the
    slice action prices them (:func:`~clipvol.scene.slice_region.stored_sizes`): the bytes the
    manifest of a store on disk (``--real``) records (a chunk holding only the fill value is never
    read), a brick's bytes for every brick of the virtual ``--size``^3 stores at ``--bricks`` (no
    manifest). The slice action reads the full-resolution region where that holds no more bytes,
    so what it reads is the smaller of the two. With ``rendered`` > 0 the first that many cases of
    each store on disk are also drawn (cold clip-texture, converged, queue drained) and the bytes
    the loader read are counted, for both slices. With ``--exact-tols T ...`` the stores on disk's
    covers are also priced with their summary tables at the tolerance ``T`` (the first; grey window
    over the value range, :mod:`clipvol.scene.slice_exact`) and, rendered, drawn with it."""
    from types import SimpleNamespace

    from clipvol.bricking.pyramid import Pyramid
    from clipvol.paging.open import open_store
    from clipvol.scene.params import RenderParams
    from clipvol.scene.plane import default_pixel_size, default_size
    from clipvol.scene.slice_region import region_bytes, slice_region, stored_sizes

    stores = []
    for b in args.bricks:
        pyr = Pyramid.build((args.size,) * 3, (b,) * 3, dtype="float32")
        stores.append((f"fractal {args.size}^3 (virtual)", pyr, stored_sizes(SimpleNamespace(pyramid=pyr)), None))
    for path in args.real or ():
        ld = open_store(path)
        stores.append((Path(path).name, ld.pyramid, stored_sizes(ld), path))
    from clipvol.bricking.summary import open_summary
    from clipvol.scene.slice_exact import accumulated_errors, grey_window_colours, stand_ins

    tol = args.exact_tols[0] if args.exact_tols else None
    def grey(pyr):
        lo, hi = pyr.value_range
        return grey_window_colours((lo + hi) / 2.0, max(hi - lo, 1e-300))

    for name, pyr, sizes, path in stores:
        slices = random_slices(pyr, args.samples, args.seed)
        stand = None
        if tol is not None and path is not None:
            stand = stand_ins(accumulated_errors(open_summary(path), grey(pyr)), tol)
        per_plane: dict = {}

        def stand_for(i, plane):
            """The virtual store's stand-ins for plane ``i`` (its slab's tables built from the
            generator, :func:`slab_tables`), for the first ``--exact-virtual`` planes."""
            if tol is None or i >= args.exact_virtual:
                return None
            if i not in per_plane:
                ld = EncodedFractal(args.size, pyr.brick_shape[0])
                tables, secs = slab_tables(ld, plane, args.threads)
                per_plane[i] = stand_ins(accumulated_errors(tables, grey(ld.pyramid)), tol)
                print(f"  {name} b{pyr.brick_shape[0]} plane {i}: slab tables in {secs:.1f} s", flush=True)
            return per_plane[i]

        for df in args.distance_factors:
            more_chunks, more_bytes, read_more, fell_back, worst, worst_case, ratios = 0, 0, 0, 0, 0.0, None, []
            exact_ratios, exact_more = [], 0
            for i, (kind, plane, poi) in enumerate(slices):
                px = default_pixel_size(pyr, plane)
                size = default_size(pyr, plane, px)
                params = RenderParams(policy="plane", focus=tuple(poi.tolist()), distance_factor=df)
                full = slice_region(pyr, plane, RenderParams(policy="plane", level=0), px, size=size)
                multi = slice_region(pyr, plane, params, px, size=size)
                f, m = region_bytes(full, sizes), region_bytes(multi, sizes)
                read = m if m < f else f  # the slice action's choice (SliceAction.render)
                fell_back += int(m >= f)
                more_chunks += int(multi.nbricks > full.nbricks)
                more_bytes += int(m > f)
                read_more += int(read > f)
                ratios.append(f / max(read, 1))
                ex = {}
                st = stand if path is not None else stand_for(i, plane)
                if st is not None:
                    er = slice_region(pyr, plane, params, px, size=size, stand_in=st)
                    e = region_bytes(er, sizes)
                    exact_more += int(e > m)
                    exact_ratios.append(f / max(min(e, m, f), 1))  # the slice action's choice (SliceAction.render)
                    ex = dict(exact_chunks=er.nbricks, exact_bytes=e, exact_slice_action_bytes=min(e, m, f))
                if m / max(f, 1) > worst:
                    worst, worst_case = m / max(f, 1), (kind, plane, poi, m, f, multi.nbricks, full.nbricks)
                row = dict(store=name, brick=pyr.brick_shape[0], distance_factor=df, case=i, kind=kind,
                           origin=" ".join(f"{v:.2f}" for v in plane.origin),
                           normal=" ".join(f"{v:.4f}" for v in plane.normal),
                           focus=" ".join(f"{v:.2f}" for v in poi), cover_chunks=multi.nbricks,
                           full_resolution_chunks=full.nbricks, cover_bytes=m, full_resolution_bytes=f,
                           slice_action_bytes=read, measured_multires="", measured_full="", **ex)
                if path is not None and i < rendered:
                    ld_m, ld_f = open_store(path), open_store(path)
                    def rule(t):
                        def prepare(sa):
                            sa.exact_tol = t
                        return prepare

                    _, row["measured_multires"], _, ok_m = _slice(ctx, ld_m, plane, "256MB", threads=args.threads,
                                                                 follow=True, size=size, px=px, prepare=rule(None),
                                                                 focus=params.focus, distance_factor=df)
                    if stand is not None:
                        _, row["measured_exact"], _, ok_e = _slice(ctx, open_store(path), plane, "256MB",
                                                                  threads=args.threads, follow=True, size=size, px=px,
                                                                  prepare=rule(tol), focus=params.focus,
                                                                  distance_factor=df)
                        ok_m = ok_m and ok_e
                    _, row["measured_full"], _, ok_f = _slice(ctx, ld_f, plane, "256MB", threads=args.threads,
                                                             follow=True, size=size, px=px, level=0)
                    if not (ok_m and ok_f):
                        row["measured_multires"] = f"{row['measured_multires']} (NOT CONVERGED)"
                writer.writerow(row)
            r = np.array(ratios)
            kind, plane, poi, m, f, mc, fc = worst_case
            print(f"{name} b{pyr.brick_shape[0]} df={df}: {len(slices)} random planes and points of interest "
                  f"(axial and oblique); the cover's region holds more chunks than the full-resolution slab on "
                  f"{more_chunks}, more bytes on {more_bytes} (worst {worst:.3f}x: {kind} plane through "
                  f"{_fmt(plane.origin, 1)} normal {_fmt(plane.normal, 3)}, point {_fmt(poi, 1)}, {m} bytes in {mc} "
                  f"chunks against {f} in {fc}); the slice draws full resolution on {fell_back} and reads more on "
                  f"{read_more}; fewer bytes: min {r.min():.2f}x, median {np.median(r):.2f}x"
                  + ("" if not exact_ratios else
                     f"; with the colour rule (exact_tol={tol:g}, {len(exact_ratios)} planes) the cover holds more "
                     f"bytes than by distance alone on {exact_more} (the slice action then draws by distance alone), "
                     f"fewer bytes read than full resolution: min {np.min(exact_ratios):.2f}x, median "
                     f"{np.median(exact_ratios):.2f}x, >= 8x on {100 * np.mean(np.array(exact_ratios) >= 8):.0f} % "
                     f"(by distance alone on those planes: median {np.median(r[:len(exact_ratios)]):.2f}x, >= 8x on "
                     f"{100 * np.mean(r[:len(exact_ratios)] >= 8):.0f} %)"), flush=True)


def _zarr_plane(path, z: float):
    """The level-0 voxel planes around ``z`` read with zarr-python alone (outside our code path):
    ``(seconds, bytes of the chunk files it touched, plane as float64)``, linear between the two."""
    import time

    import zarr

    t0 = time.perf_counter()
    arr = zarr.open_array(str(Path(path) / "0"), mode="r")
    z0 = min(int(np.floor(z)), arr.shape[0] - 2)
    t = z - z0
    two = np.asarray(arr[z0:z0 + 2 if t > 0 else z0 + 1]).astype(np.float64)
    plane = two[0] if t == 0 else (1.0 - t) * two[0] + t * two[1]
    secs = time.perf_counter() - t0
    cz = arr.chunks[0]
    layers = sorted({z0 // cz, (z0 + (1 if t > 0 else 0)) // cz})
    files = [f for f in (Path(path) / "0").rglob("*") if f.is_file() and f.name != "zarr.json"]
    # chunk keys c/<z>/<y>/<x>: the files of the layers the read touched
    nbytes = sum(f.stat().st_size for f in files if f.parent.parent.name.isdigit()
                 and int(f.parent.parent.name) in layers and f.parent.parent.parent.name == "c")
    return secs, nbytes, plane


def real_stores(ctx, args, writer, rounds: int = 3) -> None:
    """A multiresolution slice of a real store on disk (axial, through the centre, point of interest
    there) against its full-resolution slice (``level=0``) and against zarr-python reading the same
    level-0 plane: bytes read from the chunk files (the loader's own counter, and the files' sizes
    for zarr-python), wall time from a cold clip-texture to the converged slice with its queue
    drained, and the slice's error against the full-resolution one (% pixels Delta E >= 6, grey
    window over the value range). Rounds alternate the three reads (the OS page cache is warm
    after the first: all three read from memory). With ``--exact-tols`` each multiresolution slice
    is drawn by distance alone (``exact_tol = None``) and at each tolerance, and the error is also
    measured against zarr-python's plane."""
    import statistics
    import time

    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.paging.region import Region
    from clipvol.render.slice_action import SliceAction, window_level_grey
    from clipvol.scene.metrics import percent_delta_e
    from clipvol.scene.plane import Plane

    for path in args.real:
        pyr = open_store(path).pyramid
        plane = Plane.axis(pyr, "axial")
        lo, hi = pyr.value_range
        win = ((lo + hi) / 2.0, max(hi - lo, 1e-300))
        runs = {"full": dict(level=0)}
        for df in args.distance_factors:  # the rule off (distance alone), then at each tolerance
            for tol in [None] + list(args.exact_tols):
                runs[f"multires df={df:g}" + ("" if tol is None else f" exact_tol={tol:g}")] = dict(
                    focus=tuple(plane.origin), distance_factor=df, exact_tol=tol)
        times: dict = {k: [] for k in list(runs) + ["zarr"]}
        got: dict = {}
        for _ in range(rounds):
            for name, params in runs.items():
                ld = open_store(path)
                t0 = time.perf_counter()
                kw = dict(params)
                tol = kw.pop("exact_tol", None)
                with ClipTexture(ld, "256MB", args.threads, region=Region.empty(pyr.num_levels)) as ct, \
                        SliceAction(ctx, ct, **kw) as sa:
                    sa.exact_tol = tol
                    rgba = sa.render(plane, window=win, wait=True, timeout=600)
                    ok = sa.last_stats.converged
                    ct.wait_until_idle(600)
                times[name].append(time.perf_counter() - t0)
                got[name] = (rgba, ld.read_counter.snapshot(), ok)
            secs, nbytes, values = _zarr_plane(path, plane.origin[2] / pyr.spacing[0])
            times["zarr"].append(secs)
        full_rgba, full_read, _ = got["full"]
        zarr_grey = window_level_grey(values, *win)
        for name in list(runs) + ["zarr"]:
            if name == "zarr":
                nb, nr, ok, de, dz = nbytes, "", True, percent_delta_e(zarr_grey, full_rgba), 0.0
            else:
                rgba, rd, ok = got[name]
                nb, nr, de, dz = rd.bytes, rd.reads, percent_delta_e(rgba, full_rgba), percent_delta_e(rgba, zarr_grey)
            t = statistics.median(times[name])
            writer.writerow(dict(store=Path(path).name, brick=pyr.brick_shape[0], what=name, bytes_read=nb,
                                 chunks_read=nr, converged=ok, median_s=round(t, 4),
                                 bytes_vs_full=round(full_read.bytes / max(nb, 1), 3),
                                 time_vs_zarr=round(t / statistics.median(times["zarr"]), 2),
                                 pct_de6_vs_full=round(de, 3), pct_de6_vs_zarr=round(dz, 3)))
            print(f"{Path(path).name} {name}: {nb / 1e3:.0f} kB ({nr} chunks), "
                  f"{full_read.bytes / max(nb, 1):.2f}x fewer "
                  f"than the full-resolution slice, {1e3 * t:.0f} ms = {t / statistics.median(times['zarr']):.1f}x "
                  f"zarr-python's plane; Delta E>=6 against the full-resolution slice on {de:.2f} % of pixels, "
                  f"against zarr-python's plane on {dz:.2f} %"
                  + ("" if ok else " (NOT CONVERGED)"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--bricks", nargs="+", type=int, default=[64, 32])
    p.add_argument("--budget", default="1GB",
                   help="memory budget of the multiresolution slab runs (their windows must hold the region)")
    p.add_argument("--full-budget", default="2GB", help="memory budget of the full-resolution slab (must hold it)")
    p.add_argument("--cube-budgets", nargs="*", default=["256MB", "1GB"])
    p.add_argument("--distance-factors", nargs="+", type=float, default=[1.0, 0.5])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--scroll-size", type=int, default=4096)
    p.add_argument("--scroll-pixels", type=int, default=512)
    p.add_argument("--steps", type=int, default=12)
    p.add_argument("--scroll-distance-factor", type=float, default=0.5,
                   help="the scroll's distance factor (1.0 makes the level-0 disc 8 bricks wide at 64^3)")
    p.add_argument("--stride", type=float, default=16.0)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--exact-tols", nargs="*", type=float, default=[],
                   help="also draw the centre slices (and the --real slices) with a coarser brick where the summary "
                        "tables show it within this CIELUV Delta E of level 0 (SliceAction.exact_tol; the virtual "
                        "stores' tables built for the slab's bricks); with it only the centre slices run, no cube "
                        "windows: bench_slice_io_exact.csv (bench_slice_io_exact_real.csv with --real)")
    p.add_argument("--geometry", action="store_true",
                   help="only the region's chunks from the pyramid's geometry (no rendering, seconds): "
                        "bench_slice_io_geometry.csv")
    p.add_argument("--real", nargs="+", default=None, metavar="STORE",
                   help="(with --never-more: stores on disk checked besides the virtual ones) only real stores on disk (e.g. the MNI template bricked by clipvol brick): bytes, time "
                        "and error of the slice against the full-resolution one and a zarr-python read of the "
                        "plane: bench_slice_io_real.csv")
    p.add_argument("--never-more", action="store_true",
                   help="only the check that a multiresolution slice never reads more than the full-resolution "
                        "one: --samples random axial and oblique planes with random points of interest on the "
                        "virtual --size^3 stores at --bricks and on the --real stores, in chunks and bytes, "
                        "distance factors 1 0.5 0.25 unless given: bench_slice_io_never_more.csv")
    p.add_argument("--samples", type=int, default=200, help="random planes of --geometry / --never-more")
    p.add_argument("--seed", type=int, default=0, help="the random planes' seed")
    p.add_argument("--exact-virtual", type=int, default=0,
                   help="--never-more --exact-tols: also price the colour rule on the first N planes of the virtual "
                        "stores (their slab's summary tables built from the generator, 10-60 s a plane)")
    p.add_argument("--rendered", type=int, default=0,
                   help="--never-more: also draw the first N cases of each --real store and count the bytes read")
    p.add_argument("--rounds", type=int, default=3, help="--real: alternating rounds (median times)")
    p.add_argument("--out", type=Path, default=HERE / "results")
    args = p.parse_args(argv)
    if args.never_more:
        from clipvol.render import create_context

        args.out.mkdir(parents=True, exist_ok=True)
        if args.distance_factors == [1.0, 0.5]:
            args.distance_factors = [1.0, 0.5, 0.25]
        ctx = create_context() if args.rendered and args.real else None
        with open(args.out / "bench_slice_io_never_more.csv", "w", newline="") as f:
            w = csv.DictWriter(f, ["store", "brick", "distance_factor", "case", "kind", "origin", "normal", "focus",
                                   "cover_chunks", "full_resolution_chunks", "cover_bytes", "full_resolution_bytes",
                                   "slice_action_bytes", "measured_multires", "measured_full", "exact_chunks",
                                   "exact_bytes", "exact_slice_action_bytes", "measured_exact"])
            w.writeheader()
            never_more(ctx, args, w, args.rendered)
        return 0
    if args.real and not args.never_more:
        from clipvol.render import create_context

        args.out.mkdir(parents=True, exist_ok=True)
        ctx = create_context()
        name = "bench_slice_io_exact_real.csv" if args.exact_tols else "bench_slice_io_real.csv"
        with open(args.out / name, "w", newline="") as f:
            w = csv.DictWriter(f, ["store", "brick", "what", "bytes_read", "chunks_read", "converged", "median_s",
                                   "bytes_vs_full", "time_vs_zarr", "pct_de6_vs_full", "pct_de6_vs_zarr"])
            w.writeheader()
            real_stores(ctx, args, w, args.rounds)
        return 0
    if args.geometry:
        args.out.mkdir(parents=True, exist_ok=True)
        if args.distance_factors == [1.0, 0.5]:
            args.distance_factors = [1.0, 0.5, 0.25]
        with open(args.out / "bench_slice_io_geometry.csv", "w", newline="") as f:
            w = csv.DictWriter(f, ["store", "brick", "distance_factor", "case", "z", "focus_x", "focus_y",
                                   "region_chunks", "per_level", "full_resolution_chunks", "ratio"])
            w.writeheader()
            geometry(args, w, args.samples, args.seed)
        return 0
    if args.quick:
        args.size, args.scroll_size, args.steps = 256, 1024, 4
        args.bricks, args.cube_budgets, args.distance_factors = [32], ["64MB"], [0.5]

    from clipvol.render import create_context

    ctx = create_context()
    args.out.mkdir(parents=True, exist_ok=True)
    exact = bool(args.exact_tols)
    with open(args.out / ("bench_slice_io_exact.csv" if exact else "bench_slice_io.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, ["store", "brick", "distance_factor", "what", "bytes_read", "chunks_read", "converged",
                               "ratio_to_multires", "pct_de6_vs_exact",
                               "max_de_vs_exact"] + (["exact_tol", "tables_s"] if exact else []))
        w.writeheader()
        if exact:
            args.cube_budgets = []
        for brick in args.bricks:
            centre_slice(ctx, args, brick, w)
    if exact:
        return 0
    with open(args.out / "bench_slice_io_scroll.csv", "w", newline="") as f:
        w = csv.DictWriter(f, ["store", "brick", "view", "voxels_per_pixel", "slice", "z", "bytes_read", "chunks_read",
                               "converged"])
        w.writeheader()
        scroll(ctx, args, w, "whole slice", args.scroll_size / args.scroll_pixels)
        scroll(ctx, args, w, "zoomed to full resolution", 1.0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
