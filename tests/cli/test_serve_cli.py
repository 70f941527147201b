"""``clipvol serve``'s flags: exposure refused without a token, Ctrl-C exits 130, a missing extra named."""

from __future__ import annotations

import pytest
from optional import needs

from clipvol.tools.cli import main

SOURCE = "procedural:fractal?size=32"


def test_no_token_off_loopback_is_refused(capsys):
    assert main(["serve", SOURCE, "--host", "0.0.0.0", "--no-token"]) == 2
    assert "--no-token: refused with --host 0.0.0.0" in capsys.readouterr().err
    assert main(["serve", SOURCE, "--host", "::", "--no-token"]) == 2
    assert main(["serve", SOURCE, "--token", "short"]) == 2
    assert "--token: expected at least 8 characters" in capsys.readouterr().err
    assert main(["serve", SOURCE, "--token", "has spaces in it"]) == 2
    assert main(["serve", SOURCE, "--token", "abcdefghij", "--no-token"]) == 2
    assert "either --token or --no-token" in capsys.readouterr().err
    assert main(["serve", SOURCE, "--port", "70000"]) == 2
    assert main(["serve", SOURCE, "--max-views", "0"]) == 2


def test_a_missing_aiohttp_names_the_extra(monkeypatch, capsys):
    import builtins

    real = builtins.__import__

    def no_aiohttp(name, *args, **kwargs):
        if name == "aiohttp" or name.startswith("aiohttp."):
            raise ImportError(f"No module named {name!r}")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_aiohttp)
    assert main(["serve", SOURCE]) == 2
    assert "pip install 'clipvol[serve]'" in capsys.readouterr().err


@pytest.mark.gl
@needs("aiohttp")
def test_ctrl_c_stops_it_with_130_and_the_port_is_free_again():
    import socket

    from serve_harness import ServeProcess, http_get

    s = ServeProcess([SOURCE, "--brick", "16", "--size", "32x32", "--threads", "1"])
    try:
        assert http_get(s.url)[0] == 200
    finally:
        rc = s.stop()
    assert rc == 130
    assert "clipvol serve: interrupted" in s.stderr() and "Traceback" not in s.stderr()
    port = int(s.base.rsplit(":", 1)[1])
    with socket.socket() as sock:  # nothing listens there any more
        assert sock.connect_ex(("127.0.0.1", port)) != 0
