"""The custom loader in docs/loaders.md runs and passes the conformance suite, so the doc never rots."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from clipvol.paging.loader import Loader
from clipvol.testing import LoaderTests

DOC = Path(__file__).resolve().parents[2] / "docs" / "loaders.md"
MARKER = "<!-- custom-loader-example"


def doc_example() -> str:
    text = DOC.read_text(encoding="utf-8")
    after = text[text.index(MARKER):]
    m = re.search(r"```python\n(.*?)```", after, re.S)
    assert m is not None, "docs/loaders.md: no python block after the custom-loader marker"
    return m.group(1)


def run_example() -> dict:
    ns: dict = {"__name__": "docs_loaders_example"}
    exec(compile(doc_example(), str(DOC), "exec"), ns)
    return ns


def test_example_is_short_and_a_loader():
    code = doc_example()
    assert len(code.strip().splitlines()) <= 30
    ns = run_example()
    assert isinstance(ns["loader"], Loader)


class TestDocLoader(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls):
        return run_example()["loader"]

    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls, loader):
        # independent of the example's code: distances from np.indices
        n = loader.pyramid.shape[0]
        c = (n - 1) / 2
        z, y, x = np.indices((n, n, n), dtype=np.float64) - c
        return np.sqrt(z**2 + y**2 + x**2).astype(np.float32)
