"""The paper: it builds, and its inputs can be regenerated.

- ``paper/main.tex`` builds with ``latexmk`` (in a temporary copy, from the committed
  figures and tables) without a LaTeX error, an undefined reference or citation, or
  a box more than 10 pt too wide; skipped where ``latexmk`` is not installed.
- ``analyses/run_all.py --quick`` makes every file that ``main.tex`` includes and
  defines every generated macro it uses (a few minutes, into a temporary output
  root; marked ``slow``).
"""

from __future__ import annotations

import os
import re
import shutil
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


# --- the build log ---------------------------------------------------------------------

MAX_OVERFULL_PT = 10.0
_TEX_ERROR = re.compile(r"^! (.*)$", re.M)
_UNDEFINED = re.compile(r"LaTeX Warning: (Citation|Reference) `([^']*)'")
_OVERFULL = re.compile(r"Overfull \\([hv])box \((\d+(?:\.\d+)?)pt too (?:wide|high)\)[^\n]*")


def log_problems(log: str, blg: str = "") -> list[str]:
    """What is wrong in a LaTeX log (and BibTeX's ``.blg``); empty when the build is clean.

    Errors (``! ...`` lines), undefined citations and references, a request to rerun,
    and boxes more than ``MAX_OVERFULL_PT`` too wide or too high.
    """
    problems = [f"LaTeX error: {m}" for m in _TEX_ERROR.findall(log)]
    problems += [f"undefined {kind.lower()}: {key}" for kind, key in _UNDEFINED.findall(log)]
    if "There were undefined references" in log:
        problems.append("LaTeX says: there were undefined references")
    if "Label(s) may have changed" in log:
        problems.append("LaTeX says: labels may have changed (rerun needed)")
    for m in _OVERFULL.finditer(log):
        if float(m.group(2)) > MAX_OVERFULL_PT:
            problems.append(m.group(0).strip())
    problems += [f"BibTeX: {line.strip()}" for line in blg.splitlines()
                 if "didn't find a database entry" in line or "error message" in line]
    return list(dict.fromkeys(problems))  # each once, in order


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


_BAD_LOG = r"""
! Missing $ inserted.
<inserted text>
l.61 regenerated by one command (\texttt{python analyses/run_
                                                              all.py}).
LaTeX Warning: Citation `godage' on page 1 undefined on input line 51.
LaTeX Warning: Reference `tab:posterior' on page 2 undefined on input line 123.
LaTeX Warning: There were undefined references.
Overfull \hbox (59.0792pt too wide) detected at line 85
Overfull \hbox (3.2pt too wide) in paragraph at lines 90--95
Overfull \vbox (12.5pt too high) has occurred while \output is active []
"""


def test_the_log_checks_catch_errors_undefined_names_and_wide_boxes():
    problems = log_problems(_BAD_LOG, "I didn't find a database entry for \"ljung\"\n")
    assert "LaTeX error: Missing $ inserted." in problems
    assert "undefined citation: godage" in problems
    assert "undefined reference: tab:posterior" in problems
    assert "LaTeX says: there were undefined references" in problems
    assert any("59.0792pt" in p for p in problems)
    assert any("12.5pt too high" in p for p in problems)
    assert not any("3.2pt" in p for p in problems)  # under the 10 pt tolerance
    assert any(p.startswith("BibTeX:") for p in problems)
    assert len(problems) == 7
    assert log_problems("Output written on main.pdf (7 pages).\n") == []


_BUILD_ARTEFACTS = ("fits", "*.pdf", "*.aux", "*.log", "*.out", "*.fls", "*.fdb_latexmk",
                    "*.bbl", "*.blg", "*.synctex.gz")


@pytest.mark.skipif(shutil.which("latexmk") is None,
                    reason="latexmk is not on PATH: install TeX Live (see paper/README.md)")
def test_the_paper_builds_cleanly(tmp_path):
    build = tmp_path / "paper"
    shutil.copytree(MAIN_TEX.parent, build, ignore=shutil.ignore_patterns(*_BUILD_ARTEFACTS))
    env = dict(os.environ, max_print_line="10000")  # one log line per message
    proc = subprocess.run(["latexmk", "-pdf", "-interaction=nonstopmode", "main.tex"],
                          cwd=build, capture_output=True, text=True, errors="replace", env=env,
                          timeout=600)
    log = (build / "main.log").read_text(errors="replace")
    blg = build / "main.blg"
    problems = log_problems(log, blg.read_text(errors="replace") if blg.exists() else "")
    assert not problems, "paper/main.tex does not build cleanly:\n" + "\n".join(problems)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert (build / "main.pdf").stat().st_size > 0


# --- the committed inputs --------------------------------------------------------------

#: inputs that analyses/boucwen_benchmark.py, real_cavatappi.py and real_loads.py write,
#: not run_all.py: their data live outside the repository (../shared) and their fits
#: take minutes
MADE_BY_THE_BENCHMARK = {"tables/boucwen.tex", "tables/numbers_boucwen.tex",
                         "tables/numbers_real.tex", "tables/real_loads.tex"}


def _check_inputs(tex: str, root: Path, *, elsewhere: Path | None = None) -> None:
    """Every input of ``tex`` is in ``root``; with ``elsewhere``, the benchmark's in that
    folder instead (the committed paper) and every other input in ``root``."""
    files = included_files(tex)
    assert any(f.startswith("figures/") for f in files)
    assert any(f.startswith("tables/") for f in files)
    missing = missing_inputs(tex, root)
    if elsewhere is not None:
        assert MADE_BY_THE_BENCHMARK <= set(files)
        assert missing_inputs(tex, elsewhere) == []
        missing = [f for f in missing if f not in MADE_BY_THE_BENCHMARK]
    assert missing == []
    for f in files:
        where = elsewhere if elsewhere is not None and f in MADE_BY_THE_BENCHMARK else root
        assert (where / f).stat().st_size > 0, f
    numbers = sorted((root / "tables").glob("numbers_*.tex"))
    if elsewhere is not None:
        numbers += [elsewhere / f for f in sorted(MADE_BY_THE_BENCHMARK)
                    if Path(f).name.startswith("numbers_")]
    assert numbers
    # main.tex inputs every numbers file the analyses write
    assert {f"tables/{p.name}" for p in numbers} <= set(files)
    defined = defined_macros(numbers)
    assert not {k: v for k, v in defined.items() if len(v) > 1}
    assert used_macros(tex) - set(defined) == set()


def _check_balanced(tables: Path) -> None:
    assert unbalanced(MAIN_TEX.read_text()) == []
    assert brace_problems(MAIN_TEX.read_text()) == []
    for f in tables.glob("*.tex"):
        text = f.read_text()
        assert unbalanced(text) == [], f
        assert brace_problems(text) == [], f
        assert text.isascii(), f"{f.name} has non-ASCII characters"


def test_the_committed_inputs_are_complete():
    _check_inputs(MAIN_TEX.read_text(), MAIN_TEX.parent)


def test_the_committed_latex_is_balanced():
    _check_balanced(MAIN_TEX.parent / "tables")


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


@pytest.mark.slow
def test_the_quick_run_makes_every_input(quick_root):
    _check_inputs(MAIN_TEX.read_text(), quick_root, elsewhere=MAIN_TEX.parent)


@pytest.mark.slow
def test_the_quick_run_writes_balanced_latex(quick_root):
    _check_balanced(quick_root / "tables")


def test_the_paper_says_the_data_are_synthetic():
    tex = MAIN_TEX.read_text()
    assert "synthetic" in tex.lower()
    assert "generate\\_chirp\\_dataset" in tex
