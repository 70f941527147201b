"""One meaning per flag across commands: a flag several commands offer reads and parses the same in each.

Reference: argparse's own actions of the parser ``clipvol`` builds (``build_parser()``'s sub-parsers,
``tf save`` included), read without the modules that declare the flags. For every documented
(not hidden) long flag that two or more commands offer, its action kind, type, choices, default,
``nargs``/``const`` and help must be the same in each; a command that needs another value where
the flag is left out says so in that one help (and ``clipvol`` fills it in: :func:`_parsed`).
Threads are ``--threads``, worker processes ``--workers``; an old spelling (hidden) still parses
into the documented flag it was renamed to.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import pytest

from clipvol.tools.cli import build_parser

#: the one flag whose help and default are each command's own, and why: ``--out`` names what the
#: command writes (a PNG, a folder of frames, a report folder, a region file), which its
#: description already says; its type (a path as typed) is still checked below
OWN_OUTPUT = {"--out": {"help", "default"}}


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """command (``"tf save"`` for a nested one) -> its parser, every command of ``clipvol``."""
    out: dict[str, argparse.ArgumentParser] = {}

    def walk(prefix: str, parser: argparse.ArgumentParser) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    full = f"{prefix} {name}".strip()
                    out[full] = sub
                    walk(full, sub)

    walk("", build_parser())
    return out


def _documented(parser) -> dict[str, argparse.Action]:
    """long flag -> action, of the flags ``--help`` shows."""
    return {o: a for a in parser._actions if a.help is not argparse.SUPPRESS
            for o in a.option_strings if o.startswith("--") and o != "--help"}


def _meaning(action: argparse.Action) -> dict:
    return {"kind": type(action).__name__, "type": action.type, "choices": tuple(action.choices or ()) or None,
            "default": action.default, "nargs": action.nargs, "const": action.const, "help": action.help,
            "required": action.required}


PARSERS = _parsers()
SHARED = defaultdict(dict)
for _cmd, _p in PARSERS.items():
    for _flag, _action in _documented(_p).items():
        SHARED[_flag][_cmd] = _action
SHARED = {flag: by_cmd for flag, by_cmd in SHARED.items() if len(by_cmd) > 1}


def test_there_are_shared_flags_to_check():
    assert {"--threads", "--timeout", "--size", "--tolerance", "--view", "--c", "--camera", "--no-labels",
            "--workers", "--quiet", "--overwrite"} <= set(SHARED), sorted(SHARED)


@pytest.mark.parametrize("flag", sorted(SHARED))
def test_a_shared_flag_means_the_same_in_every_command(flag):
    by_cmd = SHARED[flag]
    skip = OWN_OUTPUT.get(flag, set()) | ({"required"} if flag in OWN_OUTPUT else set())
    first_cmd, first = next(iter(by_cmd.items()))
    want = {k: v for k, v in _meaning(first).items() if k not in skip}
    for cmd, action in by_cmd.items():
        got = {k: v for k, v in _meaning(action).items() if k not in skip}
        diff = {k: (want[k], got[k]) for k in want if want[k] != got[k]}
        assert not diff, f"{flag}: {first_cmd} and {cmd} differ in {diff}"


def _help_of(flag: str) -> dict[str, str]:
    return {cmd: _documented(p)[flag].help.lower() for cmd, p in PARSERS.items() if flag in _documented(p)}


def test_threads_are_threads_and_workers_are_processes():
    threads, workers = _help_of("--threads"), _help_of("--workers")
    assert {"brick", "summarize", "render", "view"} <= set(threads), sorted(threads)
    assert threads and all("thread" in h and "process" not in h for h in threads.values()), threads
    assert workers and all("process" in h and "thread" not in h for h in workers.values()), workers
    assert {"summarize", "brick-points"}.isdisjoint(workers), sorted(workers)


def test_brick_workers_without_processes_are_threads_as_before(tmp_path, capsys):
    """``brick --workers N`` asked for threads before ``--threads``; it still builds (with N threads),
    says so, and the store is the one ``--threads N`` builds (the same bytes of level 0)."""
    import numpy as np
    import zarr

    from clipvol.tools.cli import main

    vol = np.arange(24 * 20 * 16, dtype=np.uint16).reshape(24, 20, 16)
    np.save(tmp_path / "v.npy", vol)
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "a.zarr"), "--brick", "8", "--workers", "2",
                 "--quiet", "--no-summary"]) == 0
    assert "--workers 2 is worker processes with --scheduler processes" in capsys.readouterr().err
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "b.zarr"), "--brick", "8", "--threads", "2",
                 "--quiet", "--no-summary"]) == 0
    a, b = (zarr.open_group(str(tmp_path / n), mode="r")["0"][...] for n in ("a.zarr", "b.zarr"))
    assert np.array_equal(np.asarray(a)[:24, :20, :16], vol) and np.array_equal(np.asarray(a), np.asarray(b))
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "c.zarr"), "--threads", "2", "--workers", "2"]) == 2
    assert "--workers: expected --threads alone" in capsys.readouterr().err


@pytest.mark.parametrize("argv, dest, want", [
    (["summarize", "s.zarr", "--workers", "2"], "threads", 2),
    (["slice", "s.zarr", "--origin", "1,2,3"], "through", (1.0, 2.0, 3.0)),
    (["serve", "s.zarr", "--rate", "30"], "message_rate", 30.0),
    (["report", "s.zarr", "--out", "r", "--max-error", "5%"], "max_errors", "5%"),
    (["demo", "--size", "48"], "edge", 48),
])
def test_an_old_spelling_does_what_it_did_with_a_note(argv, dest, want, capsys):
    args = build_parser().parse_args(argv)
    assert getattr(args, dest) == want
    old = argv[-2]
    err = capsys.readouterr().err
    assert f"note: {old} is an old spelling of --" in err, err


def test_brick_points_accepts_workers_and_says_it_is_ignored(capsys):
    args = build_parser().parse_args(["brick-points", "p.npy", "p.zarr", "--workers", "4"])
    assert not hasattr(args, "workers") and not hasattr(args, "threads")
    assert "--workers is ignored" in capsys.readouterr().err


def _parsed(argv):
    return build_parser().parse_args(argv)


@pytest.mark.parametrize("argv, dest, want", [
    (["render", "s", "-o", "a.png"], "tolerance", "0.01"),
    (["view", "s"], "tolerance", "0.05"),
    (["render", "s", "-o", "a.png"], "timeout", 300.0),
    (["view", "s"], "timeout", 60.0),
    (["report", "s", "--out", "r"], "timeout", 120.0),
    (["render", "s", "-o", "a.png"], "view", "iso"),
    (["view", "s"], "view", None),
    (["view", "s"], "frames", 36),
    (["demo"], "frames", None),
    (["brick", "a.npy", "b.zarr"], "brick", 64),
    (["render", "s", "-o", "a.png"], "brick", None),
    (["brick-points", "p.npy", "p.zarr"], "unit", ""),
    (["brick", "a.npy", "b.zarr"], "unit", None),
])
def test_a_command_left_to_its_own_value_gets_what_the_help_says(argv, dest, want):
    """The one default (None) of a flag whose commands differ without it becomes each command's
    value as it always was, and the flag's help (the same in every command) names that value."""
    args = _parsed(argv)
    assert getattr(args, dest) == want, (argv, dest)
    flag = "--" + dest.replace("_", "-")
    text = _help_of(flag)[argv[0]]
    if want not in (None, ""):
        shown = "x".join(map(str, want)) if isinstance(want, tuple) else f"{want:g}" if isinstance(want, float) else str(want)
        assert shown in text, (flag, shown, text)
