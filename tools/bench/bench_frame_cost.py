"""What a frame costs the host when the cut holds thousands of bricks: clipvol's frame against a plain
one-texture caster at the same cameras, static, orbiting and flying, for a full-resolution
(fixed-level) cut and a projected-size cut.

On a GPU the rays of a small image cost about a millisecond, so the frame is the host's work:
selecting the cut, merging it, building the page table. A fixed-level cut does not change when the
camera turns, and clipvol draws it again (:mod:`clipvol.render.frame_loop`, "Coherence"): its merged
boxes and page table are kept with it, so a turning camera costs a check over flat arrays and a
redraw. A projected-size cut changes with the camera in a band of nodes near its level boundaries;
clipvol keeps it and re-tests only that band
(:class:`~clipvol.scene.selection.kept_cut.KeptCut`). This benchmark measures both, and how the
host's cost grows with the cut (``--head`` sizes and ``--brick`` edges give cuts from about a
thousand to about ten thousand bricks).

Data: any clipvol store (``--store``, repeatable: the MNI ICBM152 T1 template bricked at 16^3 with
``clipvol brick``), and the CT-like head of :func:`common.ct_volume` at ``--head`` sizes (bricked
once into ``bench-data/`` at each of ``--brick``'s edges, default 16^3: a 512^3 head is a level-0
cut of thousands of bricks; at 16^3 bricks and a 32^2 orbit the projected-size cut holds 2 828
bricks at 256^3, 10 170 at 432^3 and 15 774 at 512^3, and the MNI template's 1 390). Every brick resident and on the GPU (:class:`common.WarmScene`), the
``bone`` table, step 1 voxel; per ``--policies``: ``fixed`` (``level=0``) and ``projected-size``
(``lod_threshold=--lod``, default 0.1 pixel per voxel: at a 32^2 image a cut of thousands of bricks
over several levels).

Per volume and image size (``--images``, default 32 and 512), three camera sequences of
``--frames`` frames each: **static** (one camera), **orbit** (1 degree a frame about the volume's
centre) and **fly** (the eye 1 % of the distance nearer each frame). Each frame is drawn by

* ``raw``: :class:`common.RawCaster` - the whole level 0 in one 3D texture, one pass, no bricks
  (the reference outside clipvol's render path), stopping where clipvol stops;
* ``clipvol``: a :class:`~clipvol.render.action.ClipRenderAction` (the default path, ``auto``),
  keeping its cut between frames;
* ``fresh``: the same action made to select, merge and build its tables from nothing every frame
  (a policy instance passed per frame, which the frame loop never replays): what every frame cost
  before the cut was kept;

interleaved frame by frame (the order alternating), so a drift in the machine's load weighs on all
three alike. Columns: the medians over the sequence's frames of each one's ms, ``clipvol``'s host
ms and GL ms (:attr:`FrameStats.host_ms`, :attr:`FrameStats.gpu_ms`), the share of its frames that
drew the kept cut again (``replayed``) and that drew the kept projected-size cut updated for the
camera (``updated``), the CPU time of the rendering thread per frame for ``clipvol`` and ``fresh``
(``time.thread_time``: the host's own work, which a shared machine's load does not inflate as it
does wall times), the share of its frames whose single-pass page table was updated from the frame
before's (``tables_updated``) and built from nothing (``tables_built``; neither: the table was kept),
and the ratios ``clipvol/raw`` and ``fresh/clipvol`` (medians over frames of the
per-frame ratios). Rows go to ``tools/bench/results/bench_frame_cost.csv``.

``--flat`` asks one question robustly: is the host's cost per orbit frame the same for a small cut
and a large one? Run to run, the sequences above move the 12-frame medians by ~3 ms (the machine's
load, the caches, llvmpipe's threads), more than the difference asked about. So ``--flat`` holds
every volume's scene and action warm in ONE process and ONE GL context and draws their orbit frames
alternately, frame by frame (small, large, small, large ...; the order reversed on every other
frame), over ``--frames`` frames each (default 48 in this mode) of the same 1 degree a frame orbit,
after the same warm-up; each clipvol frame beside the raw caster's of the same volume at the same
camera. A drift in the load then weighs on both frames of a pair alike, and the figure is the
median over frames of the per-pair ratio ``large / small`` of the rendering thread's CPU time
(``time.thread_time``), with its quartiles, for each volume against the first (give the smallest
cut first: ``--store`` comes before ``--head``, the heads in the order given). Each volume's
clipvol ÷ raw caster (wall, medians of per-frame ratios) is reported too. Rows go to
``tools/bench/results/bench_frame_cost_flat.csv`` (``--out``). It runs on an older tree too (the
script's ``common.py`` with the installed clipvol), to measure it alternately with a change:

    python tools/bench/bench_frame_cost.py --flat --store mni16.zarr --head 256,432,512 --brick 16

Runs as is on a machine with a GPU (``python tools/bench/bench_frame_cost.py``): the GL is whatever
the context gets.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import common  # noqa: E402  (tools/bench/common.py, beside this script)

STEP = 1.0


def cameras(pyr, image: int, kind: str, frames: int) -> list:
    """The ``kind`` sequence (static, orbit, fly) of ``frames`` cameras around ``pyr``'s volume."""
    from clipvol.scene.camera import Camera

    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    dist = 1.05 * float(np.linalg.norm(hi - lo))
    out = []
    for k in range(frames):
        deg = float(k) if kind == "orbit" else 0.0
        scale = 0.99 ** k if kind == "fly" else 1.0
        th = np.radians(30.0 + deg)
        d = np.array([np.sin(th) * 0.7, 0.45, np.cos(th) * 0.7])
        d /= np.linalg.norm(d)
        out.append(Camera.perspective(tuple(c - d * dist * scale), tuple(c), up=(0, -1, 0), fov_y=35,
                                      size=(image, image)))
    return out


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def _timed_cpu(fn, cpu: list) -> float:
    """Wall seconds of ``fn``; appends the CPU seconds of this thread during it to ``cpu`` (the
    host's own work: llvmpipe rasterises on its own threads, and a wait costs this thread nothing,
    so the figure holds under a shared machine's load where wall times do not)."""
    c = time.thread_time()
    t = time.perf_counter()
    fn()
    wall = time.perf_counter() - t
    cpu.append(time.thread_time() - c)
    return wall


