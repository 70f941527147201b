"""The front door is light: ``clipvol --help`` and ``clipvol CMD --help`` for every command import
neither numpy nor zarr (the parsers read their choices and shown defaults from
:mod:`clipvol.choices`), and import no command module but the one named.

Reference: ``sys.modules`` of a fresh interpreter (a subprocess) that ran ``clipvol``'s ``main``
with ``--help``, not a timing (``docs/benchmarks.md`` has the wall times).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from clipvol.tools import cli

PROBE = """
import contextlib, io, json, sys
from clipvol.tools import cli
with contextlib.redirect_stdout(io.StringIO()):
    try:
        cli.main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps(sorted(m for m in sys.modules if m in ("numpy", "zarr") or m.startswith("clipvol.tools.cmd_"))))
"""

#: every command line whose help is asked for: the listing, each command, ``tf``'s actions
HELPS = [("--help",), *((name, "--help") for name in cli.COMMANDS), ("tf", "save", "--help"), ("tf", "load", "--help")]


def _modules(*argv: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", HELPS, ids=lambda a: " ".join(a))
def test_help_imports_no_numpy_or_zarr_and_only_the_named_command(argv):
    mods = _modules(*argv)
    assert "numpy" not in mods and "zarr" not in mods, mods
    named = [f"clipvol.tools.cmd_{argv[0].replace('-', '_')}"] if not argv[0].startswith("-") else []
    assert mods == named, mods


def test_help_still_lists_every_command(capsys):
    from clipvol.tools import cli

    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert all(name in out for name in cli.COMMANDS)
