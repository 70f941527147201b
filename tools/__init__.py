"""The command-line front of clipvol (installed as ``clipvol.tools``): the ``clipvol`` console script
and its sub-commands. The benchmarks live beside it in ``tools/bench/`` (run as scripts from the
repository: ``python tools/bench/bench_render.py``); they are not installed."""
