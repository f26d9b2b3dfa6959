"""The commands shown in the README and the docs, and how CI runs them.

A command is a line starting with ``$ `` inside a ```` ```console ```` block of a
Markdown page (a trailing ``\\`` continues it on the next line); every other line of
the block is output. A ```` ```bash ```` block is a script: it runs whole, as one
command (``bash -e``). A command may end with an instruction for CI:

``# ci: ARGS``
    run it with ``ARGS`` appended (argparse: the last occurrence of an option wins);
``# ci: options only``
    check that the program accepts its options (``tests/_options_only.py`` lets
    argparse parse them and stops), without running it.

The output shown under a command that CI runs as written is checked too: each line
must stand in what the command prints (anywhere: standard error follows standard
output), ``[...]`` standing for any text, so a page cannot show numbers that a
change has made stale.

The test commands (``python -m pytest``) are CI's own: ``.ci/run`` runs the README's
first one verbatim, and the harness, which runs inside that suite, checks that
rather than running the suite again. ``docs/develop.md`` says all this to readers.
"""

from __future__ import annotations

import difflib
import math
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OPTIONS_ONLY = Path(__file__).resolve().parent / "_options_only.py"

_FENCE = re.compile(r"^\s*(`{3,}|~{3,})\s*(\S*)")
_CI = re.compile(r"\s+#\s*ci:\s*(?P<what>.*?)\s*$")
#: the prefix that runs a command in the project's environment; the harness runs
#: in it already, so a command with and without it is the same command
VENV_PREFIX = "bash .ci/with-venv "


@dataclass(frozen=True)
class Command:
    """One command of a page.

    Parameters
    ----------
    page : str
        The page, relative to the repository root.
    line : int
        Its line on the page (1-based).
    text : str
        The command as shown, without the prompt and the ``# ci:`` instruction.
    ci : str or None
        The ``# ci:`` instruction, if any.
    shown : tuple of str
        The output lines shown under it, stripped (``[...]`` stands for any text).
    """

    page: str
    line: int
    text: str
    ci: str | None = None
    shown: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        """``page:line``, for messages."""
        return f"{self.page}:{self.line}"

    @property
    def is_test_suite(self) -> bool:
        """Whether this is one of the test commands, which CI itself runs."""
        return " -m pytest" in f" {self.text}"

    def ci_form(self) -> tuple[str, str]:
        """How CI runs the command: ``("run", shell text)`` or ``("options", shell text)``.

        Returns
        -------
        tuple of str
            The mode and the text to give ``bash -c``.

        Raises
        ------
        ValueError
            For an instruction that is neither ``options only`` nor arguments.
        """
        if self.ci is None:
            return "run", self.text
        if self.ci == "options only":
            return "options", options_only(self)
        if self.ci.startswith("-"):
            return "run", f"{self.text} {self.ci}"
        raise ValueError(f"{self.where}: unknown CI instruction '# ci: {self.ci}'; write "
                         "'# ci: --OPTION VALUE ...' (appended) or '# ci: options only'")

    def key(self) -> str:
        """What makes two commands the same (with or without the venv prefix)."""
        mode, text = self.ci_form()
        return mode + ":" + text.removeprefix(VENV_PREFIX)


def extract(text: str, page: str) -> list[Command]:
    """The commands of one Markdown page.

    Parameters
    ----------
    text : str
        The page's source.
    page : str
        Its name, for the commands' ``page``.

    Returns
    -------
    list of Command
        In the order they appear.
    """
    commands: list[Command] = []
    fence: str | None = None
    in_console = False
    script: list[str] | None = None
    pending: list[str] = []
    start = 0
    output = False  # lines after a command in its block are its output
    for number, line in enumerate(text.splitlines(), start=1):
        match = _FENCE.match(line)
        if fence is None and match:
            fence, in_console = match.group(1), match.group(2) == "console"
            if match.group(2) in ("bash", "sh"):
                script, start = [], number + 1
            continue
        if fence is not None and line.strip() == fence:
            if script:
                commands.append(Command(page, start, "set -e\n" + "\n".join(script)))
            fence, in_console, script, output = None, False, None, False
            continue
        if script is not None:
            script.append(line)
            continue
        if not in_console:
            continue
        if pending:
            pending.append(line.strip())
        elif line.startswith("$ "):
            pending, start, output = [line[2:].strip()], number, False
        elif output and line.strip():
            commands[-1] = replace(commands[-1], shown=(*commands[-1].shown, line.strip()))
        if pending and not pending[-1].endswith("\\"):
            joined = " ".join(part.removesuffix("\\").strip() for part in pending)
            ci = _CI.search(joined)
            command = joined[:ci.start()] if ci else joined
            commands.append(Command(page, start, command.strip(),
                                    ci.group("what") if ci else None))
            pending, output = [], True
    return commands


def pages(root: Path = ROOT) -> list[Path]:
    """The README, then the docs' Markdown pages (built output and generated pages out).

    Parameters
    ----------
    root : Path
        The repository root.

    Returns
    -------
    list of Path
    """
    skip = ("_build", "auto_examples", "generated")
    docs = sorted(p for p in (root / "docs").rglob("*.md")
                  if not any(part in skip for part in p.relative_to(root).parts))
    return [root / "README.md", *docs]


