"""The house's rules, checked on the source: imports only along the layers' graph
(type-only imports too), no circles, effects known only to
``effects``, and no matplotlib backend chosen at import (``tests/test_control.py``
checks that importing control computes nothing)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import pmabayes
import pmabayes.model.effects as effects_module
from pmabayes._layers import JOBS, LAYERS, USES, may_import

PACKAGE = Path(pmabayes.__file__).parent


def _stage(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def _imports(path: Path) -> list[tuple[int, str]]:
    """Every pmabayes module imported by ``path`` (at any depth, under ``if
    TYPE_CHECKING:`` too), with its line. A name of the top level that it imports from
    its layer when first used (``from pmabayes import fit``) is that layer's module."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module == "pmabayes" and node.level == 0:
            names = [pmabayes._LAZY.get(a.name, "pmabayes") for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        out += [(node.lineno, n) for n in names if n.split(".")[0] == "pmabayes"]
    return sorted(out)


def _source_modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        stage = rel.parts[0]
        if stage in ("__init__", "__main__", "_layers"):
            continue
        yield path, stage


def layout_violations(files) -> list[str]:
    """Imports of a layer the importer does not build on (a higher one, or a sibling), as
    ``file:line: stage imports module`` lines. The top level (``from pmabayes import
    __version__``) imports nothing when imported, so any layer may import it."""
    bad = []
    for path, stage in files:
        allowed = may_import(stage)
        for line, module in _imports(path):
            target = _stage(module)
            if target and target not in allowed:
                bad.append(f"{path.name}:{line}: {stage} imports {module}")
    return bad


def test_every_module_has_a_stage():
    assert {stage for _, stage in _source_modules()} <= set(USES)


def test_the_layers_are_a_graph_without_circles():
    assert set(USES) == set(JOBS) == set(LAYERS)
    assert all(set(below) <= set(USES) for below in USES.values())
    for name in USES:  # a layer built on one that may import it back would be a circle
        assert all(name not in may_import(below) for below in USES[name]), name
    siblings = ("synthetic", "criticism", "control", "design")
    assert all(a == b or b not in may_import(a) for a in siblings for b in siblings)


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(("pmabayes", *(rel[:-1] if rel[-1] == "__init__" else rel)))


#: Type-only imports that still close a circle, each to be broken and then taken out:
#: the noise models annotate the likelihood they serve, which holds them (a protocol of
#: what they read of it, in ``noise/base.py``, would break these).
TYPE_ONLY_LEFT = frozenset(
    (f"pmabayes.inference.noise.{m}", "pmabayes.inference.likelihood")
    for m in ("ar1", "ar_repeats", "base"))


def import_cycles(paths, ignore=frozenset()) -> list[list[str]]:
    """Circles of imports among pmabayes' modules, at any depth (an import inside a
    function closes a circle as surely, only later) and type-only ones too (under ``if
    TYPE_CHECKING:``: they never run, but two modules that need each other's types are
    one module's job split in two, and a type checker or the docs walk the circle)."""
    graph = {}
    for path in paths:
        tree = ast.parse(path.read_text())
        deps = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                deps.add(node.module)
                deps.update(f"{node.module}.{a.name}" for a in node.names)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
        graph[_module_name(path)] = deps
    known = set(graph)
    graph = {m: {d for d in deps if d in known and d != m and (m, d) not in ignore}
             for m, deps in graph.items()}
    # a package's __init__ runs before its modules: an import of the package from one
    # of its own modules is not a circle the interpreter walks
    graph = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in graph.items()}
    cycles, state = [], {}

    def visit(m, stack):
        state[m] = 1
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return cycles


def test_no_module_imports_itself_round_a_circle():
    assert import_cycles(sorted(PACKAGE.rglob("*.py")), ignore=TYPE_ONLY_LEFT) == []
    # each circle left is still there (so that one broken is taken out of the list)
    for edge in TYPE_ONLY_LEFT:
        assert import_cycles(sorted(PACKAGE.rglob("*.py")), ignore=TYPE_ONLY_LEFT - {edge}), \
            f"{edge} closes no circle any more: take it out of TYPE_ONLY_LEFT"


