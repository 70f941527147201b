"""How long ``clipvol --help`` and ``clipvol CMD --help`` take, as whole processes.

The reference outside clipvol's code path is the bare interpreter of the same environment
(``python -c pass``: its start-up, ``site`` and the installed packages' ``.pth`` hooks), timed in
the same rounds, interleaved. ``--before DIR`` adds an older checkout of the repository (its
``clipvol``, ``tools`` and ``loaders`` put first on the path from a temporary folder), so a change is
measured against the code before it in the same run. Each round runs every command once, in turn;
a figure is the median over the rounds of the process's wall time and of its CPU time (user +
system, from the operating system's accounting of the finished child).

Run from a checkout: ``python tools/bench/bench_front_door.py --rounds 9 [--before /path/to/old]``.
It imports no numpy itself (this folder's ``common.py`` does, so it is not used). Rows go to
``tools/bench/results/bench_front_door.csv``.
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
#: the command lines timed (after ``python -m clipvol.tools.cli``)
HELPS = (("--help",), ("render", "--help"), ("view", "--help"), ("slice", "--help"), ("report", "--help"))


def _timed(argv: list[str], env: dict, cwd: str) -> tuple[float, float]:
    """``(wall s, CPU s)`` of one run of ``argv`` to the end (output thrown away)."""
    t = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=cwd)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)}: exit status {proc.returncode}")
    return wall, usage.ru_utime + usage.ru_stime


def _old_tree(checkout: Path, into: Path) -> Path:
    """A folder that makes ``import clipvol`` (with ``clipvol.tools`` and ``clipvol.loaders``) the
    checkout's: ``into/clipvol`` links every entry of ``checkout/clipvol`` and the two installed
    folders, so the editable install's mapping of ``clipvol.tools`` to this checkout is not reached."""
    pkg = into / "clipvol"
    pkg.mkdir()
    for entry in (checkout / "clipvol").iterdir():
        (pkg / entry.name).symlink_to(entry)
    for name in ("tools", "loaders"):
        if not (pkg / name).exists():
            (pkg / name).symlink_to(checkout / name)
    return into


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--before", type=Path, default=None, metavar="DIR", help="an older checkout to time in the same rounds")
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_front_door.csv")
    args = ap.parse_args(argv)
    py = sys.executable
    base_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    with tempfile.TemporaryDirectory() as tmp:
        runs = {"python -c pass": ([py, "-c", "pass"], base_env)}
        for h in HELPS:
            runs[f"clipvol {' '.join(h)}"] = ([py, "-m", "clipvol.tools.cli", *h], base_env)
        if args.before is not None:
            (Path(tmp) / "before").mkdir()  # not the working folder, which ``-m`` puts first on the path
            old = _old_tree(args.before.resolve(), Path(tmp) / "before")
            for h in HELPS:
                runs[f"before: clipvol {' '.join(h)}"] = ([py, "-m", "clipvol.tools.cli", *h],
                                                         {**base_env, "PYTHONPATH": str(old)})
        for argv_, env in runs.values():  # warm the file cache and the .pyc files
            _timed(argv_, env, tmp)
        got: dict[str, list[tuple[float, float]]] = {name: [] for name in runs}
        for _ in range(args.rounds):
            for name, (argv_, env) in runs.items():
                got[name].append(_timed(argv_, env, tmp))
    load = os.getloadavg()[0]
    bare_wall = statistics.median(w for w, _ in got["python -c pass"])
    bare_cpu = statistics.median(c for _, c in got["python -c pass"])
    rows = []
    print(f"{args.rounds} rounds, load {load:.1f}; ratios to the bare interpreter (python -c pass) of the same rounds")
    print(f"{'command':40s} {'wall s':>8s} {'CPU s':>8s} {'wall/bare':>10s} {'CPU/bare':>9s} {'CPU/before':>11s}")
    for name, xs in got.items():
        wall, cpu = statistics.median(w for w, _ in xs), statistics.median(c for _, c in xs)
        before = got.get(f"before: {name}")
        vs = statistics.median(c for _, c in xs) / statistics.median(c for _, c in before) if before else None
        print(f"{name:40s} {wall:8.3f} {cpu:8.3f} {wall / bare_wall:10.2f} {cpu / bare_cpu:9.2f} "
              f"{'' if vs is None else f'{vs:11.2f}'}")
        rows.append(dict(command=name, rounds=args.rounds, wall_s=f"{wall:.4f}", cpu_s=f"{cpu:.4f}",
                         wall_over_bare=f"{wall / bare_wall:.3f}", cpu_over_bare=f"{cpu / bare_cpu:.3f}",
                         cpu_over_before="" if vs is None else f"{vs:.3f}", load=f"{load:.2f}",
                         date=time.strftime("%Y-%m-%d")))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