def all_commands(root: Path = ROOT) -> list[Command]:
    """Every command of every page of :func:`pages` under ``root``, README first."""
    out = []
    for path in pages(root):
        out += extract(path.read_text(), str(path.relative_to(root)))
    return out


def options_only(command: Command) -> str:
    """The shell text that checks a command's options without running it.

    The program must be ``python SCRIPT.py`` or ``pmabayes`` (with environment
    assignments before it, if any); it is run under ``tests/_options_only.py``.

    Parameters
    ----------
    command : Command
        The command.

    Returns
    -------
    str
    """
    words = shlex.split(command.text.removeprefix(VENV_PREFIX))
    env = []
    while words and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", words[0]):
        env.append(words.pop(0))
    if words[:1] == ["python"] and len(words) > 1 and words[1].endswith(".py"):
        program = [sys.executable, str(OPTIONS_ONLY), words[1]]
        args = words[2:]
    elif words[:1] == ["pmabayes"]:
        program = [sys.executable, str(OPTIONS_ONLY), "-m", "pmabayes"]
        args = words[1:]
    else:
        raise ValueError(f"{command.where}: '# ci: options only' needs 'python SCRIPT.py ...' "
                         f"or 'pmabayes ...', got {command.text!r}")
    return shlex.join([*env, *program, *args])


_NUMBER = r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?"


def shows(shown: str, printed: str, rel_tol: float = 1e-3) -> bool:
    """Whether a line a page shows stands in a printed line: ``[...]`` stands for any
    text, and each number for one that agrees with it to ``rel_tol`` (the last digit of
    a seven-digit ELPD may move with the machine's arithmetic; a stale value does not
    pass).

    Parameters
    ----------
    shown : str
        The page's line.
    printed : str
        A line of the command's output.
    rel_tol : float
        Relative tolerance of the numbers.

    Returns
    -------
    bool

    Examples
    --------
    >>> shows("ΔELPD +1740342.7 ± 482.1 ([...] s)", "ΔELPD +1740342.6 ± 482.1 (3.2 s)")
    True
    >>> shows("RMS 41.8 µm", "RMS 40.0 µm")
    False
    """
    numbers: list[float] = []
    parts = []
    for piece in re.split(r"(\[\.\.\.\]|" + _NUMBER + ")", shown.strip()):
        if piece == "[...]":
            parts.append(".*")
        elif re.fullmatch(_NUMBER, piece):
            numbers.append(float(piece))
            parts.append(f"({_NUMBER})")
        else:
            parts.append(re.escape(piece))
    found = re.search("".join(parts), printed)
    return found is not None and all(
        math.isclose(float(got), want, rel_tol=rel_tol)
        for got, want in zip(found.groups(), numbers, strict=True))


@dataclass
class Outcome:
    """What running one command gave."""

    command: Command
    mode: str
    seconds: float
    returncode: int
    output: str


def run(command: Command, cwd: Path, env: dict, timeout_s: float = 1200.0) -> Outcome:
    """Run a command as CI runs it (see :meth:`Command.ci_form`), in ``cwd``.

    Parameters
    ----------
    command : Command
        The command.
    cwd : Path
        The folder to run it in (a copy of the checkout).
    env : dict
        Its environment.
    timeout_s : float
        Longest it may take.

    Returns
    -------
    Outcome
    """
    mode, text = command.ci_form()
    start = time.perf_counter()
    try:
        done = subprocess.run(["bash", "-c", text], cwd=cwd, env=env, capture_output=True,
                              text=True, timeout=timeout_s)
        code, output = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as err:
        code = -1
        output = f"timed out after {timeout_s:.0f} s\n{err.stdout or ''}{err.stderr or ''}"
    return Outcome(command, mode, time.perf_counter() - start, code, output)


def check(outcome: Outcome) -> None:
    """Fail with the page, the line, the command and its output's tail, unless it
    exited 0 and, run as written, printed every line the page shows under it.

    Parameters
    ----------
    outcome : Outcome
        A command's run.

    Raises
    ------
    AssertionError
        When the command failed, or printed other than the page shows.
    """
    tail = "\n".join(outcome.output.splitlines()[-40:])
    if outcome.returncode != 0:
        raise AssertionError(
            f"{outcome.command.where}: the command shown there failed "
            f"(exit {outcome.returncode}, {outcome.mode}):\n$ {outcome.command.text}\n{tail}")
    if outcome.command.ci is not None:
        return  # run otherwise than shown: its output may differ
    printed = [line.strip() for line in outcome.output.splitlines()]
    stale = [f"shown:   {shown}\nclosest: "
             + "".join(difflib.get_close_matches(shown, printed, n=1, cutoff=0.0))
             for shown in outcome.command.shown
             if not any(shows(shown, line) for line in printed)]
    if stale:
        raise AssertionError(
            f"{outcome.command.where}: the page shows {len(stale)} line(s) the command does "
            f"not print (update the page, or elide what varies with [...]):\n$ "
            f"{outcome.command.text}\n" + "\n".join(stale) + f"\nprinted:\n{tail}")
