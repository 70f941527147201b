#!/usr/bin/env bash
# The renderer's benchmarks on a lent GPU machine (no network there): the GL loader libraries
# (.gl/*.deb) and the Python wheels clipvol needs beyond that machine's image (.whl/) travel with
# the checkout. Prints the GL renderer, then runs bench_skip (empty-space skipping against the raw
# one-texture caster) at two volume sizes; CSVs are copied to $OUT.
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done
lib=/usr/lib/x86_64-linux-gnu  # glcontext opens libEGL.so / libGL.so (the -dev names)
[ -e $lib/libEGL.so ] || ln -s $lib/libEGL.so.1 $lib/libEGL.so
[ -e $lib/libGL.so ] || ln -s $lib/libGL.so.1 $lib/libGL.so
ldconfig
v=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; [ -e $v ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$v
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site
rm -rf /tmp/clip; python3 -m pip install -q --no-index --no-deps --no-build-isolation --no-cache-dir --target /tmp/clip . || exit 1
export PYTHONPATH=/tmp/clip:/tmp/site
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
python3 -c "from clipvol.render import create_context; c = create_context(); print('GL:', c.info['GL_RENDERER'], c.info['GL_VERSION'])" || exit 1
mkdir -p "$OUT"
[ -n "${SKIP_SKIP:-}" ] || timeout 200 python3 tools/bench/bench_skip.py --size 256 --images 256,512 --repeat 7 --out "$OUT/bench_skip_h100_256.csv"
[ -n "${SKIP_SKIP:-}" ] || timeout 250 python3 tools/bench/bench_skip.py --size 512 --images 512,1024 --repeat 7 --out "$OUT/bench_skip_h100_512.csv"
# the mission's number (issue: 5x faster than full resolution at <= 5 % of pixels dE>=6)
timeout 420 python3 tools/bench/bench_mission.py --size 512x512x512 --images 512,1024 --repeat 5 --out "$OUT/bench_mission_h100.csv"
