"""``tools/bench/gpu/undeb.py`` (the GL loader's unpacker for a lent GPU machine without dpkg or root)
unpacks a Debian package as ``dpkg-deb -x`` does: the reference is dpkg's own tool, on packages
that dpkg-deb builds."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(shutil.which("dpkg-deb") is None, reason="needs dpkg-deb (the reference)")


def _undeb():
    spec = importlib.util.spec_from_file_location("undeb", ROOT / "tools" / "bench" / "gpu" / "undeb.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _tree(root: Path) -> dict:
    """Every file and link under ``root``: its bytes and permission bits, or its link target."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_symlink():
            out[rel] = ("link", os.readlink(p))
        elif p.is_file():
            out[rel] = ("file", p.read_bytes(), p.stat().st_mode & 0o777)
    return out


def _package(tmp_path: Path, compression: str) -> Path:
    """A .deb built by dpkg-deb: a shared library (an odd size: the ar member is padded), its soname
    link and a doc file, ``compression`` its data member's compressor."""
    pkg = tmp_path / "pkg"
    if not pkg.exists():
        (pkg / "DEBIAN").mkdir(parents=True)
        (pkg / "DEBIAN" / "control").write_text(
            "Package: t\nVersion: 1.0\nArchitecture: amd64\nMaintainer: t <t@example.org>\nDescription: t\n")
        lib = pkg / "usr" / "lib" / "x86_64-linux-gnu"
        lib.mkdir(parents=True)
        (lib / "libT.so.1.2.0").write_bytes(os.urandom(5001))
        (lib / "libT.so.1.2.0").chmod(0o644)
        (lib / "libT.so.1").symlink_to("libT.so.1.2.0")
        doc = pkg / "usr" / "share" / "doc" / "t"
        doc.mkdir(parents=True)
        (doc / "copyright").write_text("none\n")
    deb = tmp_path / f"t-{compression}.deb"
    subprocess.run(["dpkg-deb", "--root-owner-group", f"-Z{compression}", "--build", str(pkg), str(deb)],
                   check=True, capture_output=True)
    return deb


@pytest.mark.parametrize("compression", ["xz", "gzip"])
def test_unpacks_what_dpkg_deb_unpacks(tmp_path, compression):
    deb = _package(tmp_path, compression)
    ref, got = tmp_path / "ref", tmp_path / "got"
    subprocess.run(["dpkg-deb", "-x", str(deb), str(ref)], check=True)
    assert _undeb().main([str(got), str(deb)]) == 0
    want = _tree(ref)
    assert "usr/lib/x86_64-linux-gnu/libT.so.1" in want
    assert _tree(got) == want


def test_refuses_zstd_and_non_packages_by_name(tmp_path, capsys):
    undeb = _undeb()
    if subprocess.run(["dpkg-deb", "--help"], capture_output=True, text=True).stdout.find("zstd") >= 0:
        deb = _package(tmp_path, "zstd")
        assert undeb.main([str(tmp_path / "z"), str(deb)]) == 1
        assert f"{deb}: data.tar.zst is zstd-compressed" in capsys.readouterr().err
    bad = tmp_path / "bad.deb"
    bad.write_bytes(b"not an archive")
    assert undeb.main([str(tmp_path / "b"), str(bad)]) == 1
    assert f"{bad}: expected a Debian package" in capsys.readouterr().err


@pytest.mark.skipif(shutil.which("ar") is None, reason="needs binutils' ar (the reference)")
def test_reads_every_member_of_an_ar_archive_binutils_writes(tmp_path):
    """Members of odd sizes are padded to an even offset (ar(5)); binutils' ``ar`` writes the archive."""
    files = {"debian-binary": b"2.0\n", "control.tar.gz": os.urandom(301), "odd": os.urandom(7),
             "data.tar.xz": os.urandom(1000)}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    deb = tmp_path / "a.deb"
    subprocess.run(["ar", "rc", str(deb), *files], cwd=tmp_path, check=True)
    assert _undeb().members(deb) == files
