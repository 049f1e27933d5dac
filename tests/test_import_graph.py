"""The import graph of ``fgloc`` and ``factors``, read statically with :mod:`ast`, has no
cycle, and ``factors`` (the math) never imports ``fgloc`` (the system).

Every ``import`` / ``from ... import`` counts wherever it stands (module level, inside a
function, under ``if TYPE_CHECKING:``): a function-local import only hides a cycle until the
function runs, and a type-only import still says which module knows about which. Relative
imports are resolved against the importing module's package. ``from a.b import c`` is an edge
to ``a.b.c`` when that is a module of ours, else to ``a.b``. Importing ``a.b.c`` also runs
``a/__init__.py`` and ``a/b/__init__.py``; those implicit edges are left out, so a package's
``__init__`` may re-export its submodules' names as long as the submodules import each other
directly, never through their package.
"""

from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("fgloc", "factors")


def module_files(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file of ``packages`` under ``root``."""
    out = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The module named by ``from <level dots><node.module> import ...`` inside ``module``."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    base = base if is_package else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join([*base, node.module] if node.module else base)


def imports_of(module: str, path: Path, modules: set[str]) -> set[str]:
    """The modules among ``modules`` that ``module`` (source ``path``) imports anywhere."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(node, module, is_package)
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                     for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in modules:     # ``import a.b.c`` of a non-module tail
                name = name.rpartition(".")[0]
            if name:
                out.add(name)
    out.discard(module)
    return out


def import_graph(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, set[str]]:
    """Module -> the modules of ``packages`` it imports."""
    files = module_files(root, packages)
    return {m: imports_of(m, p, set(files)) for m, p in files.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None when it is acyclic (iterative DFS)."""
    state: dict[str, int] = {}                   # 1: on the DFS path, 2: done
    for root in sorted(graph):
        if state.get(root):
            continue
        path, stack = [root], [iter(sorted(graph[root]))]
        state[root] = 1
        while stack:
            nxt = next(stack[-1], None)
            if nxt is None:
                state[path.pop()] = 2
                stack.pop()
            elif state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            elif not state.get(nxt):
                state[nxt] = 1
                path.append(nxt)
                stack.append(iter(sorted(graph.get(nxt, ()))))
    return None


def test_graph_covers_the_packages():
    graph = import_graph()
    assert "fgloc.pipeline" in graph and "factors.gp" in graph
    assert "fgloc.config" in graph["fgloc.pipeline"]


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_factors_never_imports_fgloc():
    graph = import_graph()
    bad = sorted((m, d) for m, deps in graph.items() if m.startswith("factors")
                 for d in deps if d.split(".")[0] == "fgloc")
    assert not bad, f"factors imports fgloc: {bad}"


def test_no_run_imports_open3d():
    """Open3D is the benchmarks' peer, not a stage: importing it (dash, plotly, IPython with
    it) cost a run 2 s and 190 MB. Only the helper that loads it for bench/ and the tests
    (``fgloc._open3d``) may import it, anywhere in a function or not."""
    files = module_files()
    heavy = {"open3d", "fgloc._open3d"}
    bad = sorted(m for m, p in files.items()
                 if m != "fgloc._open3d" and heavy & imports_of(m, p, set(files) | heavy))
    assert not bad, f"modules importing open3d: {bad}"
    helper = imports_of("fgloc._open3d", files["fgloc._open3d"], set(files) | heavy)
    assert "open3d" in helper                    # the check sees a function-local import


def test_finds_cycles_and_resolves_relative_imports(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from .a import f\n")
    (pkg / "sub" / "a.py").write_text("def f():\n    from ..b import g\n    return g\n")
    (pkg / "b.py").write_text("from pkg.sub import a\n")
    graph = import_graph(tmp_path, ("pkg",))
    assert graph["pkg.sub"] == {"pkg.sub.a"}
    assert graph["pkg.sub.a"] == {"pkg.b"}
    assert graph["pkg.b"] == {"pkg.sub.a"}
    assert find_cycle(graph) == ["pkg.b", "pkg.sub.a", "pkg.b"]
    (pkg / "b.py").write_text("import os\n")
    assert find_cycle(import_graph(tmp_path, ("pkg",))) is None


@pytest.mark.parametrize(("old", "new", "name"), [
    ("fgloc.fine", "fgloc.registration.fine", "register_tracks"),
    ("fgloc.source", "fgloc.registration.source", "build_source_cloud"),
    ("fgloc.modes", "fgloc.registration.modes", "choose_mode"),
    ("fgloc.evaluate", "fgloc.evaluation.pose", "pose_error"),
    ("fgloc.evaluate_tracking", "fgloc.evaluation.tracking", "evaluate_tracks"),
])
def test_moved_modules_keep_a_deprecated_alias(old, new, name):
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=new.replace(".", r"\.")):
        alias = importlib.import_module(old)
    assert getattr(alias, name) is getattr(importlib.import_module(new), name)


def test_stage_packages_keep_the_old_module_paths():
    """``fgloc.map`` and ``fgloc.coarse`` became packages; the names documented under the old
    module paths still import from them, without a warning."""
    import fgloc.coarse
    import fgloc.map

    assert fgloc.map.build_target_cloud.__module__ == "fgloc.map.target_cloud"
    assert fgloc.coarse.target_and_coarse.__module__ == "fgloc.coarse.localize"
    assert fgloc.coarse.fit_vertical.__module__ == "fgloc.coarse.vertical"
