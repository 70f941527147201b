"""Ctrl-C always ends the CLI with exit 130, even when a C extension re-raises it as another error."""

from __future__ import annotations

import pytest

from clipvol.tools import cli


def _main_with(monkeypatch, run):
    parser = cli.build_parser()
    real_parse = parser.parse_args

    def parse(argv=None):
        args = real_parse(["info", "procedural:fractal?size=16"])
        args._run = run
        return args

    monkeypatch.setattr(parser, "parse_args", parse)
    monkeypatch.setattr(cli, "build_parser", lambda only=None: parser)
    return cli.main([])


def test_interrupt_wrapped_by_an_extension_exits_130(monkeypatch, capsys):
    def run(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise TypeError("an extension's error while the interrupt was pending")

    assert _main_with(monkeypatch, run) == 130
    assert "interrupted" in capsys.readouterr().err


def test_other_errors_still_raise(monkeypatch):
    def run(args):
        raise TypeError("a real bug")

    with pytest.raises(TypeError, match="a real bug"):
        _main_with(monkeypatch, run)


def test_interrupt_swallowed_on_its_way_still_exits_130(monkeypatch, capsys):
    """A real SIGINT that code under the command catches and drops (as some C code does) must not
    end the command with 0: the work it stopped did not finish."""
    import os
    import signal

    def run(args):
        try:
            os.kill(os.getpid(), signal.SIGINT)  # the CLI's handler raises KeyboardInterrupt here
            signal.pthread_sigmask(signal.SIG_BLOCK, [])  # a call for the handler to run in
        except KeyboardInterrupt:
            pass  # swallowed
        return 0

    assert _main_with(monkeypatch, run) == 130
    assert "interrupted" in capsys.readouterr().err


def test_a_command_without_interrupt_keeps_its_status(monkeypatch):
    assert _main_with(monkeypatch, lambda args: 3) == 3
