"""Shared plumbing of the paper's analyses (not a public API).

Every paper script (``analyses/paper/paper_*.py``) writes its figures into
``<out-root>/figures``, its tables into ``<out-root>/tables`` and the numbers the
text needs into ``<out-root>/tables/numbers_<step>.tex`` as LaTeX macros
(``\\newcommand{\\pbName}{value}``), so that ``paper/main.tex`` never types a number
by hand. The default ``<out-root>`` is ``paper/``. Fits are cached in
``<out-root>/fits`` (not committed) and shared between the scripts.

Two sizes: ``--quick`` (short synthetic chirps, few trials, short chains; for CI)
and the full size (the bundled data sets and the default sampler settings).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# the checkout (run without installing the package) and analyses/ (the studies and
# benchmarks the paper's steps wrap)
for _path in (ROOT, ROOT / "analyses"):
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

import xarray as xr  # noqa: E402

from pmabayes.data import Dataset, load  # noqa: E402
from pmabayes.inference.fitfile import load_fit, save_fit  # noqa: E402
from pmabayes.inference.likelihood import NOISE_PARAMETERS  # noqa: E402
from pmabayes.inference.sampler import FitSettings, fit  # noqa: E402
from pmabayes.model.effects import registered_effects  # noqa: E402
from pmabayes.model.model import BASE_PARAMETERS, Model  # noqa: E402
from pmabayes.synthetic import Chirp, generate_chirp_dataset  # noqa: E402

PAPER_DIR = ROOT / "paper"
DATA_DIR = ROOT / "data"

#: the hidden effects of ``data/pma_chirp_lab.csv`` (see data/README.md)
LAB_EFFECTS = {"regulator_lag": 0.045, "coulomb_friction": 0.8}
#: the candidates of the paper's criticism loop: the library the paper describes (the
#: six effects of round one), so that its figures and tables do not change as the
#: library grows
ROUND_ONE_EFFECTS = ("regulator_lag", "transport_delay", "coulomb_friction",
                     "cubic_stiffness", "pressure_stiffness", "position_offset")
#: the short chirp of the quick mode
QUICK_CHIRP = Chirp(duration_s=6.0, f0_hz=0.5, f1_hz=3.0)
QUICK_TRIALS = 4
#: sampler settings of the quick mode: short chains that need not converge
QUICK_SETTINGS = FitSettings(n_walkers=16, n_ensembles=2, max_steps=200, check_every=100,
                             min_ess=50.0, tau_multiple=5.0, ppc_draws=16)

_MACRO = re.compile(r"^pb[A-Za-z]+$")


def parser(doc: str) -> argparse.ArgumentParser:
    """An argument parser with the options every paper script shares.

    Parameters
    ----------
    doc : str
        The script's docstring (its first line is the description).

    Returns
    -------
    argparse.ArgumentParser
        With ``--out-root`` (default ``paper/``), ``--quick`` and ``--seed``.
    """
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--out-root", type=Path, default=PAPER_DIR,
                   help="folder that receives figures/, tables/ and fits/ (default paper/)")
    p.add_argument("--quick", action="store_true",
                   help="small sizes for CI: short synthetic chirps, short chains")
    p.add_argument("--seed", type=int, default=1, help="seed of everything random")
    return p


def out_dirs(out_root: Path) -> tuple[Path, Path]:
    """Create and return ``(figures, tables)`` under ``out_root``."""
    figures, tables = Path(out_root) / "figures", Path(out_root) / "tables"
    figures.mkdir(parents=True, exist_ok=True)
    tables.mkdir(parents=True, exist_ok=True)
    return figures, tables


def tex_escape(text: str) -> str:
    """Escape LaTeX's special characters in plain text."""
    out = []
    for ch in str(text):
        if ch in "&%$#_{}":
            out.append("\\" + ch)
        elif ch == "~":
            out.append(r"\textasciitilde{}")
        elif ch == "^":
            out.append(r"\textasciicircum{}")
        elif ch == "\\":
            out.append(r"\textbackslash{}")
        elif ch == "µ":
            out.append(r"\textmu{}")
        elif ch == "³":
            out.append(r"\textthreesuperior{}")
        else:
            out.append(ch)
    return "".join(out)


def symbol(name: str) -> str:
    """LaTeX symbol of a base, effect or noise parameter, in math mode without the ``$``.

    Taken from the parameter's :attr:`pmabayes.Parameter.latex`, so the paper shows
    the symbols the package declares (the name, escaped, where none is declared).
    """
    params = [*BASE_PARAMETERS, *NOISE_PARAMETERS,
              *(q for e in registered_effects().values() for q in e.parameters)]
    for q in params:
        if q.name == name:
            return q.latex or r"\mathrm{" + tex_escape(q.name) + "}"
    raise KeyError(f"no base, noise or registered effect parameter is called {name!r}")


