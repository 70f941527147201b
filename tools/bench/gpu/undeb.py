"""Unpack the files of Debian packages (``.deb``) into a folder, with the standard library only.

``run_gpu.sh`` needs the GL loader libraries (libglvnd's libEGL and libOpenGL) on a lent GPU
machine whose image lacks them and that has no network. Unpacking them into a private folder
(``LD_LIBRARY_PATH``) instead of ``/`` leaves the image's own libraries alone, and needs neither
root nor ``dpkg``: a ``.deb`` is an ``ar`` archive whose member ``data.tar.{xz,gz,bz2}`` holds the
files (Debian's own format, ``deb(5)``). Members compressed with zstd (newer Ubuntu builds) are
refused with a clear message: ``prepare.sh`` downloads Debian's, which use xz.

Usage: ``python3 undeb.py DEST PACKAGE.deb [...]``
"""

from __future__ import annotations

import io
import sys
import tarfile
from pathlib import Path

AR_MAGIC = b"!<arch>\n"


def members(deb: Path) -> dict[str, bytes]:
    """The ``ar`` members of ``deb``, by name (``ar(5)``: 60-byte headers, bodies padded to even)."""
    data = deb.read_bytes()
    if not data.startswith(AR_MAGIC):
        raise ValueError(f"{deb}: expected a Debian package (an ar archive), got no ar magic")
    out, pos = {}, len(AR_MAGIC)
    while pos + 60 <= len(data):
        head = data[pos:pos + 60]
        name = head[:16].decode("ascii").strip().rstrip("/")
        size = int(head[48:58].decode("ascii").strip())
        out[name] = data[pos + 60:pos + 60 + size]
        pos += 60 + size + (size & 1)
    return out


def unpack(deb: Path, dest: Path) -> list[str]:
    """Extract ``deb``'s files under ``dest``; return the names of the regular files and links."""
    parts = members(deb)
    name = next((n for n in parts if n.startswith("data.tar")), None)
    if name is None:
        raise ValueError(f"{deb}: expected a data.tar member, got {sorted(parts)}")
    if name.endswith(".zst"):
        raise ValueError(f"{deb}: {name} is zstd-compressed, which Python's tarfile cannot read; "
                         "download the Debian build (xz) with tools/bench/gpu/prepare.sh")
    with tarfile.open(fileobj=io.BytesIO(parts[name]), mode="r:*") as tar:
        safe = [m for m in tar.getmembers() if not (m.name.startswith("/") or ".." in Path(m.name).parts)]
        # the "data" filter (Python 3.11.4+, 3.12) also refuses links out of dest and device files
        tar.extractall(dest, members=safe, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
        return [m.name for m in safe if m.isfile() or m.issym()]


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    dest = Path(argv[0])
    dest.mkdir(parents=True, exist_ok=True)
    for deb in argv[1:]:
        try:
            files = unpack(Path(deb), dest)
        except (OSError, ValueError, tarfile.TarError) as e:
            print(f"undeb: {e}", file=sys.stderr)
            return 1
        print(f"{Path(deb).name}: {len(files)} files")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
