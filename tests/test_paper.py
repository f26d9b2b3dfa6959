"""The paper's inputs: ``analyses/run_all.py --quick`` makes every file that
``paper/main.tex`` includes, and defines every generated macro it uses.

The PDF is not built (no TeX is needed): the checks are on the LaTeX source and the
generated files. Runs the quick analyses once (a few minutes) into a temporary
output root.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAIN_TEX = ROOT / "paper" / "main.tex"

_INCLUDE = re.compile(r"\\(includegraphics|input)\s*(?:\[[^\]]*\])?\s*\{([^}]*)\}")
_MACRO_USE = re.compile(r"\\(pb[A-Za-z]+)")
_MACRO_DEF = re.compile(r"\\newcommand\s*\{\\(pb[A-Za-z]+)\}")
_ENV = re.compile(r"\\(begin|end)\{([^}]*)\}")


def _strip_comments(tex: str) -> str:
    return re.sub(r"(?<!\\)%.*", "", tex)


def included_files(tex: str) -> list[str]:
    """Paths given to ``\\includegraphics`` and ``\\input``, comments ignored."""
    return [m.group(2).strip() for m in _INCLUDE.finditer(_strip_comments(tex))]


def used_macros(tex: str) -> set[str]:
    """Generated macros (``\\pb...``) used in the source."""
    return {m for m in _MACRO_USE.findall(_strip_comments(tex))}


def defined_macros(files: list[Path]) -> dict[str, list[Path]]:
    """Generated macros defined in ``files``, with where each is defined."""
    out: dict[str, list[Path]] = {}
    for f in files:
        for name in _MACRO_DEF.findall(_strip_comments(f.read_text())):
            out.setdefault(name, []).append(f)
    return out


def unbalanced(tex: str) -> list[str]:
    """Environments that are not closed in order (empty when balanced)."""
    stack, problems = [], []
    for kind, name in _ENV.findall(_strip_comments(tex)):
        if kind == "begin":
            stack.append(name)
        elif not stack or stack.pop() != name:
            problems.append(name)
    return problems + stack


def brace_problems(tex: str) -> list[str]:
    """Unbalanced braces or an odd number of ``$`` (empty when fine)."""
    text = _strip_comments(tex).replace("\\{", "").replace("\\}", "").replace("\\$", "")
    depth, problems = 0, []
    for ch in text:
        depth += (ch == "{") - (ch == "}")
        if depth < 0:
            problems.append("a } closes nothing")
            depth = 0
    if depth:
        problems.append(f"{depth} unclosed {{")
    if text.count("$") % 2:
        problems.append("odd number of $")
    return problems


def missing_inputs(tex: str, out_root: Path) -> list[str]:
    """Included paths with no file under ``out_root``."""
    return [p for p in included_files(tex) if not (out_root / p).is_file()]


# --- the checks themselves can fail --------------------------------------------------

def test_the_checks_catch_missing_files_and_macros(tmp_path):
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"png")
    (tmp_path / "numbers.tex").write_text("\\newcommand{\\pbKnown}{1}\n")
    tex = ("\\input{numbers.tex}\n\\includegraphics[width=1cm]{figures/a.png}\n"
           "\\includegraphics{figures/b.png} % \\input{commented.tex}\n"
           "\\pbKnown \\pbUnknown\n\\begin{table}\\begin{tabular}\\end{table}\n")
    assert missing_inputs(tex, tmp_path) == ["figures/b.png"]
    assert used_macros(tex) - set(defined_macros([tmp_path / "numbers.tex"])) == {"pbUnknown"}
    assert unbalanced(tex) != []
    assert brace_problems("{a}$x$") == []
    assert brace_problems("{a") and brace_problems("a}") and brace_problems("$x")
    assert unbalanced("\\begin{a}\\begin{b}\\end{b}\\end{a}") == []


# --- the quick run ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def quick_root(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_quick")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    proc = subprocess.run(
        [sys.executable, str(ROOT / "analyses" / "run_all.py"), "--quick", "--out-root",
         str(out)], capture_output=True, text=True, env=env, cwd=ROOT, timeout=1200)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    assert "total" in proc.stdout  # the timing table is printed
    return out


def test_every_included_file_exists_after_the_quick_run(quick_root):
    tex = MAIN_TEX.read_text()
    files = included_files(tex)
    assert any(f.startswith("figures/") for f in files)
    assert any(f.startswith("tables/") for f in files)
    assert missing_inputs(tex, quick_root) == []
    for f in files:
        assert (quick_root / f).stat().st_size > 0, f


def test_every_generated_macro_is_defined_once(quick_root):
    tex = MAIN_TEX.read_text()
    numbers = sorted((quick_root / "tables").glob("numbers_*.tex"))
    assert numbers
    # main.tex inputs every numbers file the analyses write
    inputs = set(included_files(tex))
    assert {f"tables/{p.name}" for p in numbers} <= inputs
    defined = defined_macros(numbers)
    assert not {k: v for k, v in defined.items() if len(v) > 1}
    assert used_macros(tex) - set(defined) == set()


def test_latex_sources_are_balanced(quick_root):
    assert unbalanced(MAIN_TEX.read_text()) == []
    assert brace_problems(MAIN_TEX.read_text()) == []
    for f in (quick_root / "tables").glob("*.tex"):
        text = f.read_text()
        assert unbalanced(text) == [], f
        assert brace_problems(text) == [], f
        assert text.isascii(), f"{f.name} has non-ASCII characters"


def test_the_paper_says_the_data_are_synthetic():
    tex = MAIN_TEX.read_text()
    assert "synthetic" in tex.lower()
    assert "generate\\_chirp\\_dataset" in tex
