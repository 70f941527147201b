"""The import rule of docs/architecture.md, checked: stages import only stages below them, and the
core never imports a GL or window toolkit.

Imports are read from the source with :mod:`ast` (module level and inside functions alike, since a
function-local import is still a dependency), so the rule holds for every code path, not only the
ones a test happens to run.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: folder (relative to the repository) -> module prefix
PACKAGES = {"clipvol": "clipvol", "loaders": "clipvol.loaders", "tools": "clipvol.tools"}

#: stage of every package: each module inside it (at any depth) has this stage. A module may import
#: its own stage and lower ranks only.
PACKAGE_STAGES = {
    "clipvol.bricking": 1,
    "clipvol.paging": 2, "clipvol.loaders": 2,
    "clipvol.scene": 3,
    "clipvol.render": 4,
    "clipvol.app": 5,
    "clipvol.viewer": 6,
    "clipvol.tools": 7,  # the CLI uses everything
}
#: stage of every module outside those packages, named one by one: a new top-level module (or a
#: new package) belongs to no stage until it is added here, and test_every_module_is_in_a_stage fails
MODULE_STAGES = {
    "clipvol.errors": 0, "clipvol.units": 0, "clipvol.rows": 0, "clipvol.choices": 0, "clipvol.interrupts": 0,
    "clipvol.testing": 2,  # the loader conformance suite: loaders and the pyramid
    "clipvol.napari_plugin": 5,  # a front end (napari reader) over bricking, like app/notebook.py
    "clipvol": 7,  # the package root re-exports every stage lazily
}
#: toolkits the core (ranks below render) must not import
GL = {"moderngl", "glfw", "OpenGL"}


def stage_of(module: str) -> int:
    if module in MODULE_STAGES:
        return MODULE_STAGES[module]
    for prefix, rank in PACKAGE_STAGES.items():
        if module == prefix or module.startswith(prefix + "."):
            return rank
    raise AssertionError(f"module {module} belongs to no stage: name it in PACKAGE_STAGES or MODULE_STAGES of "
                         f"tests/test_architecture.py and in docs/architecture.md")


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
    for line, target, _ in located_imports(path, module, is_pkg):
        yield line, target


def _function_nodes(tree) -> set[int]:
    """ids of the import nodes inside a function body (at any depth)."""
    inside = set()
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            inside.update(id(n) for n in ast.walk(fn) if isinstance(n, (ast.Import, ast.ImportFrom)))
    return inside


def located_imports(path: Path, module: str, is_pkg: bool) -> tuple:
    """``(line, imported module, in a function)`` of every import statement, relative ones resolved;
    each file parsed once per test session (a dozen tests read every module's imports), and again
    when it changes on disk (the tests that write a module of their own)."""
    st = path.stat()
    return _located_imports(path, module, is_pkg, st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=None)
def _located_imports(path: Path, module: str, is_pkg: bool, mtime_ns: int, size: int) -> tuple:
    return tuple(_parse_imports(path, module, is_pkg))


def _parse_imports(path: Path, module: str, is_pkg: bool):
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    in_function = _function_nodes(tree)
    package = module.split(".") if is_pkg else module.split(".")[:-1]
    for node in ast.walk(tree):
        local = id(node) in in_function
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name, local
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
                if node.module is None:  # from . import x: each name may be a module
                    for a in node.names:
                        yield node.lineno, f"{target}.{a.name}", local
                    continue
            else:
                target = node.module or ""
            yield node.lineno, target, local


ALL = list(modules())


def test_every_module_is_in_a_stage():
    assert len(ALL) > 40
    for _, module, _ in ALL:
        stage_of(module)


def test_a_module_without_a_stage_is_refused():
    """A new top-level module or package is in no stage until it says so (no catch-all)."""
    for module in ("clipvol.meshes", "clipvol.meshes.reader", "clipvol.new_module", "clipvol.loaders_extra"):
        with pytest.raises(AssertionError, match="belongs to no stage"):
            stage_of(module)
    assert stage_of("clipvol") == 7 and stage_of("clipvol.scene.selection.policies.distance") == 3


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


#: the paging modules the scene may use: pure-numpy brick geometry (cells of a brick, the bricks a
#: slab covers, the region handed to the clip-texture), importing nothing of paging that reads
PAGING_GEOMETRY = {"clipvol.paging.cells", "clipvol.paging.slab", "clipvol.paging.region"}


def test_scene_reads_no_bricks():
    """The scene stage decides on the pyramid alone (it defines the residency contract it needs):
    of paging and the loaders it imports only the pure geometry of ``PAGING_GEOMETRY``, and those
    import nothing of paging but each other (no loader, no clip-texture, no threads)."""
    bad = [f"{path.relative_to(ROOT)}:{line} imports {target}"
           for path, module, is_pkg in ALL if stage_package(module) == "clipvol.scene"
           for line, target in imports(path, module, is_pkg)
           if stage_package(target) in ("clipvol.paging", "clipvol.loaders") and target not in PAGING_GEOMETRY]
    assert not bad, "scene importing paging:\n" + "\n".join(bad)
    leaky = [f"{path.relative_to(ROOT)}:{line} imports {target}"
             for path, module, is_pkg in ALL if module in PAGING_GEOMETRY
             for line, target in imports(path, module, is_pkg)
             if target.startswith("clipvol.") and stage_package(target) in ("clipvol.paging", "clipvol.loaders")
             and target not in PAGING_GEOMETRY | {"clipvol.paging"}]
    assert not leaky, "paging geometry importing more of paging:\n" + "\n".join(leaky)


def test_the_rule_would_catch_a_violation(tmp_path):
    """The checker itself: an upward and a GL import in a core module are both reported."""
    f = tmp_path / "bad.py"
    f.write_text("import moderngl\nfrom ..render.action import ClipRenderAction\n")
    found = list(imports(f, "clipvol.scene.bad", False))
    assert (1, "moderngl") in found and (2, "clipvol.render.action") in found
    assert stage_of("clipvol.render.action") > stage_of("clipvol.scene.bad")


MODULES = {module: is_pkg for _, module, is_pkg in ALL}


def module_of(target: str) -> str | None:
    """The module (or package ``__init__``) an imported name lives in; None outside clipvol."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def _ancestors(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def import_graph(entries):
    """``{module: {imported module: [(path, line, target, in a function), ...]}}`` over ``entries``
    (``(path, module, is_pkg)``). Importing ``a.b.c`` also runs the ``__init__`` of ``a`` and
    ``a.b``, so those are edges too - except the importer's own packages: they are already running
    when it runs, and a module reading a name of its own package (``from . import require``) is
    part of that package, not a dependency of it."""
    graph: dict[str, dict[str, list]] = {}
    for path, module, is_pkg in entries:
        own = set(_ancestors(module)) | {module}
        for line, target, local in located_imports(path, module, is_pkg):
            dst = module_of(target)
            if dst is None or dst in own:
                continue
            for node in [a for a in _ancestors(dst) if a in MODULES and a not in own] + [dst]:
                if node != module:
                    graph.setdefault(module, {}).setdefault(node, []).append((path, line, target, local))
    return graph


def stage_package(module: str) -> str:
    """The stage package a module belongs to (``clipvol.paging``, ``clipvol.loaders``), or the
    module itself for a top-level module (``clipvol.errors``)."""
    for prefix in PACKAGE_STAGES:
        if module == prefix or module.startswith(prefix + "."):
            return prefix
    return module


def package_graph(graph):
    """The module graph collapsed onto stage packages (edges inside one package dropped)."""
    out: dict[str, dict[str, list]] = {}
    for src, targets in graph.items():
        for dst, where in targets.items():
            p, q = stage_package(src), stage_package(dst)
            if p != q and src != "clipvol":  # the root re-exports lazily: no package depends on it
                out.setdefault(p, {}).setdefault(q, []).extend(where)
    return out


def path_between(graph, start: str, goal: str) -> list[str] | None:
    """A path of nodes from ``start`` to ``goal`` in ``graph`` (breadth first), or None."""
    prev, todo = {start: None}, [start]
    while todo:
        node = todo.pop(0)
        if node == goal:
            path = [node]
            while prev[path[-1]] is not None:
                path.append(prev[path[-1]])
            return path[::-1]
        for nxt in graph.get(node, {}):
            if nxt not in prev:
                prev[nxt] = node
                todo.append(nxt)
    return None


def function_import_cycles(graph, allowed=()) -> list[str]:
    """Function-level imports whose target leads back (directly or through others) to the
    importer: a cycle that a deferred import only hides. ``allowed``: ``(a, b)`` node pairs exempt."""
    bad = []
    for src, targets in graph.items():
        for dst, where in targets.items():
            if (src, dst) in allowed:
                continue
            for path, line, target, local in where:
                if not local:
                    continue
                back = path_between(graph, dst, src)
                if back is not None:
                    bad.append(f"{Path(path).name}:{line} imports {target} inside a function: cycle "
                               + " -> ".join([src] + back))
                    break
    return bad


#: package cycles that are the design, each with its reason (none may be added without one)
ALLOWED_PACKAGE_CYCLES = {
    ("clipvol.paging", "clipvol.loaders"): "clipvol.paging.open.open_store is the factory of the bundled loaders "
    "(imported on use, so that zarr is imported only for a zarr store) while each loader implements the "
    "clipvol.paging.loader contract; a plug-in loader comes through the clipvol.loaders entry point instead",
}


#: module cycles that are the design, each with its reason
ALLOWED_MODULE_CYCLES = {
    ("clipvol.tools.cmd_info", "clipvol.tools.remote_info"): "one command, `clipvol info`: cmd_info hands a URL to "
    "remote_info, which prints the same trust and statistics lines as cmd_info does for a local store",
}
ALLOWED_MODULE_CYCLES.update({(b, a): why for (a, b), why in list(ALLOWED_MODULE_CYCLES.items())})


def test_no_cycle_hidden_in_a_function():
    """No function-level import closes a cycle of modules (the import Python defers would fail or
    see a half-built module if it ran at load time) or of stage packages."""
    graph = import_graph(ALL)
    bad = function_import_cycles(graph, allowed=set(ALLOWED_MODULE_CYCLES))
    bad += function_import_cycles(package_graph(graph), allowed=set(ALLOWED_PACKAGE_CYCLES))
    assert not bad, "function-level imports that close an import cycle:\n" + "\n".join(bad)


def test_the_cycle_check_would_catch_one(tmp_path):
    """The checker itself: params importing the policies inside a function while the traversal (in
    the policies' parent package, whose ``__init__`` runs first) imports params is reported; the
    policies importing a leaf registry that params imports is no cycle."""
    scene = tmp_path / "scene"
    (scene / "selection" / "policies").mkdir(parents=True)
    files = {"__init__.py": "", "registry.py": "",
             "params.py": "def f():\n    from .selection.policies import POLICIES\n",
             "selection/__init__.py": "from .traversal import select\n",
             "selection/traversal.py": "from ..params import RenderParams\n",
             "selection/policies/__init__.py": "from ...registry import POLICIES\n"}
    entries = []
    for rel, text in files.items():
        (scene / rel).write_text(text)
        parts = ["clipvol", "scene"] + rel[:-3].split("/")
        is_pkg = parts[-1] == "__init__"
        entries.append((scene / rel, ".".join(parts[:-1] if is_pkg else parts), is_pkg))
    saved = dict(MODULES)
    MODULES.clear()
    MODULES.update({m: p for _, m, p in entries})
    try:
        bad = function_import_cycles(import_graph(entries))
        assert len(bad) == 1 and bad[0].startswith("params.py:2")
        assert "clipvol.scene.params -> clipvol.scene.selection -> clipvol.scene.selection.traversal -> " \
               "clipvol.scene.params" in bad[0]
        (scene / "params.py").write_text("def f():\n    from .registry import POLICIES\n")
        assert function_import_cycles(import_graph(entries)) == []
    finally:
        MODULES.clear()
        MODULES.update(saved)


def test_the_package_cycle_check_would_catch_one():
    """Two stage packages importing each other, one of them inside a function, are reported."""
    g = {"clipvol.paging.open": {"clipvol.loaders.zarr_store": [("open.py", 3, "clipvol.loaders.zarr_store", True)]},
         "clipvol.loaders.zarr_store": {"clipvol.paging.loader": [("zarr_store.py", 1, "clipvol.paging.loader", False)]}}
    assert function_import_cycles(g) == []  # no module cycle
    bad = function_import_cycles(package_graph(g))
    assert bad == ["open.py:3 imports clipvol.loaders.zarr_store inside a function: cycle "
                   "clipvol.paging -> clipvol.loaders -> clipvol.paging"]
    assert function_import_cycles(package_graph(g), allowed=set(ALLOWED_PACKAGE_CYCLES)) == []


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
