#!/usr/bin/env bash
# The GPU rows of the frame-cost benchmark and the benchmark that decides, in one command on a lent
# GPU machine (no network there; nothing outside the checkout and the carried .gpu/ folder is used).
#
# Prepare once where there is a network: `bash tools/bench/gpu/prepare.sh` (the GL loader .debs, the
# wheels for CPython 3.12 and 3.11, the MNI T1 template, into the git-ignored .gpu/), then on the GPU
# machine, from the repository root, with .gpu carried:
#     COMMIT=<hash> bash tools/bench/gpu/run_gpu.sh
# It unpacks the GL loader into $WORK (never into /), installs the wheels offline into the machine's
# Python (the image's own numpy is used when it fits), builds clipvol from the checkout, prints the GPU
# and the GL renderer and stops at once if the context is not a GPU's (llvmpipe), builds the stores (16
# cores, in parallel), then runs the parts below in order of importance, each under a `timeout` cut to
# what is left of BUDGET_S (default 510 s for the whole script), each part's failure leaving the others
# to run. CSVs, logs and a summary go to $OUT; the rows belong under tools/bench/results/*_gpu_*.csv.
#
#   frame512      bench_frame_cost.py on the 512^3 CT-like head, 16^3 bricks: clipvol's
#                 full-resolution (fixed level 0) and projected-size frames against the plain
#                 one-texture caster at 512^2 and 32^2, static / orbiting 1 deg a frame / flying
#   mission_mni   bench_mission.py on the MNI T1 template bricked at 32^3 (consistent coarse
#                 levels), the eight settings of docs/benchmarks.md's 2026-11-29 MNI rows, each with
#                 classify mean and distribution, 512^2 and 1024^2, iso / face / close, 5 rounds
#   flat          bench_frame_cost.py --flat, 32^2 orbit: the MNI template at 16^3 bricks and
#                 the head at 256^3 / 432^3 / 512^3 (16^3 bricks), host CPU per frame against the
#                 smallest cut's, and each against the raw caster
#   frame512b32   as frame512 with 32^3 bricks (the cut of the 2026-11-26 H100 rows)
#   mission_head  as mission_mni on the 512^3 head at 32^3 bricks (the H100 rows' volume)
#   report        `clipvol report` on the MNI store at 512^2: 3 views, 3 rounds, thresholds 1,4,8,
#                 --max-errors 5%, the default --refine settings; no memory, texture or block budget
#                 sweeps, no plots
# and, only when PARTS names them (run_h100.sh does), the 2026-11-26 H100 rows' empty-space skipping:
#   skip256 / skip512   bench_skip.py on the head at 256^3 (256^2, 512^2) and 512^3 (512^2, 1024^2)
#
# Environment: OUT (required), WORK (default /tmp/clipvol-gpu), BUDGET_S (510), PARTS (default all, in
# the order above), PYTHON (default: the first of python3, python3.12, python3.11 with a carried wheel
# set), COMMIT (recorded in gpu_env.txt). For a check on a machine without a GPU: GPU_CHECK=0 accepts
# any renderer, QUICK=1 shrinks every part (64^3 heads, 32-64 pixel images, few frames), INSTALL=0 uses
# PYTHON's environment as it is, GL_UNPACK=0 uses the system's GL loader.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../../.." || exit 1
ROOT=$PWD
T0=$SECONDS
: "${OUT:?run_gpu.sh: set OUT to the folder the CSVs and logs go to}"
mkdir -p "$OUT" && OUT=$(cd "$OUT" && pwd)
CARRY=${CARRY:-$ROOT/.gpu}
WORK=${WORK:-/tmp/clipvol-gpu}
BUDGET_S=${BUDGET_S:-510}
QUICK=${QUICK:-0}
GPU_CHECK=${GPU_CHECK:-1}
GL_UNPACK=${GL_UNPACK:-1}
INSTALL=${INSTALL:-1}
PARTS=${PARTS:-"frame512 mission_mni flat frame512b32 mission_head report"}
mkdir -p "$WORK"