def sig(value: float, digits: int = 3) -> str:
    """``value`` to ``digits`` significant figures, plain decimal where sensible."""
    value = float(value)
    if not math.isfinite(value):
        return "n/a"
    if value == 0.0:
        return "0"
    e = math.floor(math.log10(abs(value)))
    if -4 <= e < 5:  # up to 99 999: larger values read better beside their 10^k peers
        decimals = max(digits - 1 - e, 0)
        return f"{value:.{decimals}f}"
    mant = value / 10.0**e
    return f"\\ensuremath{{{mant:.{digits - 1}f}\\times10^{{{e}}}}}"


def pval(p: float) -> str:
    """A p-value for the text: two significant figures, or ``<0.001``."""
    p = float(p)
    if not math.isfinite(p):
        return "n/a"
    return "\\ensuremath{<}0.001" if p < 1e-3 else sig(p, 2)


class Numbers:
    """LaTeX macros of one step, written to ``tables/numbers_<step>.tex``.

    Parameters
    ----------
    step : str
        Name of the step (the file's suffix).
    quick : bool
        Whether the step ran in quick mode (recorded as a comment and in a macro
        ``\\pb<Step>Mode``).
    """

    def __init__(self, step: str, quick: bool) -> None:
        self.step = step
        self.quick = quick
        self.macros: dict[str, str] = {}
        mode = "".join(w.capitalize() for w in re.split(r"[^A-Za-z]+", step) if w)
        self.add(f"pb{mode}Mode", "quick (CI) sizes" if quick else "full sizes")

    def add(self, name: str, value: object) -> None:
        """Define macro ``\\name`` as ``value`` (text is used as given: LaTeX).

        Raises
        ------
        ValueError
            If the name is not ``pb`` followed by letters, or is defined twice.
        """
        if not _MACRO.match(name):
            raise ValueError(f"macro name {name!r} must be 'pb' followed by letters only")
        if name in self.macros:
            raise ValueError(f"macro {name!r} defined twice in step {self.step}")
        self.macros[name] = str(value)

    def write(self, tables: Path) -> Path:
        """Write the macros; return the file's path."""
        path = Path(tables) / f"numbers_{self.step}.tex"
        lines = [f"% generated by analyses/paper/paper_{self.step}.py"
                 f" ({'quick' if self.quick else 'full'} mode); do not edit"]
        lines += [f"\\newcommand{{\\{k}}}{{{v}}}" for k, v in self.macros.items()]
        path.write_text("\n".join(lines) + "\n")
        return path


def paper_dataset(quick: bool) -> Dataset:
    """The identification data: the bundled ``pma_chirp_paper.csv``, or in quick mode
    a short synthetic chirp made the same way (paper's values, default noise)."""
    if not quick:
        return load(DATA_DIR / "pma_chirp_paper.csv")
    return generate_chirp_dataset(n_trials=QUICK_TRIALS, seed=1, chirp=QUICK_CHIRP,
                                  description="quick paper-like chirps (CI)")


def lab_dataset(quick: bool) -> Dataset:
    """The lab-like data: the bundled ``pma_chirp_lab.csv``, or in quick mode a short
    synthetic chirp with the same two hidden effects."""
    if not quick:
        return load(DATA_DIR / "pma_chirp_lab.csv")
    return generate_chirp_dataset(n_trials=QUICK_TRIALS, seed=2, chirp=QUICK_CHIRP,
                                  effects=LAB_EFFECTS,
                                  description="quick lab-like chirps (CI)")


def settings(quick: bool) -> FitSettings:
    """Sampler settings: :data:`QUICK_SETTINGS` or the package defaults."""
    return QUICK_SETTINGS if quick else FitSettings()


def cached_fit(out_root: Path, key: str, dataset: Dataset, effects: Sequence[str],
               *, quick: bool, seed: int) -> tuple[xr.DataTree, float | None]:
    """Fit ``dataset`` with the base model plus ``effects``, or load the cached fit.

    Parameters
    ----------
    out_root : Path
        The output root; fits live in ``out_root/fits``.
    key : str
        Name of the fit (the file is ``<key>[_quick].nc``).
    dataset : Dataset
        The data.
    effects : sequence of str
        Effects added to the base model.
    quick : bool
        Quick sampler settings.
    seed : int
        Seed of the fit.

    Returns
    -------
    tuple
        The fit and the wall time in s of this call's fitting (None if loaded).
    """
    folder = Path(out_root) / "fits"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{key}{'_quick' if quick else ''}_seed{seed}.nc"
    if path.exists():
        return load_fit(path), None
    model = Model.for_dataset(dataset, list(effects))
    start = time.perf_counter()
    tree = fit(dataset, model, seed=seed, settings=settings(quick))
    seconds = time.perf_counter() - start
    save_fit(tree, path)
    return tree, seconds


def timed(label: str, func: Callable[[], object]) -> tuple[object, float]:
    """Run ``func``; print and return its result and wall time."""
    start = time.perf_counter()
    out = func()
    seconds = time.perf_counter() - start
    print(f"[{label}] {seconds:.1f} s", flush=True)
    return out, seconds
