"""Every command shown in the README and the docs runs as written (or as the page says
CI runs it), in a copy of the checkout (``tests/doc_commands.py`` has the rules).

The extractor's own tests are fast; running the pages' commands is slow (several
minutes: the README's tour diagnoses and fits the bundled lab-like data)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from doc_commands import (
    OPTIONS_ONLY,
    ROOT,
    VENV_PREFIX,
    Command,
    all_commands,
    check,
    extract,
    pages,
    run,
)

PAGE = """Some text.

```console
$ pmabayes simulate out.csv --trials 2  # ci: --duration 1
wrote out.csv
$ python analyses/long.py --datasets 60 \\
    --seed 3  # ci: options only
```

```text
pmabayes fit DATA.csv --out FIT.nc
```

```python
$ not a command: a Python block
```

```bash
mkdir -p made
echo made > made/file
```
"""


def test_extract_reads_commands_continuations_and_ci_instructions():
    commands = extract(PAGE, "page.md")
    assert [c.text for c in commands] == [
        "pmabayes simulate out.csv --trials 2",
        "python analyses/long.py --datasets 60 --seed 3",
        "set -e\nmkdir -p made\necho made > made/file",
    ]
    assert [c.line for c in commands] == [4, 6, 19]
    assert [c.ci for c in commands] == ["--duration 1", "options only", None]
    assert commands[0].ci_form() == ("run", "pmabayes simulate out.csv --trials 2 --duration 1")
    mode, text = commands[1].ci_form()
    assert mode == "options" and str(OPTIONS_ONLY) in text and "--seed 3" in text


def test_an_unknown_ci_instruction_is_an_error():
    with pytest.raises(ValueError, match="unknown CI instruction"):
        Command("p.md", 1, "pmabayes effects", "skip it").ci_form()
    with pytest.raises(ValueError, match="options only"):
        Command("p.md", 1, "echo hi", "options only").ci_form()


def test_the_venv_prefix_does_not_make_another_command():
    a = Command("a.md", 1, VENV_PREFIX + "pmabayes effects")
    b = Command("b.md", 9, "pmabayes effects")
    assert a.key() == b.key()


def _script(tmp_path: Path) -> Path:
    script = tmp_path / "prog.py"
    script.write_text(
        "import argparse, pathlib\n"
        "p = argparse.ArgumentParser()\n"
        "p.add_argument('--datasets', type=int)\n"
        "args = p.parse_args()\n"
        "pathlib.Path('ran').write_text('the study ran')\n")
    return script


def test_a_broken_command_fails_the_harness(tmp_path):
    """A command that fails, or whose options a program refuses, fails the check;
    ``options only`` accepts good options without running the program's work."""
    script = _script(tmp_path)
    env = dict(os.environ)
    good = run(Command("p.md", 1, f"python {script} --datasets 2", "options only"), tmp_path, env)
    check(good)
    assert not (tmp_path / "ran").exists()
    for broken in (Command("p.md", 2, f"python {script} --no-such-option", "options only"),
                   Command("p.md", 3, f"python {script} --datasets many"),
                   Command("p.md", 4, "pmabayes no-such-command")):
        with pytest.raises(AssertionError, match=r"p\.md:\d: the command shown there failed"):
            check(run(broken, tmp_path, env))
    check(run(Command("p.md", 5, f"python {script} --datasets 2"), tmp_path, env))
    assert (tmp_path / "ran").read_text() == "the study ran"


def test_the_output_a_page_shows_is_what_the_command_prints(tmp_path):
    """A shown line must stand in the output (``[...]`` for what varies); a stale number
    fails, and a command run with other options than shown is not held to it."""
    page = ("```console\n$ echo 'RMS 41.8 µm (12.3 s)'\nRMS 41.8 µm ([...] s)\n[...]\n"
            "$ echo 'RMS 41.8 µm'  # ci: -n\nRMS 40.0 µm\n```\n")
    shown, other = extract(page, "p.md")
    assert shown.shown == ("RMS 41.8 µm ([...] s)", "[...]") and other.shown == ("RMS 40.0 µm",)
    env = dict(os.environ)
    check(run(shown, tmp_path, env))
    check(run(other, tmp_path, env))
    stale = Command("p.md", 2, shown.text, shown=("RMS 40.0 µm ([...] s)",))
    with pytest.raises(AssertionError, match=r"p\.md:2: the page shows 1 line\(s\) the command "
                       r"does not print(.|\n)*shown:   RMS 40\.0"):
        check(run(stale, tmp_path, env))