def test_the_circle_check_can_fail(tmp_path, monkeypatch):
    pkg = tmp_path / "pmabayes"
    (pkg / "data").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "a.py").write_text("from pmabayes.data.b import x\n")
    (pkg / "data" / "b.py").write_text("from pmabayes.data.a import y\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", pkg)
    assert import_cycles(sorted(pkg.rglob("*.py"))) == [
        ["pmabayes.data.a", "pmabayes.data.b", "pmabayes.data.a"]]


def test_a_lower_stage_never_imports_a_higher_one():
    assert layout_violations(_source_modules()) == []


def test_the_layout_check_can_fail(tmp_path):
    bad = tmp_path / "simulator.py"
    bad.write_text("from pmabayes.inference.sampler import fit\n")
    assert layout_violations([(bad, "model")]) == [
        "simulator.py:1: model imports pmabayes.inference.sampler"]
    # a sibling, for annotations only, and a verb of the top level are seen too
    sibling = tmp_path / "results.py"
    sibling.write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n"
                       "    from pmabayes.control.tracking import Tracking\n"
                       "from pmabayes import validate, __version__\n")
    assert layout_violations([(sibling, "criticism")]) == [
        "results.py:4: criticism imports pmabayes.control.tracking"]
    assert layout_violations([(sibling, "model")]) == [
        "results.py:4: model imports pmabayes.control.tracking",
        "results.py:5: model imports pmabayes.criticism.validation"]


def test_the_circle_check_sees_type_only_imports(tmp_path, monkeypatch):
    pkg = tmp_path / "pmabayes"
    (pkg / "data").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "a.py").write_text("from pmabayes.data.b import x\n")
    (pkg / "data" / "b.py").write_text("from typing import TYPE_CHECKING\n\n"
                                       "if TYPE_CHECKING:\n"
                                       "    from pmabayes.data.a import y\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", pkg)
    assert import_cycles(sorted(pkg.rglob("*.py"))) == [
        ["pmabayes.data.a", "pmabayes.data.b", "pmabayes.data.a"]]


def _builtin_names() -> set[str]:
    names = set()
    for cls in effects_module.registered_effects().values():
        if cls.__module__.startswith(effects_module.__name__ + "."):
            names.add(cls.name)
            names.update(cls.parameter_names())
    return names


def _code_names(path: Path) -> set[tuple[int, str]]:
    """Identifiers and string constants in code, docstrings left out."""
    tree = ast.parse(path.read_text())
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docstrings.add(id(first.value))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if id(node) not in docstrings:
                out.add((node.lineno, node.value))
        elif isinstance(node, ast.Name):
            out.add((node.lineno, node.id))
        elif isinstance(node, ast.Attribute):
            out.add((node.lineno, node.attr))
    return out


def test_no_module_but_effects_names_a_builtin_effect():
    builtin = _builtin_names()
    assert {"regulator_lag", "tau_reg", "position_offset", "x_offset"} <= builtin
    found = []
    for path, _ in _source_modules():
        if path.relative_to(PACKAGE).with_suffix("").parts[:2] == ("model", "effects"):
            continue
        found += [f"{path.relative_to(PACKAGE)}:{line}: {name}"
                  for line, name in sorted(_code_names(path)) if name in builtin]
    assert found == []


def test_import_picks_no_matplotlib_backend():
    modules = ["pmabayes", "pmabayes.report.figures", "pmabayes.control", "pmabayes.report",
               "pmabayes.cli"]
    code = (
        f"import sys; import {', '.join(modules)}; mpl = sys.modules.get('matplotlib'); "
        "print(mpl is not None and mpl.rcParams._get_backend_or_none() is not None)"
    )  # ArviZ imports pyplot, which is harmless; calling matplotlib.use() is not
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ["False"], "importing pmabayes chose a matplotlib backend"


def _submodules(package):
    import importlib
    import pkgutil

    for info in pkgutil.iter_modules(package.__path__):
        if info.name == "__main__":
            continue
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        yield package, info.name, module
        if info.ispkg:
            yield from _submodules(module)


@pytest.mark.filterwarnings("ignore:pmabayes.effects is the old path:FutureWarning")
def test_no_name_of_a_package_hides_one_of_its_modules():
    """``from pmabayes.criticism.whiteness import whiteness`` in a package's
    ``__init__`` would make ``pmabayes.criticism.whiteness`` the function, not the
    module (``import a.b as m`` then gives the function)."""
    hidden = [f"{pkg.__name__}.{name}" for pkg, name, module in _submodules(pmabayes)
              if getattr(pkg, name) is not module]
    assert hidden == []
