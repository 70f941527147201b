"""Every sub-command listed in ``tools/cli.py`` is built: its module exists with ``add_arguments``
and ``run``, and the parser offers it (a missing module is an import error, not a silent gap).

Reference: the module files on disk and ``COMMANDS`` itself.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import clipvol.tools.cli as cli

TOOLS = Path(cli.__file__).resolve().parent


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_listed_command_has_its_module(name):
    path = TOOLS / f"cmd_{name.replace('-', '_')}.py"
    assert path.is_file(), path
    text = path.read_text(encoding="utf-8")
    assert "\ndef add_arguments(" in text and "\ndef run(" in text


def test_the_parser_offers_every_listed_command():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    assert sorted(sub.choices) == sorted(cli.COMMANDS)


def test_a_listed_command_without_a_module_fails_loudly(monkeypatch):
    monkeypatch.setitem(cli.COMMANDS, "nowhere", "a command nobody wrote")
    with pytest.raises(ModuleNotFoundError, match="cmd_nowhere"):
        cli.build_parser()
