"""The single pass's per-node cost on llvmpipe: the march loops' tests after their samples, the page
table's shift-and-mask addressing and blocks of 2 samples per empty-space lookup, against the
loops, division and blocks of 8 they replaced, in one run.

Why in one process: on a shared machine two runs minutes apart see different loads, and the
change is 10-15 % of a 32^2 frame's GL time - within the swing between alternating runs of
``bench_frame_cost.py``. So each round here draws the same still camera three ways, interleaved:

* ``raw``: :class:`common.RawCaster` (the whole level 0 in one 3D texture; the reference outside
  clipvol's render path), stopping where clipvol stops;
* ``clipvol``: the shipped shaders (a :class:`~clipvol.render.action.ClipRenderAction`, the
  default path: the single pass on these cuts);
* ``before``: the same action with the shader source changed back, by text replacement when the
  source is loaded, to the loops whose test comes first (``for``) and the row and column of a
  page-table entry by an integer division by a uniform width, and compiled with the shader's
  default ``SKIP_BLOCK`` (8) instead of :data:`~clipvol.render.paths.single_pass.SINGLE_PASS_SKIP_BLOCK`.
  A replacement that no longer finds its text is an error, not a silent no-op.

The images of ``clipvol`` and ``before`` must be equal bit for bit (checked every run). Columns:
medians over rounds of each one's ms, ``clipvol``'s and ``before``'s GL ms
(:attr:`FrameStats.gpu_ms`), and the medians of the per-round ratios to ``raw``. Rows go to
``tools/bench/results/bench_march_loops.csv``.
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

import common  # noqa: E402
from bench_frame_cost import POLICY_PARAMS, STEP, _load, cameras  # noqa: E402

#: (file, shipped text, the text before) - the loops and the division the change replaced
BEFORE = [
    ("raymarch.frag.glsl",
     "    return texelFetch(u_page_table, ivec2(i & ((1 << PT_WIDTH_LOG2) - 1), i >> PT_WIDTH_LOG2), 0).r;",
     "    return texelFetch(u_page_table, ivec2(i % u_pt_width, i / u_pt_width), 0).r;"),
    ("raymarch.frag.glsl", "uniform int u_top; ", "uniform int u_pt_width;\nuniform int u_top; "),
    ("volume_common.glsl", "    int i = 0;\n    if (n > 0) do {", "    for (int i = 0; i < n; i += SKIP_BLOCK) {"),
    ("volume_common.glsl", "    } while ((i += SKIP_BLOCK) < n);", "    }"),
    ("volume_common.glsl", "    if (i < ia) do FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t)) while (++i < ia);",
     "    for (; i < ia; ++i) FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t));"),
    ("volume_common.glsl", "    if (i < ib) do FAST_TAKE(c0 + float(i) * dc) while (++i < ib);",
     "    for (; i < ib; ++i) FAST_TAKE(c0 + float(i) * dc);"),
    ("volume_common.glsl", "    if (i < n) do FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t)) while (++i < n);",
     "    for (; i < n; ++i) FAST_TAKE(clamp(c0 + float(i) * dc, clo_t, chi_t));"),
]
#: the define that selects the source before the change (a variant of its own in the program cache)
FLAG = "BENCH_BEFORE_LOOPS"


def _install_before() -> list:
    """Make the volume shaders' source hold both versions, the one before under ``#ifdef FLAG``;
    and make the single pass's programs take ``FLAG`` while the returned switch holds True."""
    import clipvol.render.glsl as glsl
    import clipvol.render.paths.single_pass as single_pass
    from clipvol.render.paths.setup import DrawSetup

    read = glsl._read.__wrapped__

    def patched(filename: str) -> str:
        text = read(filename)
        for f, new, old in BEFORE:
            if f != filename:
                continue
            if new not in text:
                raise RuntimeError(f"{filename}: the shipped text {new.strip()[:60]!r} is gone; update BEFORE")
            text = text.replace(new, f"\n#ifdef {FLAG}\n{old}\n#else\n{new}\n#endif\n", 1)
        return text

    glsl._read = patched
    glsl.load_shader.cache_clear()
    before = [False]
    program = DrawSetup.program

    def flagged(self, vertex, fragment, defines, first_use=None):
        if before[0] and fragment == "raymarch.frag":
            defines = dict(defines, **{FLAG: 1})
            defines.pop("SKIP_BLOCK", None)  # the shader's default
        return program(self, vertex, fragment, defines, first_use)

    DrawSetup.program = flagged
    uset = single_pass.uset

    def uset_width(prog, name, value):  # the uniform width the division read
        uset(prog, name, value)
        if name == "u_top":
            uset(prog, "u_pt_width", single_pass.PAGE_TABLE_WIDTH)

    single_pass.uset = uset_width
    return before