def _load() -> str:
    """The 1-minute load average where the system tells it (Linux), else empty."""
    p = Path("/proc/loadavg")
    return p.read_text().split()[0] if p.exists() else ""


#: the parameters of each ``--policies`` name
POLICY_PARAMS = {"fixed": lambda lod: dict(policy="fixed", level=0),
                 "projected-size": lambda lod: dict(policy="projected-size", lod_threshold=lod)}


def run(store: Path, volume, label: str, images, frames: int, log=print, policies=("fixed",),
        lod: float = 0.1) -> list[dict]:
    scene = common.WarmScene(store)
    raw = scene.raw_caster(volume)
    rows = []
    try:
        for name in policies:
            params = POLICY_PARAMS[name](lod)
            kept = scene.action(**params, step=STEP)
            fresh = scene.action(**params, step=STEP)
            rows += _run_policy(scene, raw, kept, fresh, f"{label}, {name}", images, frames, log)
    finally:
        scene.close()
    return rows


def _run_policy(scene, raw, kept, fresh, label: str, images, frames: int, log) -> list[dict]:
    from clipvol.render.paths.setup import OPAQUE
    from clipvol.scene.selection.policies import policy_for

    pyr, tf = scene.pyramid, scene.tf
    rows = []
    for image in images:
        for kind in ("static", "orbit", "fly"):
            cams = cameras(pyr, image, kind, frames)
            for a in (kept, fresh):  # warm: every brick of the sequence on the GPU, programs built
                for cam in (*cams, cams[0]):  # (a projected-size cut needs each camera's bricks)
                    a.render(cam, tf, wait=True, timeout=900)
                    if not a.last_frame_stats.converged:
                        raise RuntimeError(f"{label}: the frame did not converge in 900 s ({image}^2 {kind})")
            raw.render(kept._selection_camera(cams[0]), tf, STEP, OPAQUE)
            t = {"raw": [], "clipvol": [], "fresh": []}
            host, gpu, replayed, updated, cpu_kept, cpu_fresh = [], [], [], [], [], []
            tables = {"updated": 0, "built": 0}  # the single pass's page tables, clipvol's frames
            bricks = kept.last_frame_stats.bricks_distinct
            for k, cam in enumerate(cams):
                fc = kept._selection_camera(cam)
                order = ["raw", "clipvol", "fresh"] if k % 2 == 0 else ["fresh", "clipvol", "raw"]
                for name in order:
                    if name == "raw":
                        t[name].append(_timed(lambda: raw.render(fc, tf, STEP, OPAQUE)))
                    elif name == "clipvol":
                        sp = kept._path("single-pass")
                        was = (sp.tables_updated, sp.tables_built)
                        t[name].append(_timed_cpu(lambda: kept.render(cam, tf), cpu_kept))
                        tables["updated"] += sp.tables_updated - was[0]
                        tables["built"] += sp.tables_built - was[1]
                        st = kept.last_frame_stats
                        host.append(st.host_ms)
                        gpu.append(st.gpu_ms)
                        replayed.append(st.replayed)
                        updated.append(st.updated)
                        bricks = max(bricks, st.bricks_distinct)
                    else:  # a policy instance per frame: selected, merged and tabled from nothing
                        t[name].append(_timed_cpu(lambda: fresh.render(cam, tf, policy=policy_for(fresh.params)),
                                                  cpu_fresh))
            med = {k: 1e3 * statistics.median(v) for k, v in t.items()}
            row = {"date": time.strftime("%Y-%m-%d"), "volume": label, "image": image, "camera": kind,
                   "frames": frames, "bricks": bricks, "raw_ms": round(med["raw"], 2),
                   "clipvol_ms": round(med["clipvol"], 2), "fresh_ms": round(med["fresh"], 2),
                   "host_ms": round(statistics.median(host), 2), "gpu_ms": round(statistics.median(gpu), 2),
                   "clipvol_cpu_ms": round(1e3 * statistics.median(cpu_kept), 2),
                   "fresh_cpu_ms": round(1e3 * statistics.median(cpu_fresh), 2),
                   "replayed": round(float(np.mean(replayed)), 2), "updated": round(float(np.mean(updated)), 2),
                   "tables_updated": round(tables["updated"] / len(cams), 2),
                   "tables_built": round(tables["built"] / len(cams), 2),
                   "clipvol_over_raw": round(statistics.median(c / r for c, r in zip(t["clipvol"], t["raw"])), 2),
                   "fresh_over_clipvol": round(statistics.median(f / c for f, c in zip(t["fresh"], t["clipvol"])), 2),
                   "load": _load()}
            rows.append(row)
            log(f"{label} {image}^2 {kind:6}: {bricks} bricks, raw {row['raw_ms']} ms, "
                f"clipvol {row['clipvol_ms']} ms "
                f"(host {row['host_ms']}, gl {row['gpu_ms']}, {100 * row['replayed']:.0f} % kept cut, "
                f"{100 * row['updated']:.0f} % updated; page table updated on {100 * row['tables_updated']:.0f} %, "
                f"built on {100 * row['tables_built']:.0f} %) = "
                f"{row['clipvol_over_raw']}x raw; from nothing {row['fresh_ms']} ms = "
                f"{row['fresh_over_clipvol']}x clipvol; main-thread CPU {row['clipvol_cpu_ms']} ms kept, "
                f"{row['fresh_cpu_ms']} ms from nothing; load {row['load']}")
    return rows


