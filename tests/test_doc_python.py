"""Every Python snippet of the docs runs, so that one gone stale fails CI.

A page's snippets are its ```` ```python ```` and ```` ```{code-block} python ````
blocks (Markdown) or ``.. code-block:: python`` blocks (reStructuredText). They run page
by page, in order, in one fresh namespace per page, from an empty working folder that
holds what a reader of the site has:

- ``data/``, the bundled data (a link to the checkout's);
- ``results/start/``, the files the getting-started page makes
  (``docs/guide/getting_started.md``'s own scripts, run once);
- what the page's own ```` ```bash ```` scripts make: they run in their place among the
  snippets, as a reader runs them (``tests/test_doc_commands.py`` runs them too, on
  their own).

A snippet that cannot run says why on the line before it, ``% skip-run: REASON``
(Markdown) or ``.. skip-run: REASON`` (reStructuredText); such blocks must be rare
(:data:`MAX_SKIPPED`). A failure names the page and the snippet's line: the snippet is
compiled with the page as its file name and its own line numbers.

The extractor's tests are fast; running the pages' snippets is slow (the API page and
the validation page fit, diagnose and validate, a minute or two in all).
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
import sys
import textwrap
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import pytest
from doc_commands import extract as commands

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: the page whose scripts make ``results/start/`` for the other pages' snippets
START_PAGE = "docs/guide/getting_started.md"
#: at most this many snippets may be marked not runnable
MAX_SKIPPED = 2

_MD_FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<info>.*?)\s*$")
_MD_LANG = re.compile(r"^(?:\{code-block\}\s+)?(?P<lang>[\w+-]+)$")
#: directives whose content is not Markdown (code, another markup, a file's text)
_NOT_MARKDOWN = ("{code", "{eval-rst}", "{literalinclude}", "{math}", "{cli-help}",
                 "{sidecar-keys}", "{layers-table}", "{toctree}", "{glossary}",
                 "{include}", "{image}", "{figure}")
_MD_SKIP = re.compile(r"^\s*%\s*skip-run:\s*(?P<why>.*?)\s*$")
_RST_BLOCK = re.compile(r"^(?P<indent>\s*)\.\.\s+(?:code-block|code|sourcecode)::\s*"
                        r"(?P<lang>\S+)\s*$")
_RST_SKIP = re.compile(r"^\s*\.\.\s+skip-run:\s*(?P<why>.*?)\s*$")


@dataclass(frozen=True)
class Block:
    """One code block of a page.

    Parameters
    ----------
    page : str
        The page, relative to the repository root.
    line : int
        The line of the block's first line of code (1-based).
    lang : str
        ``"python"`` or ``"bash"``.
    code : str
        The code, dedented.
    skip : str or None
        Why it is not run (its ``skip-run`` comment), or None.
    """

    page: str
    line: int
    lang: str
    code: str
    skip: str | None = None

    @property
    def where(self) -> str:
        """``page:line``, for messages."""
        return f"{self.page}:{self.line}"


def _lang(name: str) -> str | None:
    name = name.lower()
    if name in ("python", "python3", "py"):
        return "python"
    if name in ("bash", "sh"):
        return "bash"
    return None


def extract_markdown(text: str, page: str) -> list[Block]:
    """The Python and bash blocks of a Markdown (MyST) page, in order.

    Parameters
    ----------
    text : str
        The page's source.
    page : str
        Its name, for the blocks' ``page``.

    Returns
    -------
    list of Block
    """
    blocks: list[Block] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        match = _MD_FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        fence, info = match.group("fence"), match.group("info")
        end = next((j for j in range(i + 1, len(lines))
                    if lines[j].strip() == fence[0] * len(fence)), len(lines))
        kind = _MD_LANG.match(info)
        lang = _lang(kind.group("lang")) if kind else None
        if lang is None and info.startswith("{") and not info.startswith(_NOT_MARKDOWN):
            # a directive of Markdown content (a note, a dropdown) may hold code blocks
            inner = extract_markdown("\n".join(lines[i + 1:end]), page)
            blocks += [dataclasses.replace(b, line=b.line + i + 1) for b in inner]
        if lang:
            body = lines[i + 1:end]
            first = i + 2
            while body and body[0].lstrip().startswith(":"):  # a directive's options
                body, first = body[1:], first + 1
            before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
            skip = _MD_SKIP.match(before)
            blocks.append(Block(page, first, lang, textwrap.dedent("\n".join(body)),
                                skip.group("why") if skip else None))
        i = end + 1
    return blocks


def extract_rst(text: str, page: str) -> list[Block]:
    """The Python and bash ``code-block`` directives of a reStructuredText page.

    Parameters
    ----------
    text : str
        The page's source.
    page : str
        Its name, for the blocks' ``page``.

    Returns
    -------
    list of Block
    """
    blocks: list[Block] = []
    lines = text.splitlines()
    for i, line in enumerate(lines):
        match = _RST_BLOCK.match(line)
        if not match or not _lang(match.group("lang")):
            continue
        indent = len(match.group("indent"))
        j = i + 1
        while j < len(lines) and lines[j].strip().startswith(":"):  # options
            j += 1
        body: list[str] = []
        first = None
        for k in range(j, len(lines)):
            current = lines[k]
            if current.strip() and len(current) - len(current.lstrip()) <= indent:
                break
            if current.strip() and first is None:
                first = k + 1
            if first is not None:
                body.append(current)
        while body and not body[-1].strip():
            body.pop()
        before = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        skip = _RST_SKIP.match(before)
        blocks.append(Block(page, first or j + 1, _lang(match.group("lang")),
                            textwrap.dedent("\n".join(body)),
                            skip.group("why") if skip else None))
    return blocks


def page_blocks(path: Path, root: Path = ROOT) -> list[Block]:
    """The Python and bash blocks of one page (Markdown or reStructuredText).

    Parameters
    ----------
    path : Path
        The page.
    root : Path
        The repository root, which names are relative to.

    Returns
    -------
    list of Block
    """
    name = str(path.relative_to(root))
    extract = extract_rst if path.suffix == ".rst" else extract_markdown
    return extract(path.read_text(encoding="utf-8"), name)


def doc_pages(root: Path = ROOT) -> list[Path]:
    """The hand-written pages (built output, generated pages and the gallery out)."""
    skip = ("_build", "auto_examples", "generated", "_templates")
    return sorted(p for p in (root / "docs").rglob("*")
                  if p.suffix in (".md", ".rst")
                  and not any(part in skip for part in p.relative_to(root).parts))


def pages_with_python(root: Path = ROOT) -> list[str]:
    """The pages with at least one Python snippet, relative to ``root``."""
    return [str(p.relative_to(root)) for p in doc_pages(root)
            if any(b.lang == "python" for b in page_blocks(p, root))]


def run_blocks(blocks: list[Block], cwd: Path, env: dict) -> list[tuple[str, float]]:
    """Run a page's blocks in order in ``cwd``: the Python ones in one fresh namespace,
    the bash ones with ``bash -e``; the skipped ones not at all.

    Parameters
    ----------
    blocks : list of Block
        One page's blocks.
    cwd : Path
        The working folder (the process's current folder during the Python ones).
    env : dict
        The bash scripts' environment.

    Returns
    -------
    list of (str, float)
        Each block run, ``page:line``, and its seconds.

    Raises
    ------
    AssertionError
        When a block fails: its page and line, its code and the error.
    """
    namespace: dict = {"__name__": "__doc_snippet__"}
    times = []
    previous = Path.cwd()
    os.chdir(cwd)
    try:
        for block in blocks:
            if block.skip is not None:
                continue
            start = time.perf_counter()
            if block.lang == "bash":
                done = subprocess.run(["bash", "-e", "-c", block.code], cwd=cwd, env=env,
                                      capture_output=True, text=True, timeout=900)
                if done.returncode:
                    tail = "\n".join((done.stdout + done.stderr).splitlines()[-30:])
                    raise AssertionError(f"{block.where}: the script shown there failed "
                                         f"(exit {done.returncode}):\n{tail}")
            else:
                # the page's own line numbers in a traceback
                code = compile("\n" * (block.line - 1) + block.code, block.page, "exec")
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")  # a page's warnings are its output
                        exec(code, namespace)  # noqa: S102 - the docs' own snippets
                except Exception as err:
                    raise AssertionError(
                        f"{block.where}: the Python snippet shown there failed: "
                        f"{type(err).__name__}: {err}\n{block.code}") from err
            times.append((block.where, time.perf_counter() - start))
    finally:
        os.chdir(previous)
    return times


PAGE = """Text.

```python
x = 1
```

% skip-run: needs a lab's own file
```python
load("my_file.csv")
```

```{code-block} python
:caption: two
y = x + 1
```

```bash
echo made > made.txt
```

```text
not code
```

```console
$ pmabayes effects
```

````{note}
Inside a note:

```python
z = y * 2
```
````
"""

RST = """Title
=====

.. code-block:: python

   z = 3

   w = z * 2

.. skip-run: the reason
.. code-block:: python

   broken(

Text after.
"""


def test_extract_reads_python_and_bash_blocks_and_the_reasons_to_skip():
    blocks = extract_markdown(PAGE, "p.md")
    assert [(b.line, b.lang, b.code, b.skip) for b in blocks] == [
        (4, "python", "x = 1", None),
        (9, "python", 'load("my_file.csv")', "needs a lab's own file"),
        (14, "python", "y = x + 1", None),
        (18, "bash", "echo made > made.txt", None),
        (33, "python", "z = y * 2", None),
    ]
    rst = extract_rst(RST, "p.rst")
    assert [(b.line, b.code, b.skip) for b in rst] == [
        (6, "z = 3\n\nw = z * 2", None), (13, "broken(", "the reason")]


def test_a_broken_snippet_fails_with_its_page_and_line(tmp_path):
    env = dict(os.environ)
    times = run_blocks(extract_markdown(PAGE, "p.md"), tmp_path, env)
    assert [where for where, _ in times] == ["p.md:4", "p.md:14", "p.md:18", "p.md:33"]
    assert (tmp_path / "made.txt").read_text() == "made\n"
    stale = PAGE.replace("y = x + 1", "y = x + undefined_name")
    with pytest.raises(AssertionError, match=r"p\.md:14: the Python snippet shown there "
                       r"failed: NameError") as err:
        run_blocks(extract_markdown(stale, "p.md"), tmp_path, env)
    # the traceback points at the page's own line
    assert ("p.md", 14) in _frames(err.value.__cause__.__traceback__)
    with pytest.raises(AssertionError, match=r"p\.md:18: the script shown there failed"):
        run_blocks(extract_markdown(PAGE.replace("echo made", "false &&"), "p.md"),
                   tmp_path, env)
    # a fresh namespace per page: the next page does not see this one's names
    with pytest.raises(AssertionError, match="NameError"):
        run_blocks([Block("q.md", 1, "python", "print(x)")], tmp_path, env)


def _frames(tb) -> list[tuple[str, int]]:
    """The (file, line) of each frame of a traceback."""
    out = []
    while tb is not None:
        out.append((tb.tb_frame.f_code.co_filename, tb.tb_lineno))
        tb = tb.tb_next
    return out


def test_the_pages_hold_the_snippets_they_should():
    """The harness finds the pages' snippets (a test that finds none would pass on
    nothing), few are marked not runnable, each with a reason, and no page reads the
    project's ``../shared`` folder outside the real-measurement studies."""
    pages = pages_with_python()
    assert {"docs/guide/lab_files.md", "docs/guide/model.md", "docs/guide/validation.md",
            "docs/api/index.rst"} <= set(pages), pages
    blocks = [b for p in doc_pages() for b in page_blocks(p) if b.lang == "python"]
    skipped = [b for b in blocks if b.skip is not None]
    assert len(skipped) <= MAX_SKIPPED, [b.where for b in skipped]
    assert all(b.skip.strip() for b in skipped)
    studies = DOCS / "studies"
    shared = [str(p.relative_to(ROOT)) for p in doc_pages()
              if studies not in p.parents and p.name != "develop.md"
              and any("../shared" in code for code in
                      [b.code for b in page_blocks(p)]
                      + [c.text for c in commands(p.read_text(), str(p))])]
    assert not shared, f"these pages' code reads ../shared, which users do not have: {shared}"


@pytest.fixture(scope="module")
def started(tmp_path_factory):
    """``results/start/`` as the getting-started page's scripts make it, once."""
    folder = tmp_path_factory.mktemp("start")
    run_blocks([b for b in page_blocks(ROOT / START_PAGE) if b.lang == "bash"], folder,
               _env())
    assert (folder / "results" / "start" / "muscle_a.csv").is_file()
    return folder / "results" / "start"


def _env() -> dict:
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0")
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.mark.slow
@pytest.mark.parametrize("page", pages_with_python())
def test_the_python_snippets_of_a_page_run(page, started, tmp_path):
    matplotlib.use("Agg")
    (tmp_path / "data").symlink_to(ROOT / "data")
    shutil.copytree(started, tmp_path / "results" / "start")
    start = time.perf_counter()
    times = run_blocks(page_blocks(ROOT / page), tmp_path, _env())
    print(f"{page}: {time.perf_counter() - start:.0f} s "
          + ", ".join(f"{where.rsplit(':', 1)[1]}: {s:.0f} s" for where, s in times))
