"""The Examples sections of the docstrings run, and every public function or class the
user guide points to has one.

Every docstring of the package with a ``>>>`` line is executed by :mod:`doctest`, so an
example that no longer runs, or no longer prints what it shows, fails here. The
examples run in a folder of their own (the autouse fixture of ``conftest.py``) that
holds ``data/`` and ``docs/plugins/`` of the checkout, so that they read the bundled
data by the paths a user of a checkout types (``load("data/pma_chirp_lab.csv")``)
and what they write stays out of the checkout.

The objects the guide points to are those its pages name with a role
(``{func}`pmabayes.fit```, ``{class}``...) or as a dotted name in code
(```pmabayes.data.load_segments```), and the public names (``__all__``) of the
modules it links with ``{mod}``.
"""

from __future__ import annotations

import doctest
import importlib
import inspect
import pkgutil
import re
import warnings
from pathlib import Path

import pytest

import pmabayes
from pmabayes.control import GainGridWarning
from pmabayes.data import DataWarning
from pmabayes.inference.errors import ConvergenceWarning

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide"
#: ``...`` elides what varies (a path, a long message's tail); a long line may wrap
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
#: the old import path of ``pmabayes.model.effects``: its objects are the new module's
#: (their examples run there), and importing it warns
SKIPPED_MODULES = {"pmabayes.effects"}
#: an example that fits a model (a short run, or a MAP) takes seconds: marked slow
_FITS = re.compile(r"\b(fit|fit_batch|design|find_map|fit_base)\(")
#: warnings the examples show on purpose (a short fit, a unit converted, a grid's edge)
EXPECTED_WARNINGS = (ConvergenceWarning, DataWarning, GainGridWarning)

_ROLE = re.compile(r"\{(?:py:)?(func|class|meth|mod|obj|data|exc)\}`~?([\w.]+)`")
_CODE = re.compile(r"`(pmabayes(?:\.\w+)+)`")


def _resolve(name: str) -> object:
    """The object a dotted name stands for: the longest importable module, then
    attributes."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for part in parts[i:]:
            obj = getattr(obj, part)
        return obj
    raise ImportError(name)


def guide_objects() -> dict[str, object]:
    """Dotted name to each public function or class the guide's pages point to."""
    text = "\n".join(p.read_text() for p in sorted(GUIDE.glob("*.md")))
    named = {n for _, n in _ROLE.findall(text)} | set(_CODE.findall(text))
    linked = {n for role, n in _ROLE.findall(text) if role == "mod"}
    found: dict[str, object] = {}
    for name in sorted(named):
        obj = _resolve(name)
        if inspect.ismodule(obj):
            if name in linked:  # its API page is linked: its public names are shown
                for k in getattr(obj, "__all__", ()):
                    found[f"{name}.{k}"] = getattr(obj, k)
        else:
            found[name] = obj
    return {n: o for n, o in found.items()
            if (inspect.isfunction(o) or inspect.isclass(o))
            and not o.__name__.startswith("_")}


def _has_examples(obj: object) -> bool:
    return re.search(r"^Examples\n-{3,}$", inspect.getdoc(obj) or "", re.M) is not None


def test_the_guide_points_to_the_objects_a_user_calls():
    """The parser finds what the pages name (so the next test can fail)."""
    objects = guide_objects()
    for name in ("pmabayes.fit", "pmabayes.data.load", "pmabayes.data.load_segments",
                 "pmabayes.inference.trials.exclude_trials", "pmabayes.control.track"):
        assert name in objects, f"{name} is no longer found on the guide's pages"


def test_every_object_the_guide_points_to_has_examples():
    missing = sorted({f"{o.__module__}.{o.__qualname__}"
                      for o in guide_objects().values() if not _has_examples(o)})
    assert not missing, ("the user guide points to these without an Examples section; give "
                         "each a short one that runs on data/ or on tiny data it builds: "
                         + ", ".join(missing))


def _doctests() -> list[doctest.DocTest]:
    finder = doctest.DocTestFinder()
    tests: dict[str, doctest.DocTest] = {}
    names = ["pmabayes"] + [m.name for m in pkgutil.walk_packages(pmabayes.__path__,
                                                                   "pmabayes.")]
    for name in names:
        if name in SKIPPED_MODULES:
            continue
        for test in finder.find(importlib.import_module(name)):
            if test.examples:
                tests.setdefault(test.name, test)
    return sorted(tests.values(), key=lambda t: t.name)


DOCTESTS = _doctests()
PARAMS = [pytest.param(t, id=t.name, marks=[pytest.mark.slow] if any(
    _FITS.search(e.source) for e in t.examples if not e.options.get(doctest.SKIP)) else [])
    for t in DOCTESTS]


def test_the_examples_are_found():
    names = {t.name for t in DOCTESTS}
    assert {"pmabayes.data.files.load", "pmabayes.control.kernel.closed_loop"} <= names


@pytest.mark.parametrize("test", PARAMS)
def test_the_example_runs(test, tmp_path):
    (tmp_path / "data").symlink_to(ROOT / "data")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "plugins").symlink_to(ROOT / "docs" / "plugins")
    from pmabayes.model.effects import registry

    # an example may register an effect a test module also registered on import; the
    # conftest fixture restores them afterwards
    for name, effect in list(registry._REGISTRY.items()):
        if not effect.__module__.startswith("pmabayes."):
            del registry._REGISTRY[name]
    report: list[str] = []
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    with warnings.catch_warnings():
        for category in EXPECTED_WARNINGS:  # shown on purpose (the fits are short, and say so)
            warnings.simplefilter("ignore", category)
        # each run on a fresh copy of the module's globals, as doctest does
        result = runner.run(doctest.DocTest(test.examples, dict(test.globs), test.name,
                                            test.filename, test.lineno, test.docstring),
                            out=report.append)
    assert result.failed == 0, "".join(report)
