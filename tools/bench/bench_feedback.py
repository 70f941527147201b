"""Ray-guided residency, measured and not kept: how soon a cold clip-texture draws the converged
full-resolution frame when the load queue is told what the frame needs, against the queue's own order.

A cold clip-texture loads a window's bricks nearest the centre of interest first; behind an opaque
surface (the skull under the ``bone`` table) many of them are never seen. Per round, each variant
starts from a cold clip-texture and draws frames without waiting (``render(wait=False)``: what is
resident draws, as in the viewer) at one camera (:func:`bench_frame_cost.cameras`' static view)
until the frame equals the converged frame:

* ``queue``: the clip-texture's own order (distance from the centre of interest) - the baseline,
  the frame loop's own request switched off (``FrameLoop.prioritize_missing = False``);
* ``cut-first``: that request off too, and after each frame the benchmark moves the cut's missing
  bricks (``Selection.missing_wanted``) to the front of the queue
  (:meth:`~clipvol.paging.cliptexture.ClipTexture.prioritize`) - what the host knows without the
  rays, as first measured from outside the frame loop;
* ``default``: what a render action does by itself: its frame loop asks for the missing bricks of a
  frame drawn without waiting, once per changed set (``clipvol.render.frame_loop``, "Cut first").

A third variant, ``feedback`` (the single pass flagging the page-table nodes its rays sampled, read
back each frame, and the cut's missing bricks under them moved to the front: C. Crassin et al.,
"GigaVoxels", I3D 2009; M. Hadwiger et al., IEEE TVCG 2012), ran at commit ``f38e60f`` and was not
kept (docs/benchmarks.md, "Ray-guided residency"): its rows are in ``results/bench_feedback_*.csv``.

The variants run one after another within each round, their order rotating from round to round.
All use the single pass (``path="single-pass"``), a full-resolution cut (``policy="fixed",
level=0``), step 1 voxel. Storage is modelled as slow (``--latency`` ms per brick read, a remote
store's round trip; ``--threads`` loader threads), so the fill takes many frames. Columns: seconds,
frames and MB read until the frame is within 1 % of pixels at ΔE(L*u*v*) >= 6 of the converged frame
and until it equals it exactly, and the median frame ms during the fill. Ratios are to ``queue``
within the same round. Rows go to ``tools/bench/results/bench_feedback_<date>.csv``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import common  # noqa: E402  (tools/bench/common.py, beside this script)
from bench_frame_cost import _load, cameras  # noqa: E402

VARIANTS = ("queue", "cut-first", "default")


class SlowLoader:
    """``loader`` with ``latency`` seconds added to every brick read (a slow store); everything else
    (ranges, read counter, spread) is the loader's own. No ``read_brick_into``: each read sleeps."""

    def __init__(self, loader, latency: float) -> None:
        self._loader = loader
        self._latency = float(latency)

    @property
    def pyramid(self):
        return self._loader.pyramid

    def read_brick(self, level, index):
        time.sleep(self._latency)
        return self._loader.read_brick(level, index)

    def __getattr__(self, name):
        if name == "read_brick_into":
            raise AttributeError(name)
        return getattr(self._loader, name)


def converged_image(store: Path, cam, tf, params: dict) -> np.ndarray:
    """The converged full-resolution frame (a warm scene, ``wait=True``)."""
    scene = common.WarmScene(store)
    try:
        a = scene.action(**params)
        img = a.render(cam, tf, wait=True, timeout=300)
        assert a.last_frame_stats.converged, "the reference frame did not converge"
        return img
    finally:
        scene.close()


