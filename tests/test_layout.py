"""The house's rules, checked on the source: one-way imports, effects known only to
``effects``, and no matplotlib backend chosen at import (``tests/test_control.py``
checks that importing control computes nothing)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pmabayes.effects as effects_module

PACKAGE = Path(effects_module.__file__).parent

#: each module's stage; a module may import only modules of its own stage or lower
RANK = {
    "util": 0, "parallel": 0,
    "data": 1,
    "parameters": 2, "effects": 2, "model": 2,
    "simulator": 3,
    "likelihood": 4, "trials": 4,
    "synthetic": 5,
    "posterior": 6,
    "fit": 7,
    "residuals": 8, "discrepancy": 8, "criticism": 8, "control": 8, "robustness": 8,
    "reproduction": 8,
    "batch": 8, "validation": 8,
    "plots": 9,
    "report": 10,
    "cli": 11,
}
#: ``import pmabayes`` (the top level) brings these stages
TOP_LEVEL_RANK = 3


def _stage(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def _imports(path: Path) -> list[tuple[int, str]]:
    """Every pmabayes module imported by ``path`` (at any depth), with its line."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        out += [(node.lineno, n) for n in names if n.split(".")[0] == "pmabayes"]
    return out


def _source_modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        stage = rel.parts[0]
        if stage in ("__init__", "__main__"):
            continue
        yield path, stage


def layout_violations(files) -> list[str]:
    """Imports that go up the stages, as ``file:line: stage imports stage`` lines."""
    bad = []
    for path, stage in files:
        own = RANK[stage]
        for line, module in _imports(path):
            target = _stage(module)
            rank = RANK[target] if target else TOP_LEVEL_RANK
            if rank > own:
                bad.append(f"{path.name}:{line}: {stage} imports {module}")
    return bad


def test_every_module_has_a_stage():
    assert {stage for _, stage in _source_modules()} <= set(RANK)


def test_a_lower_stage_never_imports_a_higher_one():
    assert layout_violations(_source_modules()) == []


def test_the_layout_check_can_fail(tmp_path):
    bad = tmp_path / "simulator.py"
    bad.write_text("from pmabayes.fit import fit\n")
    assert layout_violations([(bad, "simulator")]) == [
        "simulator.py:1: simulator imports pmabayes.fit"]


def _builtin_names() -> set[str]:
    names = set()
    for cls in effects_module.registered_effects().values():
        if cls.__module__ == effects_module.__name__:
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
    for path, stage in _source_modules():
        if stage == "effects":
            continue
        found += [f"{path.relative_to(PACKAGE)}:{line}: {name}"
                  for line, name in sorted(_code_names(path)) if name in builtin]
    assert found == []


def test_import_picks_no_matplotlib_backend():
    modules = ["pmabayes", "pmabayes.plots", "pmabayes.control", "pmabayes.report",
               "pmabayes.cli"]
    code = (
        f"import sys; import {', '.join(modules)}; mpl = sys.modules.get('matplotlib'); "
        "print(mpl is not None and mpl.rcParams._get_backend_or_none() is not None)"
    )  # ArviZ imports pyplot, which is harmless; calling matplotlib.use() is not
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ["False"], "importing pmabayes chose a matplotlib backend"
