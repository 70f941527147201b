"""The import rule of docs/architecture.md, checked: stages import only stages below them, and the
core never imports a GL or window toolkit.

Imports are read from the source with :mod:`ast` (module level and inside functions alike, since a
function-local import is still a dependency), so the rule holds for every code path, not only the
ones a test happens to run.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: folder (relative to the repository) -> (module prefix, stage rank)
PACKAGES = {"clipvol": "clipvol", "loaders": "clipvol.loaders", "tools": "clipvol.tools"}

#: stage of each module prefix; a module may import its own stage and lower ranks only
STAGES = [
    ("clipvol.errors", 0), ("clipvol.units", 0), ("clipvol.rows", 0),
    ("clipvol.bricking", 1),
    ("clipvol.paging", 2), ("clipvol.loaders", 2), ("clipvol.testing", 2),
    ("clipvol.scene", 3),
    ("clipvol.render", 4),
    ("clipvol.app", 5),
    ("clipvol.viewer", 6),
    ("clipvol.tools", 7), ("clipvol", 7),  # the package root re-exports lazily, the CLI uses everything
]
#: toolkits the core (ranks below render) must not import
GL = {"moderngl", "glfw", "OpenGL"}


def stage_of(module: str) -> int:
    for prefix, rank in STAGES:
        if module == prefix or module.startswith(prefix + "."):
            return rank
    raise AssertionError(f"module {module} belongs to no stage in tests/test_architecture.py")


#: folders in the repository that the package does not install: the benchmarks, run as scripts
NOT_INSTALLED = ("tools/bench",)


def _installed(path: Path) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return not any(rel == d or rel.startswith(d + "/") for d in NOT_INSTALLED)


def modules():
    for folder, prefix in PACKAGES.items():
        for path in sorted(p for p in (ROOT / folder).rglob("*.py") if _installed(p)):
            parts = list(path.relative_to(ROOT / folder).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            if is_pkg:
                parts = parts[:-1]
            yield path, ".".join([prefix] + parts), is_pkg


def imports(path: Path, module: str, is_pkg: bool):
    """``(line, imported module)`` of every import statement, relative ones resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module.split(".") if is_pkg else module.split(".")[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
                if node.module is None:  # from . import x: each name may be a module
                    for a in node.names:
                        yield node.lineno, f"{target}.{a.name}"
                    continue
            else:
                target = node.module or ""
            yield node.lineno, target


ALL = list(modules())


def test_every_module_is_in_a_stage():
    assert len(ALL) > 40
    for _, module, _ in ALL:
        stage_of(module)


@pytest.mark.parametrize("path,module,is_pkg", ALL, ids=[m for _, m, _ in ALL])
def test_imports_point_down(path, module, is_pkg):
    rank = stage_of(module)
    bad = []
    for line, target in imports(path, module, is_pkg):
        top = target.split(".")[0]
        if top in GL and rank < stage_of("clipvol.render"):
            bad.append(f"{path.relative_to(ROOT)}:{line} imports {target} (a GL/window toolkit) in a core stage")
        if top != "clipvol" or module.startswith("clipvol.tools") or module == "clipvol":
            continue
        if stage_of(target) > rank:
            bad.append(f"{path.relative_to(ROOT)}:{line} ({module}, stage {rank}) imports {target} "
                       f"(stage {stage_of(target)})")
    assert not bad, "imports against the stage rule of docs/architecture.md:\n" + "\n".join(bad)


def test_the_rule_would_catch_a_violation(tmp_path):
    """The checker itself: an upward and a GL import in a core module are both reported."""
    f = tmp_path / "bad.py"
    f.write_text("import moderngl\nfrom ..render.action import ClipRenderAction\n")
    found = list(imports(f, "clipvol.scene.bad", False))
    assert (1, "moderngl") in found and (2, "clipvol.render.action") in found
    assert stage_of("clipvol.render.action") > stage_of("clipvol.scene.bad")


#: packages only the tests install (the `dev` extra): the product may not import them
TEST_ONLY = {"scipy", "pytest", "hypothesis", "moto", "boto3"}


def test_product_code_needs_no_test_only_package():
    """`pip install -e .` must be enough for everything but the benchmarks: the CPU visibility pass
    once reached for scipy, and `clipvol demo` failed on a fresh machine."""
    bad = []
    for path, module, is_pkg in ALL:
        if module == "clipvol.testing":
            continue  # the loader conformance suite is for pytest (benchmarks are not in ALL: not installed)
        for line, target in imports(path, module, is_pkg):
            if target.split(".")[0] in TEST_ONLY:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    assert not bad, "product code importing a test-only package:\n" + "\n".join(bad)


def test_the_benchmarks_stay_out_of_the_package():
    """The benchmarks are scripts in ``tools/bench/`` (run from the repository, results beside them):
    pyproject installs no package there, the folder is no package, none is left in the CLI's
    folder, and no installed module imports one (``clipvol demo`` and the CLI run without them)."""
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert not [p for p in cfg["packages"] if "bench" in p]
    assert all("bench" not in d for d in cfg["package-dir"].values())
    bench = ROOT / "tools" / "bench"
    assert sorted(bench.glob("bench_*.py")) and not (bench / "__init__.py").exists()
    assert not sorted((ROOT / "tools").glob("bench_*.py"))
    names = {p.stem for p in bench.glob("*.py")}
    bad = [f"{path.relative_to(ROOT)}:{line} imports {target}"
           for path, module, is_pkg in ALL for line, target in imports(path, module, is_pkg)
           if target.split(".")[0] in names or target.startswith("clipvol.tools.bench")]
    assert not bad, "installed code importing a benchmark:\n" + "\n".join(bad)


def test_every_package_of_the_library_is_installed():
    """pyproject lists its packages by name: a package folder missing from the list installs
    from a checkout (``pip install -e``) but not from a wheel, where importing it fails."""
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    found = {module for _, module, is_pkg in ALL if is_pkg}
    assert found - listed == set(), f"package folders pyproject does not install: {sorted(found - listed)}"
