"""The flags every drawing command shares (:mod:`clipvol.tools.common_args`): each command parses the
defaults it always had, and refuses the same bad value of a shared flag with the same one-line error
naming the flag, exit status 2, before anything is opened or written.

References: a literal table of each command's defaults (as the commands declared them one by one),
the clip-texture's own thread limit, and the files on disk (absent after a refusal).
"""

from __future__ import annotations

import pytest

from clipvol.tools.cli import build_parser, main

#: a command does not offer this flag
ABSENT = object()
REMOTE = {"cache": None, "in_flight": None, "connect_timeout": None, "read_timeout": None}
CUT = {"crop": None, "crop_voxels": None, "clip_plane": []}
NO_CUT = {"crop": ABSENT, "crop_voxels": ABSENT, "clip_plane": ABSENT}

#: command -> (minimal command line, the parsed value of each shared flag)
DEFAULTS = {
    "render": (["render", "s", "-o", "a.png"], {
        "store": None, "brick": None, "size": (512, 512), "memory_budget": "256MB", "threads": None,
        "no_wait": False, "timeout": 300.0, "allow_partial": False, "unverified": False, **REMOTE, **CUT}),
    "view": (["view", "s"], {
        "store": None, "brick": None, "size": None, "memory_budget": "256MB", "threads": None,
        "no_wait": ABSENT, "timeout": 60.0, "allow_partial": False, "unverified": False, **REMOTE, **CUT}),
    "slice": (["slice", "s"], {
        "store": None, "brick": None, "size": None, "memory_budget": "256MB", "threads": None,
        "no_wait": False, "timeout": 300.0, "allow_partial": False, "unverified": False, **REMOTE, **CUT}),
    "report": (["report", "s", "--out", "r"], {
        "store": ABSENT, "brick": None, "size": (192, 192), "memory_budget": ABSENT, "threads": None,
        "no_wait": ABSENT, "timeout": 120.0, "allow_partial": False, "unverified": False, **REMOTE, **NO_CUT}),
    "export": (["export", "s", "--out", "x.npy", "--box", "0:1,0:1,0:1"], {
        "brick_store": None, "brick": ABSENT,  # its positional STORE is the store itself
        "size": ABSENT, "memory_budget": ABSENT,
        "threads": ABSENT, "no_wait": ABSENT, "timeout": ABSENT, "allow_partial": ABSENT, "unverified": False,
        **REMOTE, **NO_CUT}),
}


@pytest.mark.parametrize("command", sorted(DEFAULTS))
def test_each_command_parses_its_own_defaults(command):
    argv, want = DEFAULTS[command]
    args = build_parser().parse_args(argv)
    for dest, value in want.items():
        if value is ABSENT:
            assert not hasattr(args, dest), (command, dest)
        else:
            assert hasattr(args, dest), (command, dest)
            got = getattr(args, dest)
            assert got == value and type(got) is type(value), (command, dest, got)


def test_given_values_parse_alike_in_every_command():
    p = build_parser()
    for command in ("render", "view", "slice"):
        argv = DEFAULTS[command][0]
        args = p.parse_args([*argv, "--threads", "3", "--timeout", "2.5", "--memory-budget", "1GiB", "--size", "40x30",
                             "--brick", "16", "--store", "x.zarr", "--unverified", "--allow-partial"])
        assert (args.threads, args.timeout, args.memory_budget, args.size, args.brick, args.store) == \
            (3, 2.5, "1GiB", (40, 30), 16, "x.zarr"), command
        assert args.unverified and args.allow_partial, command


def test_the_threads_limit_is_the_clip_textures():
    from clipvol.paging.cliptexture import MAX_LOADER_THREADS
    from clipvol.tools.common_args import MAX_THREADS

    assert MAX_THREADS == MAX_LOADER_THREADS


#: flag -> bad values (each refused by every command that offers the flag)
BAD = {
    "--threads": ["0", "257", "-3"],
    "--timeout": ["0", "-1", "nan", "inf", "1e9"],
    "--memory-budget": ["0", "12XB", "lots", "-5MB"],
    "--brick": ["0", "-8"],
}
#: command -> extra arguments that keep a refused run from touching anything (an output in tmp)
SRC = "procedural:fractal?size=16"


def _argv(command, tmp_path):
    out = str(tmp_path / "out")
    return {
        "render": ["render", SRC, "-o", out + ".png", "--size", "16x16"],
        "view": ["view", SRC, "--offscreen", "--frames", "1", "--size", "16x16", "--out", out],
        "slice": ["slice", SRC, "-o", out + ".png"],
        "report": ["report", SRC, "--out", out, "--size", "16x16", "--views", "1"],
    }[command]


def _offers(command, flag) -> bool:
    return DEFAULTS[command][1].get(flag[2:].replace("-", "_"), ABSENT) is not ABSENT


CASES = [(c, f, v) for c in ("render", "view", "slice", "report") for f, vs in BAD.items() if _offers(c, f) for v in vs]


@pytest.mark.parametrize("command,flag,value", CASES)
def test_a_bad_shared_value_is_one_line_naming_the_flag(command, flag, value, tmp_path, capsys):
    assert main([*_argv(command, tmp_path), f"{flag}={value}"]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"clipvol {command}: error: {flag}: expected "), lines[0]
    assert list(tmp_path.iterdir()) == [], "a refused run wrote something"


@pytest.mark.parametrize("flag,value", [(f, vs[0]) for f, vs in BAD.items()])
def test_every_command_refuses_with_the_same_words(flag, value, tmp_path, capsys):
    said = set()
    for command in ("render", "view", "slice", "report"):
        if not _offers(command, flag):
            continue
        assert main([*_argv(command, tmp_path), f"{flag}={value}"]) == 2
        said.add(capsys.readouterr().err.split(": error: ", 1)[1])
    assert len(said) == 1, said


def test_a_bad_size_is_refused_by_every_command(tmp_path, capsys):
    for command in ("render", "view", "slice", "report"):
        with pytest.raises(SystemExit) as e:
            main([*_argv(command, tmp_path), "--size", "0x16"])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert err == f"clipvol {command}: error: argument --size: expected 1..16384 pixels per side, got '0x16'", err


def test_brick_of_clipvol_brick_keeps_its_own_check(tmp_path, capsys):
    """``clipvol brick --brick`` is the store's brick edge (even, 8..256), not a shared flag."""
    import numpy as np

    np.save(tmp_path / "v.npy", np.zeros((8, 8, 8), np.uint8))
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "v.zarr"), "--brick", "0"]) == 2
    err = capsys.readouterr().err
    assert "8..256" in err and "--brick: expected a brick edge >= 1" not in err, err