def test_the_pages_hold_the_commands_they_should():
    """The harness finds the pages' commands (a test that finds none would pass on
    nothing), the README starts with the main job and CI's test command, and no
    reStructuredText page hides a console block the harness would not read."""
    commands = all_commands()
    assert len(commands) >= 40, len(commands)
    assert {Path(c.page).parts[0] for c in commands} == {"README.md", "docs"}
    readme = [c for c in commands if c.page == "README.md"]
    main_job = "pmabayes run data/pma_chirp_lab.csv --out results/lab"
    assert readme[0].text == VENV_PREFIX + main_job
    assert readme[1].text == "bash .ci/with-venv python -m pytest -q -n 2 --dist loadfile"
    for c in commands:
        c.ci_form()  # every instruction is one the harness knows
    rst = [p for p in (ROOT / "docs").rglob("*.rst") if "_build" not in p.parts
           and "generated" not in p.parts and "auto_examples" not in p.parts]
    assert not [p for p in rst if "code-block:: console" in p.read_text()]


def test_ci_runs_the_readmes_test_command_verbatim():
    command = next(c for c in all_commands() if c.is_test_suite)
    assert command.text in (ROOT / ".ci" / "run").read_text().splitlines()


def _workspace(tmp: Path) -> Path:
    """A copy of the checkout's files (git's view: tracked and new, not ignored), with
    the project's environment and the shared folder beside it linked, not copied.
    ``.ci`` and ``pyproject.toml`` are links too, so ``.ci/with-venv`` sees the
    environment as installed and never reinstalls it from the copy."""
    repo = tmp / "repo"
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout.splitlines()
    linked = (".ci/", "pyproject.toml")
    for name in listed:
        source = ROOT / name
        if name.startswith(linked) or not source.is_file():
            continue
        target = repo / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target)
    (repo / ".ci").symlink_to(ROOT / ".ci")
    (repo / "pyproject.toml").symlink_to(ROOT / "pyproject.toml")
    (repo / ".venv").symlink_to(Path(sys.prefix))
    if (ROOT.parent / "shared").exists():
        (tmp / "shared").symlink_to(ROOT.parent / "shared")
    return repo


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    stamp = Path(sys.prefix) / ".pmabayes-installed"
    newer = [p for p in (ROOT / "pyproject.toml", ROOT / ".ci" / "with-venv")
             if not stamp.exists() or p.stat().st_mtime > stamp.stat().st_mtime]
    if newer:
        pytest.fail(f"the environment is older than {newer[0].name}: run the tests through "
                    "bash .ci/with-venv, which reinstalls it first")
    return {"repo": _workspace(tmp_path_factory.mktemp("docs_commands")), "done": {},
            "times": []}


@pytest.mark.slow
@pytest.mark.parametrize("page", [str(p.relative_to(ROOT)) for p in pages()])
def test_the_commands_of_a_page_run(page, workspace):
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0")
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    start = time.perf_counter()
    for command in extract((ROOT / page).read_text(), page):
        if command.is_test_suite:
            continue  # CI's own (test_ci_runs_the_readmes_test_command_verbatim)
        if command.key() in workspace["done"]:
            continue  # run on an earlier page, in the same folder
        outcome = run(command, workspace["repo"], env)
        workspace["done"][command.key()] = outcome.seconds
        workspace["times"].append((outcome.seconds, command.where, outcome.mode))
        check(outcome)
    print(f"{page}: {time.perf_counter() - start:.0f} s")
