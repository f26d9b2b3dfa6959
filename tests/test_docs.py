"""The documentation builds with warnings as errors, broken cross-references included,
and with every example of the gallery executed (``docs/develop.md``)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: the build the README and docs/develop.md show, but for the output folder
SPHINX_ARGS = ["-W", "--keep-going", "-b", "html"]


@pytest.mark.slow
def test_the_docs_build_without_a_warning(tmp_path):
    """Built from a copy of ``docs/`` (the build writes the generated reference and
    gallery beside its sources), so the checkout stays as it was."""
    shutil.copytree(ROOT / "docs", tmp_path / "docs",
                    ignore=shutil.ignore_patterns("_build", "generated", "auto_examples",
                                                  "sg_execution_times.rst"))
    shutil.copy2(ROOT / "CHANGELOG.md", tmp_path / "CHANGELOG.md")
    env = {k: v for k, v in os.environ.items() if k != "PMABAYES_DOCS_GALLERY"}
    env["MPLBACKEND"] = "Agg"
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "sphinx", *SPHINX_ARGS, "docs", "html"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1500)
    seconds = time.perf_counter() - start
    output = done.stdout + done.stderr
    warnings = [line for line in output.splitlines() if "WARNING" in line or "ERROR" in line]
    assert done.returncode == 0 and not warnings, (
        f"sphinx-build failed (exit {done.returncode}) after {seconds:.0f} s:\n"
        + "\n".join(warnings[:40] or output.splitlines()[-40:]))
    gallery = tmp_path / "html" / "auto_examples"
    assert len(list(gallery.glob("plot_*.html"))) >= 5
    images = list((gallery / "../_images").resolve().glob("sphx_glr_plot_*.png"))
    assert len(images) >= 5, "the examples drew no figures: were they executed?"
    assert (tmp_path / "html" / "layout.html").read_text().count("pmabayes-layers") >= 1
    print(f"docs built in {seconds:.0f} s")


def test_the_readme_shows_this_build():
    shown = f"sphinx-build {' '.join(SPHINX_ARGS)} docs docs/_build/html"
    assert shown in (ROOT / "README.md").read_text()
    assert shown in (ROOT / "docs" / "develop.md").read_text()
