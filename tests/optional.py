"""Skip marks for tests of the optional stacks.

The README's test command installs ``.[dev]`` (lean: the runner and the independent references);
CI installs ``.[test-all]``, which adds every optional stack. A test that needs a package outside
``dev`` carries ``needs(...)`` so that the lean run skips it, naming what is missing and how to get
it, instead of failing on an import.
"""

from __future__ import annotations

import importlib.util
import shutil

import pytest


def missing(*modules: str) -> list[str]:
    """The top-level modules of ``modules`` that cannot be imported here."""
    return [m for m in modules if importlib.util.find_spec(m.split(".")[0]) is None]


def needs(*modules: str) -> pytest.MarkDecorator:
    """``skipif`` any of ``modules`` is missing, with a reason that says how to install it."""
    gone = missing(*modules)
    return pytest.mark.skipif(
        bool(gone), reason=f"needs {', '.join(gone)}: pip install -e '.[test-all]'"
    )


def needs_program(*names: str, install: str) -> pytest.MarkDecorator:
    """``skipif`` none of the executables ``names`` is on PATH, with a reason that says how to install one."""
    found = any(shutil.which(n) for n in names)
    return pytest.mark.skipif(not found, reason=f"needs {' or '.join(names)} on PATH: {install}")


REMOTE_HTTP = needs("fsspec", "aiohttp")
REMOTE_S3 = needs("fsspec", "aiohttp", "s3fs", "moto", "boto3")
POINT_READERS = needs("pandas", "pyarrow", "plyfile", "meshio")
DASK = needs("dask", "distributed")
# the notebook view's browser half, run in a headless browser (tests/browser_harness.py)
CHROMIUM = needs_program("chromium", "chromium-browser", "google-chrome", install="apt-get install chromium")
