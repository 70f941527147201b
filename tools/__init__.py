"""The command-line front of clipvol (installed as ``clipvol.tools``): the ``clipvol`` console script,
its sub-commands, and the benchmarks (``python tools/bench_*.py``)."""
