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

The test commands (``python -m pytest``) are CI's own: ``.ci/run`` runs the README's
first one verbatim, and the harness, which runs inside that suite, checks that
rather than running the suite again. ``docs/develop.md`` says all this to readers.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
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
    """

    page: str
    line: int
    text: str
    ci: str | None = None

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
            fence, in_console, script = None, False, None
            continue
        if script is not None:
            script.append(line)
            continue
        if not in_console:
            continue
        if pending:
            pending.append(line.strip())
        elif line.startswith("$ "):
            pending, start = [line[2:].strip()], number
        if pending and not pending[-1].endswith("\\"):
            joined = " ".join(part.removesuffix("\\").strip() for part in pending)
            ci = _CI.search(joined)
            command = joined[:ci.start()] if ci else joined
            commands.append(Command(page, start, command.strip(),
                                    ci.group("what") if ci else None))
            pending = []
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
    exited 0.

    Parameters
    ----------
    outcome : Outcome
        A command's run.

    Raises
    ------
    AssertionError
        When the command failed.
    """
    if outcome.returncode != 0:
        tail = "\n".join(outcome.output.splitlines()[-40:])
        raise AssertionError(
            f"{outcome.command.where}: the command shown there failed "
            f"(exit {outcome.returncode}, {outcome.mode}):\n$ {outcome.command.text}\n{tail}")