def _quartiles(v) -> tuple[float, float, float]:
    """The first quartile, median and third quartile of ``v``."""
    q = np.percentile(np.asarray(v, dtype=float), [25, 50, 75])
    return float(q[0]), float(q[1]), float(q[2])


def run_flat(entries, image: int, frames: int, log=print, policy: str = "projected-size",
             lod: float = 0.1) -> list[dict]:
    """``--flat``: the orbit frames of every ``(store, volume, label)`` in ``entries`` drawn
    alternately frame by frame in one process and one GL context (see the module's docstring); a
    row per volume with its CPU per frame and, past the first, the per-pair ratios to the first's."""
    from clipvol.render import create_context
    from clipvol.render.paths.setup import OPAQUE

    ctx = create_context()
    scenes, raws, acts, seqs, labels = [], [], [], [], []
    try:
        for store, volume, label in entries:
            scene = common.WarmScene(store, ctx=ctx)
            scenes.append(scene)
            raws.append(scene.raw_caster(volume))
            act = scene.action(**POLICY_PARAMS[policy](lod), step=STEP)
            cams = cameras(scene.pyramid, image, "orbit", frames)
            for cam in (*cams, cams[0]):  # bench's warm-up: every brick of the orbit on the GPU
                act.render(cam, scene.tf, wait=True, timeout=900)
                if not act.last_frame_stats.converged:
                    raise RuntimeError(f"{label}: the frame did not converge in 900 s ({image}^2 orbit)")
            raws[-1].render(act._selection_camera(cams[0]), scene.tf, STEP, OPAQUE)
            acts.append(act)
            seqs.append(cams)
            labels.append(label)
        n = len(entries)
        cpu = [[] for _ in range(n)]
        wall = [[] for _ in range(n)]
        raw = [[] for _ in range(n)]
        bricks = [0] * n
        for k in range(frames):
            for i in (range(n) if k % 2 == 0 else reversed(range(n))):
                act, scene, cam = acts[i], scenes[i], seqs[i][k]
                fc = act._selection_camera(cam)
                steps = ("raw", "clipvol") if k % 2 == 0 else ("clipvol", "raw")
                for what in steps:
                    if what == "raw":
                        raw[i].append(_timed(lambda: raws[i].render(fc, scene.tf, STEP, OPAQUE)))
                    else:
                        wall[i].append(_timed_cpu(lambda: act.render(cam, scene.tf), cpu[i]))
                        bricks[i] = max(bricks[i], act.last_frame_stats.bricks_distinct)
    finally:
        for scene in reversed(scenes):
            scene.close()
        ctx.release()
    load = _load()
    rows = []
    for i in range(n):
        q1, med, q3 = _quartiles(cpu[i])
        row = {"date": time.strftime("%Y-%m-%d"), "volume": labels[i], "image": image, "camera": "orbit",
               "policy": policy, "frames": frames, "bricks": bricks[i],
               "clipvol_cpu_ms": round(1e3 * med, 2), "clipvol_cpu_q1_ms": round(1e3 * q1, 2),
               "clipvol_cpu_q3_ms": round(1e3 * q3, 2),
               "clipvol_over_raw": round(statistics.median(c / r for c, r in zip(wall[i], raw[i])), 2),
               "against": labels[0], "load": load}
        text = ""
        if i > 0:
            pq1, pmed, pq3 = _quartiles([a / b for a, b in zip(cpu[i], cpu[0])])
            row.update(cpu_over_first=round(pmed, 3), cpu_over_first_q1=round(pq1, 3),
                       cpu_over_first_q3=round(pq3, 3))
            text = f"; per pair {pmed:.2f}x the first's CPU (quartiles {pq1:.2f}-{pq3:.2f})"
        rows.append(row)
        log(f"{labels[i]} {image}^2 orbit ({policy}): {bricks[i]} bricks, main-thread CPU {1e3 * med:.2f} ms "
            f"(quartiles {1e3 * q1:.2f}-{1e3 * q3:.2f}), {row['clipvol_over_raw']}x raw{text}; load {load}")
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, action="append", default=[],
                    help="a clipvol store to measure (repeatable; its level 0 is read whole for the raw caster)")
    ap.add_argument("--head", default="512",
                    help="CT-like head edges to measure, comma separated (default 512; empty: none)")
    ap.add_argument("--brick", default="16", help="the heads' brick edges, comma separated (default 16)")
    ap.add_argument("--policies", default="fixed,projected-size",
                    help=f"selection policies, comma separated, of {', '.join(POLICY_PARAMS)} (default both)")
    ap.add_argument("--lod", type=float, default=0.1, help="projected-size's lod_threshold (default 0.1)")
    ap.add_argument("--data", type=Path, default=common.DATA, help="where the heads' stores are built once")
    ap.add_argument("--images", default="32,512", help="image edges, comma separated (default 32,512)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames per camera sequence (default 10; 48 with --flat)")
    ap.add_argument("--flat", action="store_true",
                    help="the volumes' orbit frames drawn alternately in one process: per-pair CPU ratios "
                         "to the first volume's (the first --policies, the first --images)")
    ap.add_argument("--out", type=Path, default=None,
                    help="the rows' CSV (default results/bench_frame_cost.csv, with --flat bench_frame_cost_flat.csv)")
    a = ap.parse_args(argv)
    if a.frames is None:
        a.frames = 48 if a.flat else 10
    if a.frames < 3:
        ap.error(f"--frames: expected at least 3, got {a.frames}")
    if a.out is None:
        a.out = common.RESULTS / ("bench_frame_cost_flat.csv" if a.flat else "bench_frame_cost.csv")
    images = [int(v) for v in a.images.split(",")]
    policies = [v.strip() for v in a.policies.split(",") if v.strip()]
    bad = [p for p in policies if p not in POLICY_PARAMS]
    if bad or not policies:
        ap.error(f"--policies: expected names of {', '.join(POLICY_PARAMS)}, got {a.policies!r}")
    if not a.lod > 0:
        ap.error(f"--lod: expected a pixel size > 0, got {a.lod}")
    if a.flat:
        return _main_flat(ap, a, images, policies)
    rows = []
    for store in a.store:
        from clipvol.paging.open import open_store

        loader = open_store(store)
        volume = common.WholeVolume(loader).read_brick(0, (0, 0, 0))
        rows += run(store, volume, f"{store.name}, {loader.pyramid.brick_shape[0]}^3 bricks", images, a.frames,
                    policies=policies, lod=a.lod)
    for n in (int(v) for v in a.head.split(",") if v.strip()):
        size = f"{n}x{n}x{n}"
        volume = common.ct_volume((n, n, n))
        for brick in (int(v) for v in a.brick.split(",") if v.strip()):
            store = common.ct_store(size, brick, a.data)
            rows += run(store, volume, f"ct_head {size} uint16, {brick}^3 bricks", images, a.frames,
                        policies=policies, lod=a.lod)
    if not rows:
        ap.error("nothing to measure: give --store or --head")
    return common.save_rows(a.out, rows)


def _main_flat(ap, a, images, policies) -> int:
    """``--flat``: every ``--store`` and ``--head`` volume in one alternating run."""
    from clipvol.paging.open import open_store

    entries = []
    for store in a.store:
        loader = open_store(store)
        entries.append((store, common.WholeVolume(loader).read_brick(0, (0, 0, 0)),
                        f"{store.name}, {loader.pyramid.brick_shape[0]}^3 bricks"))
    for n in (int(v) for v in a.head.split(",") if v.strip()):
        size = f"{n}x{n}x{n}"
        volume = common.ct_volume((n, n, n))
        for brick in (int(v) for v in a.brick.split(",") if v.strip()):
            entries.append((common.ct_store(size, brick, a.data), volume, f"ct_head {size} uint16, {brick}^3 bricks"))
    if len(entries) < 2:
        ap.error(f"--flat: expected at least two volumes (--store, --head) to compare, got {len(entries)}")
    return common.save_rows(a.out, run_flat(entries, images[0], a.frames, policy=policies[0], lod=a.lod))


if __name__ == "__main__":
    sys.exit(main())