def fill(ctx, programs, store: Path, variant: str, cam, tf, ref: np.ndarray, params: dict, latency: float,
         threads: int, limit: float) -> dict:
    """One cold fill of ``variant``: frames until the image equals ``ref`` (or ``limit`` seconds).
    The action compiles nothing: its programs come from ``programs``, warmed by an unrecorded round
    (a viewer compiles its variants once; llvmpipe takes about a second each)."""
    from clipvol.render.glsl import ProgramCache
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.paging.readcount import bytes_read_of
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.metrics import percent_delta_e

    loader = SlowLoader(open_store(store), latency)
    pyr = loader.pyramid
    budget = int(sum(pyr.num_bricks(L) for L in range(pyr.num_levels)) * pyr.brick_nbytes * 2.0) + (64 << 20)
    row = dict(variant=variant, t_1pct_s="", frames_1pct="", mb_1pct="", t_equal_s="", frames_equal="",
               mb_equal="", frame_ms="")
    clip = ClipTexture(loader, budget, threads=threads)
    a = ClipRenderAction(ctx, clip, texture_budget=budget, **params)
    a.setup.programs = programs
    a.frame_loop.prioritize_missing = variant == "default"  # the frame loop's own request (module docstring)
    frame_s = []
    try:
        read0 = bytes_read_of(loader) or 0
        t0 = time.perf_counter()
        n = 0
        while time.perf_counter() - t0 < limit:
            tf0 = time.perf_counter()
            img = a.render(cam, tf)
            frame_s.append(time.perf_counter() - tf0)
            n += 1
            if variant == "cut-first":
                clip.prioritize(a.last_selection.missing_wanted())
            t = time.perf_counter() - t0
            mb = round(((bytes_read_of(loader) or 0) - read0) / 1e6, 2)
            if row["t_1pct_s"] == "" and percent_delta_e(img, ref, threshold=6.0, premultiplied=False) <= 1.0:
                row.update(t_1pct_s=round(t, 3), frames_1pct=n, mb_1pct=mb)
            if np.array_equal(img, ref):
                row.update(t_equal_s=round(t, 3), frames_equal=n, mb_equal=mb)
                break
        row["frame_ms"] = round(1e3 * statistics.median(frame_s), 1)
    finally:
        a.setup.programs = ProgramCache(ctx)  # (the shared programs outlive the action)
        a.close()
        clip.close()
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, default=None, help="a clipvol store (default: the CT-like head)")
    ap.add_argument("--head", default="256x256x256", help="CT-like head size when no --store")
    ap.add_argument("--brick", type=int, default=32)
    ap.add_argument("--image", type=int, default=128)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--latency", type=float, default=20.0, help="ms added to each brick read")
    ap.add_argument("--threads", type=int, default=4, help="loader threads")
    ap.add_argument("--limit", type=float, default=120.0, help="seconds at most per fill")
    ap.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS),
                    help="variants to run (queue is always run: the ratios are to it)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / f"bench_feedback_{date.today().isoformat()}.csv")
    args = ap.parse_args(argv)

    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.render.glsl import ProgramCache
    from clipvol.scene.transfer import TransferFunction

    store, _volume, label = common.store_or_ct(args.store, args.head, args.brick)
    pyr = open_store(store).pyramid
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    cam = cameras(pyr, args.image, "static", 1)[0]
    params = dict(policy="fixed", level=0, path="single-pass", step=1.0)
    ref = converged_image(store, cam, tf, params)
    ctx = create_context()
    programs = ProgramCache(ctx)
    variants = tuple(v for v in VARIANTS if v == "queue" or v in args.variants)
    rows = []
    try:
        for v in variants:  # the warm-up: every variant's programs compiled, nothing recorded
            fill(ctx, programs, store, v, cam, tf, ref, params, args.latency / 1e3, args.threads, args.limit)
        for r in range(args.rounds):
            k = r % len(variants)
            order = variants[k:] + variants[:k]
            got = {}
            for v in order:
                load = _load()
                got[v] = fill(ctx, programs, store, v, cam, tf, ref, params, args.latency / 1e3, args.threads,
                              args.limit)
                got[v].update(round=r, volume=label, image=args.image, latency_ms=args.latency, threads=args.threads,
                              load=load)
            base = got["queue"]
            for v in variants:
                row = got[v]
                for k in ("t_1pct_s", "mb_1pct", "t_equal_s", "mb_equal"):
                    b, x = base[k], row[k]
                    row[f"{k}_vs_queue"] = round(x / b, 3) if b not in ("", 0) and x != "" else ""
                rows.append(row)
                print({k: row[k] for k in ("round", "variant", "t_1pct_s", "mb_1pct", "t_equal_s", "frames_equal",
                                           "frame_ms", "t_1pct_s_vs_queue", "t_equal_s_vs_queue",
                                           "load")}, flush=True)
    finally:
        programs.release()
        ctx.release()
    return common.save_rows(args.out, rows)


if __name__ == "__main__":
    sys.exit(main())
