#!/usr/bin/env bash
# The 2026-11-26 H100 rows again, on any lent GPU: empty-space skipping (bench_skip.py, the head at
# 256^3 and 512^3) and the benchmark that decides on the 512^3 head at 32^3 bricks. A thin alias of
# run_gpu.sh (which prepares the machine from the carried .gpu/ folder; see its header and
# docs/benchmarks.md, "On a lent GPU: one prepared run"); the mission part now times the eight
# settings of the 2026-11-29 rows, each with classify mean and distribution, not every setting.
# The .gl/ and .whl/ folders this script used to read are prepare.sh's .gpu/deb and .gpu/whl.
PARTS=${PARTS:-"skip256 skip512 mission_head"} exec bash "$(dirname "${BASH_SOURCE[0]}")/run_gpu.sh" "$@"