say() { printf '[%4d s] %s\n' $((SECONDS - T0)) "$*"; }
die() { say "STOP: $1"; exit "${2:-1}"; }
packages() {  # "name version" of every distribution PY sees (pip may be absent: it ran from its wheel)
  (cd "$WORK" && "$PY" -c 'import importlib.metadata as m
print("\n".join(sorted({f"{d.name} {d.version}" for d in m.distributions()}, key=str.lower)))')
}

main() {
# ---- the sizes of each part (QUICK: a few seconds each on llvmpipe) -----------------------------------
SETTINGS_MNI="fixed L1,fixed L2,lod=2,lod=4,lod=8,max-error=5%,step=2 refine=0.16,step=2.5 refine=0.3"
if [ "$QUICK" = 1 ]; then
  HEAD=64; FLAT_HEADS="48 64"; FC_IMAGES=64,32; FC_FRAMES=3; FLAT_FRAMES=4; SKIP=(48 64 5)
  MIS_IMAGES=64; MIS_ARGS=(--repeat 2 --dev --views iso --settings "fixed L1,step=2 refine=0.16")
  REP_ARGS=(--size 64x64 --views 1 --rounds 1 --thresholds 1 --max-errors none --refine none)
else
  HEAD=512; FLAT_HEADS="256 432 512"; FC_IMAGES=512,32; FC_FRAMES=10; FLAT_FRAMES=48; SKIP=(256 512 7)
  MIS_IMAGES=512,1024; MIS_ARGS=(--repeat 5 --views iso,face,close --settings "$SETTINGS_MNI")
  REP_ARGS=(--size 512x512 --views 3 --rounds 3 --thresholds 1,4,8 --max-errors 5%)
fi
REP_ARGS+=(--tf bone --no-plots --memory-budgets none --texture-budgets none --block-budgets none)
# each part's most seconds (cut to what is left of BUDGET_S); estimates for an idle 16-core machine in
# docs/benchmarks.md, "On a lent GPU: one prepared run"
declare -A CAP=([frame512]=180 [mission_mni]=150 [flat]=120 [frame512b32]=110 [mission_head]=150 [report]=200
                [skip256]=200 [skip512]=250)
BUILD_CAP=210
MIN_PART_S=${MIN_PART_S:-30}  # a part given less is skipped

# ---- Python: the first interpreter with a carried wheel set ------------------------------------------
PY=
for cand in ${PYTHON:-python3 python3.12 python3.11}; do
  command -v "$cand" >/dev/null 2>&1 || continue
  tag=$("$cand" -c 'import sys; print("cp%d%d" % sys.version_info[:2])' 2>/dev/null) || continue
  if [ "$INSTALL" = 0 ] || [ -d "$CARRY/whl/$tag" ]; then PY=$(command -v "$cand"); break; fi
  say "$cand is CPython ${tag#cp} but $CARRY/whl/$tag was not carried"
done
[ -n "$PY" ] || die "no Python here has a carried wheel set (carried: $(ls "$CARRY/whl" 2>/dev/null | tr '\n' ' ')): run prepare.sh with PY_VERSIONS naming this machine's Python" 3
say "Python: $PY ($("$PY" -V 2>&1))"
if [ "$INSTALL" = 1 ] && [ "$GPU_CHECK" = 0 ] && [ -z "${PYTHON:-}" ]; then
  die "GPU_CHECK=0 installs into PYTHON's environment: give PYTHON=<a throwaway venv's python>, or INSTALL=0" 2
fi

# ---- the wheels, offline ------------------------------------------------------------------------------
if [ "$INSTALL" = 1 ]; then
  if "$PY" -m pip --version >/dev/null 2>&1; then PIPC=("$PY" -m pip)
  else PIPC=("$PY" "$(ls "$CARRY"/whl/any/pip-*.whl | head -1)/pip"); say "no pip in the image: pip run from its carried wheel"; fi
  # the image is thrown away after the run: its Python is installed into directly (PEP 668 waived)
  export PIP_NO_INDEX=1 PIP_FIND_LINKS="$CARRY/whl/any $CARRY/whl/$tag" PIP_BREAK_SYSTEM_PACKAGES=1 \
         PIP_ROOT_USER_ACTION=ignore PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1
  site=$(cd "$WORK" && "$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  [ -w "$site" ] || { export PIP_USER=1; say "$site is not writable: installing into the user's site-packages"; }
  "${PIPC[@]}" install -q -r tools/bench/gpu/requirements-gpu.txt > "$OUT/pip_install.log" 2>&1 \
    || { tail -20 "$OUT/pip_install.log"; die "installing the carried wheels failed (numpy missing or < 1.26 in the image? prepare.sh WITH_NUMPY=3.${tag#cp3} carries it)" 3; }
  # clipvol from the checkout (build isolation: setuptools and wheel from the carried wheels)
  rm -rf build
  "${PIPC[@]}" install -q --no-deps . >> "$OUT/pip_install.log" 2>&1 \
    || { tail -20 "$OUT/pip_install.log"; die "building clipvol from the checkout failed" 3; }
  say "installed: $(packages | grep -i -E '^(clipvol|numpy|zarr|numcodecs|moderngl|glcontext) ' | tr '\n' ';')"
fi
hash -r
# the CLI through the interpreter (its console script may sit outside PATH, /usr/local/bin or a venv's bin)
CLIPVOL=("$PY" -c 'import sys; from clipvol.tools.cli import main; sys.exit(main(sys.argv[1:]))')

# ---- the GL loader (libglvnd) and the NVIDIA EGL vendor -------------------------------------------------
if [ "$GL_UNPACK" = 1 ]; then
  "$PY" tools/bench/gpu/undeb.py "$WORK/gl" "$CARRY"/deb/*.deb > "$OUT/gl_unpack.log" 2>&1 \
    || { cat "$OUT/gl_unpack.log"; die "unpacking the GL loader failed" 3; }
  GLLIB=$WORK/gl/usr/lib/x86_64-linux-gnu
  export LD_LIBRARY_PATH="$GLLIB${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  export GLCONTEXT_LINUX_LIBEGL=$GLLIB/libEGL.so.1 GLCONTEXT_LINUX_LIBGL=$GLLIB/libOpenGL.so.0
fi
if [ "$GPU_CHECK" = 1 ]; then
  [ -d /usr/local/nvidia/lib64 ] && export LD_LIBRARY_PATH="${LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}/usr/local/nvidia/lib64"
  vendor=
  for j in /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json /usr/share/glvnd/egl_vendor.d/10_nvidia.json \
           /etc/glvnd/egl_vendor.d/10_nvidia.json; do [ -e "$j" ] && { vendor=$j; break; }; done
  if [ -z "$vendor" ]; then  # the driver's EGL library without its vendor file: write one
    lib=$(ldconfig -p 2>/dev/null | awk '/libEGL_nvidia\.so\.0/ {print $NF; exit}')
    [ -n "$lib" ] || lib=$(find /usr/local/nvidia /usr/lib/x86_64-linux-gnu /usr/lib64 /usr/lib -maxdepth 2 -name 'libEGL_nvidia.so.0' 2>/dev/null | head -1)
    if [ -n "$lib" ]; then
      vendor=$WORK/10_nvidia.json
      printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "%s"}}\n' "$lib" > "$vendor"
    else
      say "no NVIDIA EGL library (libEGL_nvidia.so.0) in this container: the driver's EGL part is not mounted"
    fi
  fi
  # only the NVIDIA vendor: device 0 is then the GPU, not a Mesa software device
  [ -n "$vendor" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$vendor && say "EGL vendor: $vendor"
fi
GPU=$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null | head -1)
say "GPU: ${GPU:-none reported by nvidia-smi}"
GL=$(cd "$WORK" && "$PY" -c '
from clipvol.render import create_context
c = create_context()
print(c.info["GL_RENDERER"], "|", c.info["GL_VENDOR"], "|", c.info["GL_VERSION"])' 2>"$OUT/gl_check.log") \
  || { tail -5 "$OUT/gl_check.log"; die "no GL context (above); LD_LIBRARY_PATH=$LD_LIBRARY_PATH" 4; }
say "GL: $GL"
{ echo "date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"; echo "commit: ${COMMIT:-$(git rev-parse HEAD 2>/dev/null || echo unknown)}"
  echo "gpu: ${GPU:-none}"; echo "gl: $GL"; echo "python: $("$PY" -V 2>&1)"; echo "cpu: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"
  echo "load: $(cat /proc/loadavg)"; echo "quick: $QUICK"; echo "packages:"; packages; } > "$OUT/gpu_env.txt"
if [ "$GPU_CHECK" = 1 ] && ! grep -qi nvidia <<<"$GL"; then
  die "the GL context is not an NVIDIA GPU's ($GL): no GPU rows would come of it" 4
fi

# ---- the stores, built in parallel before anything is timed ---------------------------------------------
mkdir -p "$WORK/bench-data"
head_store() { echo "$WORK/bench-data/ct-$1x$1x$1-b$2-uint16-crc.zarr"; }
want() { case " $PARTS " in *" $1 "*) return 0;; esac; return 1; }
builds=()
want mission_mni || want report && builds+=("mni 32")
want flat && builds+=("mni 16")
want frame512 || want flat && builds+=("head $HEAD 16")
want frame512b32 || want mission_head && builds+=("head $HEAD 32")
if want flat; then for n in $FLAT_HEADS; do [ "$n" = "$HEAD" ] || builds+=("head $n 16"); done; fi
pids=()
for b in "${builds[@]}"; do
  set -- $b
  if [ "$1" = mni ]; then
    log=$OUT/build_mni$2.log
    (cd "$WORK" && timeout -k 5 $BUILD_CAP "${CLIPVOL[@]}" brick "$CARRY/data/mni_t1.nii.gz" "$WORK/mni$2.zarr" --brick "$2" --overwrite) > "$log" 2>&1 &
  else
    log=$OUT/build_head$2_b$3.log
    (cd "$WORK" && timeout -k 5 $BUILD_CAP "$PY" -c "import sys; sys.path.insert(0, '$ROOT/tools/bench'); import common
from pathlib import Path; print(common.ct_store('$2x$2x$2', $3, Path('$WORK/bench-data')))") > "$log" 2>&1 &
  fi
  pids+=($!)
done
say "building ${#builds[@]} stores in parallel: ${builds[*]}"
for i in "${!pids[@]}"; do wait "${pids[$i]}" || say "build '${builds[$i]}' failed (rc $?): its log is in $OUT"; done
say "stores built"

# ---- the parts -----------------------------------------------------------------------------------------
declare -A STATUS SECS FILES
part_cmd() {  # the command line of part $1, one argument per line
  case $1 in
    frame512) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_frame_cost.py --store "$(head_store $HEAD 16)" --head "" \
                --policies fixed,projected-size --images $FC_IMAGES --frames $FC_FRAMES --out "$OUT/bench_frame_cost_gpu_${HEAD}b16.csv";;
    mission_mni) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_mission.py --store "$WORK/mni32.zarr" --images $MIS_IMAGES \
                "${MIS_ARGS[@]}" --out "$OUT/bench_mission_gpu_mni32.csv";;
    flat) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_frame_cost.py --flat --store "$WORK/mni16.zarr"
          for n in $FLAT_HEADS; do printf '%s\n' --store "$(head_store $n 16)"; done
          printf '%s\n' --head "" --policies projected-size --images 32 --frames $FLAT_FRAMES --out "$OUT/bench_frame_cost_flat_gpu.csv";;
    frame512b32) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_frame_cost.py --store "$(head_store $HEAD 32)" --head "" \
                --policies fixed,projected-size --images $FC_IMAGES --frames $FC_FRAMES --out "$OUT/bench_frame_cost_gpu_${HEAD}b32.csv";;
    mission_head) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_mission.py --store "$(head_store $HEAD 32)" --images $MIS_IMAGES \
                "${MIS_ARGS[@]}" --out "$OUT/bench_mission_gpu_head${HEAD}b32.csv";;
    report) printf '%s\n' "${CLIPVOL[@]}" report "$WORK/mni32.zarr" --out "$OUT/report_mni32_gpu" "${REP_ARGS[@]}";;
    skip256) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_skip.py --size ${SKIP[0]} --images ${SKIP[0]},${SKIP[1]} \
               --repeat ${SKIP[2]} --out "$OUT/bench_skip_gpu_${SKIP[0]}.csv";;
    skip512) printf '%s\n' "$PY" "$ROOT"/tools/bench/bench_skip.py --size ${SKIP[1]} --images ${SKIP[1]},$((2 * SKIP[1])) \
               --repeat ${SKIP[2]} --out "$OUT/bench_skip_gpu_${SKIP[1]}.csv";;
    *) return 1;;
  esac
}
for p in $PARTS; do
  mapfile -t cmd < <(part_cmd "$p") || true
  if [ "${#cmd[@]}" = 0 ]; then STATUS[$p]="unknown part"; continue; fi
  left=$((BUDGET_S - (SECONDS - T0) - 5))
  t=${CAP[$p]}; [ "$left" -lt "$t" ] && t=$left
  if [ "$t" -lt "$MIN_PART_S" ]; then STATUS[$p]="skipped: ${left} s left of BUDGET_S=$BUDGET_S"; say "$p: ${STATUS[$p]}"; continue; fi
  say "$p (at most $t s; the command heads $p.log)"
  s=$SECONDS
  printf '%q ' "${cmd[@]}" > "$OUT/$p.log"; echo >> "$OUT/$p.log"
  # from $WORK: a `python -c` in the checkout would import its clipvol/ folder, not the installed package
  (cd "$WORK" && exec timeout -k 10 "$t" "${cmd[@]}") >> "$OUT/$p.log" 2>&1
  rc=$?
  SECS[$p]=$((SECONDS - s))
  case $rc in 0) STATUS[$p]=ok;; 124|137) STATUS[$p]="timed out after $t s";; *) STATUS[$p]="failed (rc $rc)";; esac
  out=$(printf '%s\n' "${cmd[@]}" | grep -A1 -x -- --out | tail -1)
  FILES[$p]="$p.log${out:+ $(basename "$out")}"
  say "$p: ${STATUS[$p]} in ${SECS[$p]} s"
  [ "$rc" = 0 ] || tail -4 "$OUT/$p.log" | cut -c1-400
done

# ---- summary ------------------------------------------------------------------------------------------
echo
echo "== headlines"
for p in $PARTS; do
  [ -f "$OUT/$p.log" ] || continue
  case $p in
    frame512|frame512b32) grep -E "\^2 (static|orbit|fly)" "$OUT/$p.log" \
                            | sed -E 's/, [0-9]+ % kept cut[^)]*\)/)/; s/; from nothing.*//; s/-uint16-crc.zarr//' | cut -c1-200;;
    mission_*) grep -E "^[0-9]+\^2 [a-z]+: full" "$OUT/$p.log" | sed -E 's/ against the converged picture//; s/ \(target 5x: .*//' | cut -c1-220;;
    flat) grep -E "orbit \(" "$OUT/$p.log" | sed -E 's/-uint16-crc.zarr//' | cut -c1-240;;
    report) grep -E "^At <= " "$OUT/$p.log" | cut -c1-300;;
    skip*) grep -E "skip/raw" "$OUT/$p.log" | cut -c1-200;;
  esac