def run(store: Path, images, rounds: int, policy: str, lod: float, log=print) -> list[dict]:
    from clipvol.render.paths.setup import OPAQUE

    before = _install_before()
    scene = common.WarmScene(store)
    rows = []
    try:
        vol = common.WholeVolume(scene.loader).read_brick(0, (0, 0, 0))
        raw = scene.raw_caster(vol)
        action = scene.action(**POLICY_PARAMS[policy](lod), step=STEP)
        for image in images:
            cam = cameras(scene.pyramid, image, "static", 3)[0]
            imgs = {}
            for name in ("clipvol", "before", "clipvol"):  # warm: every brick, both programs
                before[0] = name == "before"
                action.render(cam, scene.tf, wait=True, timeout=900)
                imgs[name] = np.asarray(action.render(cam, scene.tf)).copy()
            same = bool(np.array_equal(imgs["clipvol"], imgs["before"]))
            if not same:
                raise RuntimeError(f"{store.name} {image}^2: the images before and after differ")
            fc = action._selection_camera(cam)
            path = action.path_drawn
            raw.render(fc, scene.tf, STEP, OPAQUE)
            t = {"raw": [], "clipvol": [], "before": []}
            gl = {"clipvol": [], "before": []}
            for k in range(rounds):
                order = ["raw", "clipvol", "before"]
                for name in (order if k % 2 == 0 else order[::-1]):
                    t0 = time.perf_counter()
                    if name == "raw":
                        raw.render(fc, scene.tf, STEP, OPAQUE)
                    else:
                        before[0] = name == "before"
                        action.render(cam, scene.tf)
                        gl[name].append(action.last_frame_stats.gpu_ms)
                    t[name].append(time.perf_counter() - t0)
            before[0] = False
            ratio = {k: statistics.median(a / r for a, r in zip(t[k], t["raw"])) for k in ("clipvol", "before")}
            row = {"date": time.strftime("%Y-%m-%d"), "volume": store.name, "policy": policy, "image": image,
                   "path": path, "rounds": rounds,
                   **{f"{k}_ms": round(1e3 * statistics.median(v), 2) for k, v in t.items()},
                   **{f"{k}_gl_ms": round(statistics.median(v), 2) for k, v in gl.items()},
                   "clipvol_over_raw": round(ratio["clipvol"], 3), "before_over_raw": round(ratio["before"], 3),
                   "clipvol_over_before": round(statistics.median(a / b for a, b in zip(t["clipvol"], t["before"])), 3),
                   "images_equal": same, "load": _load()}
            rows.append(row)
            log(f"{store.name} {policy} {image}^2 ({path}): raw {row['raw_ms']} ms, clipvol {row['clipvol_ms']} ms "
                f"(gl {row['clipvol_gl_ms']}) = {row['clipvol_over_raw']}x raw, before {row['before_ms']} ms "
                f"(gl {row['before_gl_ms']}) = {row['before_over_raw']}x raw; clipvol/before "
                f"{row['clipvol_over_before']}; images equal; load {row['load']}")
    finally:
        scene.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, required=True,
                    help="a clipvol store (its level 0 is read whole for the raw caster)")
    ap.add_argument("--images", default="32,512", help="image edges, comma separated (default 32,512)")
    ap.add_argument("--rounds", type=int, default=20, help="interleaved rounds per image (default 20)")
    ap.add_argument("--policy", default="projected-size", choices=sorted(POLICY_PARAMS))
    ap.add_argument("--lod", type=float, default=0.1, help="projected-size's lod_threshold (default 0.1)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_march_loops.csv")
    a = ap.parse_args(argv)
    if a.rounds < 3:
        ap.error(f"--rounds: expected at least 3, got {a.rounds}")
    images = [int(v) for v in a.images.split(",")]
    return common.save_rows(a.out, run(a.store, images, a.rounds, a.policy, a.lod))


if __name__ == "__main__":
    sys.exit(main())
