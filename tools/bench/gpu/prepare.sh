#!/usr/bin/env bash
# Fetch, on a machine with a network, what tools/bench/gpu/run_gpu.sh needs on a lent GPU machine
# that has none, into the git-ignored folder .gpu/ beside the checkout:
#   .gpu/deb/         the GL loader libraries (libglvnd's libEGL, libOpenGL and libGLdispatch:
#                     Debian bookworm's libegl1, libopengl0, libglvnd0); the NVIDIA driver brings
#                     the vendor library (libEGL_nvidia) they dispatch to. No libGL / libGLX: with
#                     EGL, libOpenGL.so.0 serves the GL functions (glcontext's GLCONTEXT_LINUX_LIBGL),
#                     so nothing of X11 is needed. Unpacked there by undeb.py into /tmp, never into /.
#   .gpu/whl/any/     pure-Python wheels (and abi3 ones), shared by every Python version
#   .gpu/whl/cpXY/    the compiled wheels for CPython X.Y, manylinux x86_64 (default 3.12 and 3.11)
#   .gpu/data/        the MNI ICBM152 2009a T1 template (real anatomy; bricked on the GPU machine)
# The wheels are tools/bench/gpu/requirements-gpu.txt resolved for each Python, plus setuptools and
# wheel (pip builds clipvol from the checkout with them) and pip (in case the image has no pip).
# numpy is left out (the image's own is used; a wheel is 16.6 MB a Python version) unless
# WITH_NUMPY lists versions ("3.12", "3.12 3.11"; "1" means 3.12).
# Prints the total size (the carried paths may hold 64 MiB in all) and the `carry` list to pass.
#
# Usage: bash tools/bench/gpu/prepare.sh      (env: PY_VERSIONS, WITH_NUMPY, MNI, DEST, PIP)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../../.."
DEST=${DEST:-.gpu}
PY_VERSIONS=${PY_VERSIONS:-"3.12 3.11"}
WITH_NUMPY=${WITH_NUMPY:-}
[ "$WITH_NUMPY" = 1 ] && WITH_NUMPY=3.12
MNI=${MNI:-/work/data/mni_t1.nii.gz}
PIP=${PIP:-"python3 -m pip"}
REQ=tools/bench/gpu/requirements-gpu.txt
NUMPY_PIN=numpy==2.4.6  # the version the llvmpipe figures were measured with (kept only with WITH_NUMPY)
DEBS="libglvnd0 libegl1 libopengl0"
LIMIT_MIB=64

git check-ignore -q "$DEST/x" || { echo "prepare.sh: $DEST/ is not git-ignored (add /$DEST/ to .gitignore)" >&2; exit 1; }
[ -f "$MNI" ] || { echo "prepare.sh: expected the MNI T1 template at $MNI (MNI=...), got no file" >&2; exit 1; }
rm -rf "$DEST"
mkdir -p "$DEST/deb" "$DEST/whl/any" "$DEST/data"

echo "== GL loader packages: $DEBS"
# apt-get download needs no root; it fetches the candidate version of this machine's sources (bookworm)
(cd "$DEST/deb" && apt-get download $DEBS 2>&1 | grep -v "^W: Download is performed unsandboxed" || true)
for p in $DEBS; do ls "$DEST"/deb/${p}_*.deb >/dev/null 2>&1 || { echo "prepare.sh: apt-get download $p failed" >&2; exit 1; }; done

for v in $PY_VERSIONS; do
  tag=cp${v/./}
  echo "== wheels for CPython $v ($tag, manylinux x86_64)"
  # every manylinux tag up to glibc 2.28 (numpy 2.4 and pillow ship 2_27/2_28 wheels only)
  $PIP download -q --disable-pip-version-check --only-binary=:all: --python-version "$v" --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux_2_12_x86_64 --platform manylinux2010_x86_64 \
    --platform manylinux_2_5_x86_64 --platform manylinux1_x86_64 \
    -d "$DEST/whl/$tag" -r "$REQ" "$NUMPY_PIN" "setuptools>=68" wheel pip 2>&1 | grep -v "is ignored: it is neither a file nor a directory" || true
  # every requirement must have resolved to a wheel here: a missing one would fail offline on the GPU machine
  have=$(ls "$DEST/whl/$tag" | sed 's/-.*//' | tr 'A-Z.-' 'a-z__')  # the wheels' distribution names
  for r in $(grep -v '^#' "$REQ" | sed 's/[<>=!;].*//' | tr -d ' ' | grep .) setuptools wheel pip; do
    n=$(echo "$r" | tr 'A-Z.-' 'a-z__')
    grep -qx "$n" <<<"$have" || { echo "prepare.sh: no wheel of $r for CPython $v" >&2; exit 1; }
  done
  case " $WITH_NUMPY " in *" $v "*) echo "   numpy kept for $v (WITH_NUMPY)";; *) rm -f "$DEST/whl/$tag"/numpy-*.whl;; esac
done

# one copy of each wheel that serves every version (py3-none-any, abi3)
for f in "$DEST"/whl/cp*/*-none-any.whl "$DEST"/whl/cp*/*-abi3-*.whl; do
  [ -e "$f" ] || continue
  if [ -e "$DEST/whl/any/$(basename "$f")" ]; then rm -f "$f"; else mv "$f" "$DEST/whl/any/"; fi
done

echo "== data"
cp "$MNI" "$DEST/data/mni_t1.nii.gz"

(cd "$DEST" && find . -type f ! -name MANIFEST.txt | sort | xargs sha256sum) > "$DEST/MANIFEST.txt"
{ echo "# prepared $(date -u +%Y-%m-%dT%H:%MZ) on $(. /etc/os-release && echo "$PRETTY_NAME"), commit $(git rev-parse --short HEAD)"; cat "$DEST/MANIFEST.txt"; } > "$DEST/MANIFEST.tmp"
mv "$DEST/MANIFEST.tmp" "$DEST/MANIFEST.txt"

echo "== sizes"
du -sh "$DEST"/deb "$DEST"/whl/* "$DEST"/data
bytes=$(du -sb "$DEST" | cut -f1)
mib=$(( (bytes + 1048575) / 1048576 ))
echo "total carried: $bytes bytes ($mib MiB of the $LIMIT_MIB MiB the carried paths may hold)"
[ "$mib" -lt "$LIMIT_MIB" ] || { echo "prepare.sh: $DEST is over $LIMIT_MIB MiB: drop WITH_NUMPY or a Python version" >&2; exit 1; }
echo
echo "carry: [\"$DEST\"]"
echo "command: bash tools/bench/gpu/run_gpu.sh"