done
# the frame-cost GPU target (<= 1.1x the plain caster, >= 60 fps), read from the CSVs: the full-resolution frame at the first image size
for f in "$OUT"/bench_frame_cost_gpu_*.csv; do
  [ -f "$f" ] || continue
  "$PY" - "$f" "${FC_IMAGES%%,*}" <<'PYEOF'
import csv, sys
for r in csv.DictReader(open(sys.argv[1])):
    if r["image"] == sys.argv[2] and r["volume"].endswith(", fixed"):
        ms, ratio = float(r["clipvol_ms"]), float(r["clipvol_over_raw"])
        print(f"target (full resolution, {r['image']}^2, {r['volume'].split(',')[0].replace('-uint16-crc.zarr', '')}, "
              f"{r['camera']}): {ratio}x the plain caster ({'met' if ratio <= 1.1 else 'not met'}: <= 1.1x), "
              f"{1e3 / ms:.0f} fps ({'met' if 1e3 / ms >= 60 else 'not met'}: >= 60)")
PYEOF
done
echo
echo "== summary ($((SECONDS - T0)) s of BUDGET_S=$BUDGET_S; GL: $GL)"
for p in $PARTS; do printf '%-13s %-40s %5s s  %s\n' "$p" "${STATUS[$p]:-not run}" "${SECS[$p]:--}" "${FILES[$p]:-}"; done
echo "files in $OUT: gpu_env.txt, run_gpu.log, build_*.log, <part>.log, the CSVs above (rows for tools/bench/results/*_gpu_*.csv)"
}

# everything to the console and to run_gpu.log (the pipe ends before the script does: no lost tail)
main 2>&1 | tee -a "$OUT/run_gpu.log"
exit "${PIPESTATUS[0]}"
