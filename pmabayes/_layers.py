"""The house's layers: each folder (or top-level module) of pmabayes, its rank and its job.

A module may import only from layers of its own rank or lower. ``tests/test_layout.py``
checks this on the source, and the documentation's layout table is generated from
:data:`LAYERS`, so the code, the test and the docs cannot disagree.
"""

from __future__ import annotations

__all__ = ["LAYERS", "TOP_LEVEL_RANK", "rank"]

#: ``name: (rank, what it holds)``, in the order data flows; a name is a folder of
#: ``pmabayes/`` or a module at its top.
LAYERS: dict[str, tuple[int, str]] = {
    "util": (0, "shared by every layer: the one cache fingerprint, progress helper and "
                "core count"),
    "parallel": (0, "the one runner: local processes or a Dask client, workers that die "
                    "with their parent"),
    "data": (1, "data sets and their checks: CSV, NetCDF and MATLAB files, sidecars, "
                "units, clocks"),
    "model": (2, "parameters and priors, the physical effects, the model on its rig, the "
                 "Bouc-Wen law, its linearisation, and the batched compiled simulator (code "
                 "generation, kernels, API)"),
    "effects": (2, "the old import path of model/effects, kept so that older plugins "
                   "load; it warns once and will be removed"),
    "inference": (3, "likelihood and noise, checks of repeated trials, the posterior "
                     "density, the fit file, the sampler (MAP and emcee) and batches"),
    "outputs": (3, "the rules of outputs, for the command line and the API alike: every "
                   "output path checked before any work, never over a file pmabayes did "
                   "not make, pages written whole"),
    "synthetic": (4, "synthetic data: chirps, measurement noise and hidden effects for "
                     "studies and tests"),
    "criticism": (5, "residuals and adequacy, score tests and refits, the verdict, the "
                     "data-driven discrepancy, comparisons and validation"),
    "control": (6, "PID and computed-torque tracking, robustness sweeps over posterior "
                   "samples, and the paper's Fig. 5"),
    "report": (7, "figures (drawn from results passed in) and HTML pages"),
    "cli": (8, "the command line over the Python API: main and the parser, the shared "
               "options, one module per group of commands, the one ending"),
}

#: ``import pmabayes`` (the top level) brings the model layer
TOP_LEVEL_RANK = 2


def rank(name: str) -> int:
    """The rank of a layer (a folder or top-level module name of ``pmabayes``)."""
    return LAYERS[name][0]
