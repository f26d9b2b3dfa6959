"""The house's layers: each folder (or top-level module) of pmabayes, what it builds on and
its job.

The layers are a graph, not a ladder: :data:`USES` names the layers each one builds on,
and a module may import only from its own layer and those it builds on, directly or
through them (:func:`may_import`). Siblings that build on the same layers (``synthetic``,
``criticism``, ``control``, ``design``) may not import each other. ``tests/test_layout.py``
checks this on the source, imports under ``if TYPE_CHECKING:`` included, and the
documentation's layout table is generated from :data:`LAYERS`, so the code, the test and
the docs cannot disagree.
"""

from __future__ import annotations

from functools import cache

__all__ = ["USES", "JOBS", "LAYERS", "may_import", "rank"]

#: ``name: the layers it builds on``, directly; a name is a folder of ``pmabayes/`` or a
#: module at its top. What a layer builds on, it may import, and what those build on.
USES: dict[str, tuple[str, ...]] = {
    "util": (),
    "parallel": ("util",),
    "data": ("util",),
    "model": ("data",),
    "effects": ("model",),
    "inference": ("model", "parallel"),
    "outputs": ("inference",),
    "synthetic": ("inference",),
    "criticism": ("outputs",),
    "control": ("inference",),
    "design": ("outputs",),
    "report": ("criticism", "control", "design"),
    "cli": ("report", "synthetic"),
}

#: ``name: what it holds``, in the order data flows.
JOBS: dict[str, str] = {
    "util": "shared by every layer: the one cache fingerprint, progress helper and core "
            "count",
    "parallel": "the one runner: local processes or a Dask client, workers that die with "
                "their parent",
    "data": "data sets and their checks: CSV, NetCDF and MATLAB files, sidecars and the "
            "rig's schema, units, clocks",
    "model": "parameters and priors, the physical effects, the model on its rig, the "
             "Bouc-Wen law, its linearisation, and the batched compiled simulator (code "
             "generation, kernels, API)",
    "effects": "the old import path of model/effects, kept so that older plugins load; it "
               "warns once and will be removed",
    "inference": "likelihood and noise, checks of repeated trials, the posterior density, "
                 "the fit file, the sampler (MAP and emcee), batches, and Pareto-smoothed "
                 "importance weights",
    "outputs": "the rules of outputs, for the command line and the API alike: every output "
               "path checked before any work, never over a file pmabayes did not make, "
               "pages written whole",
    "synthetic": "synthetic data: chirps, measurement noise and hidden effects for studies "
                 "and tests",
    "criticism": "residuals and adequacy, score tests and refits, the verdict, the "
                 "data-driven discrepancy, comparisons and validation",
    "control": "PID and computed-torque tracking, robustness sweeps over posterior samples, "
               "and the paper's Fig. 5",
    "design": "the next experiment: candidate experiments on the rig (chirps, steps, noise, "
              "sines, dead loads), the candidate models' fits, and the expected "
              "discrimination or interval shrinkage each experiment scores",
    "report": "figures (drawn from results passed in) and HTML pages",
    "cli": "the command line over the Python API: main and the parser, the shared options, "
           "one module per group of commands, the one ending",
}


@cache
def may_import(name: str) -> frozenset[str]:
    """The layers a module of layer ``name`` may import: its own, those it builds on
    (:data:`USES`) and theirs.

    Parameters
    ----------
    name : str
        A layer (a folder or top-level module name of ``pmabayes``).

    Returns
    -------
    frozenset of str

    Examples
    --------
    >>> sorted(may_import("model"))
    ['data', 'model', 'util']
    >>> "control" in may_import("criticism")
    False
    """
    out = {name}
    for below in USES[name]:
        out |= may_import(below)
    return frozenset(out)


@cache
def rank(name: str) -> int:
    """How far a layer is from the bottom: 0 for one that builds on nothing, else one more
    than the highest layer it builds on (for ordering the docs' table).

    Parameters
    ----------
    name : str
        A layer.

    Returns
    -------
    int
    """
    return 1 + max((rank(below) for below in USES[name]), default=-1)


#: ``name: (rank, what it holds)``, in the order data flows (the docs' layout table).
LAYERS: dict[str, tuple[int, str]] = {name: (rank(name), job) for name, job in JOBS.items()}
