"""Experiments that disagree, read as evidence: each experiment's own estimates side by
side, the parameters that move between them, how they follow the experiments'
declared conditions, and which candidate effect makes them agree.

The joint fit tests whether several experiments agree on one parameter set
(:func:`pmabayes.inference.search.experiments_agreement`: a likelihood ratio of each
experiment's own MAP against the joint one). Where they do not, the model lacks what
differs between them; a parameter that moves with the load (``K_e`` rising with it)
says which physics (the muscle's operating point). The conditions are the sidecar's
``"conditions"`` (:func:`pmabayes.data.experiment_conditions`) and the rig's moving
mass where it differs between experiments.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pmabayes.data import Dataset, experiment_conditions
from pmabayes.data.rig import declared_rig

__all__ = ["experiment_conditions_table", "moving_parameters", "trend_text",
           "agreement_change"]

#: A parameter moves between experiments when its own estimates differ by more than
#: this factor (largest over smallest magnitude) ...
MOVES_FACTOR = 1.25
#: ... and it follows a condition when their rank correlation is at least this.
FOLLOWS_CORRELATION = 0.9


def experiment_conditions_table(datasets: Sequence[Dataset]) -> dict[str, list[float]]:
    """The conditions that differ between experiments, each a list in their order.

    Parameters
    ----------
    datasets : sequence of Dataset
        The experiments.

    Returns
    -------
    dict of str to list of float
        Declared conditions every experiment gives, and ``moving_mass_kg`` from each
        one's rig; only those that are not the same in all.
    """
    declared = [experiment_conditions(ds.metadata or {}, str(ds.source or "the data"))
                for ds in datasets]
    table: dict[str, list[float]] = {}
    for key in declared[0] if declared else ():
        if all(key in d for d in declared):
            table[key] = [d[key] for d in declared]
    masses = []
    for ds in datasets:
        rig = declared_rig(ds.metadata) or {}  # notes about a rig declare no mass
        mass = rig.get("moving_mass_kg")
        masses.append(float(mass) if isinstance(mass, int | float) else math.nan)
    if "moving_mass_kg" not in table and all(np.isfinite(masses)):
        table["moving_mass_kg"] = masses
    return {k: v for k, v in table.items() if len(set(v)) > 1}


def _ranks(values: Sequence[float]) -> np.ndarray:
    return np.argsort(np.argsort(np.asarray(values, dtype=float))).astype(float)


def _rank_correlation(a: Sequence[float], b: Sequence[float]) -> float:
    ra, rb = _ranks(a), _ranks(b)
    if np.std(ra) == 0 or np.std(rb) == 0:
        return 0.0
    return float(np.corrcoef(ra, rb)[0, 1])


#: Two experiments' own estimates are apart when they differ by more than this many
#: standard errors of their difference (Laplace, in the sampler's coordinates).
APART_SE = 3.0


def _apart(per: dict, names: list, param: str) -> bool:
    """Whether some two experiments' own estimates of ``param`` differ beyond
    :data:`APART_SE` standard errors (True where the uncertainties are not recorded):
    a parameter one experiment cannot identify wanders without moving."""
    points = [per[n].get("z_own", {}).get(param) for n in names]
    if any(p is None for p in points):
        return True
    return any(abs(a[0] - b[0]) > APART_SE * math.hypot(a[1], b[1])
               for i, a in enumerate(points) for b in points[i + 1:])


def moving_parameters(agreement: dict, conditions: dict[str, list[float]]) -> list[dict]:
    """The parameters whose own estimates move between experiments, largest move first.

    Parameters
    ----------
    agreement : dict
        :func:`pmabayes.inference.search.experiments_agreement`'s, with each
        experiment's ``values_own``.
    conditions : dict
        :func:`experiment_conditions_table`'s, in the experiments' order.

    Returns
    -------
    list of dict
        ``parameter``, ``values`` (per experiment), ``factor`` (largest over smallest
        magnitude; only parameters whose own estimates differ beyond their
        uncertainty, :data:`APART_SE`), and ``follows``: the condition it follows best
        (``condition``, ``correlation``, ``low``, ``high``: the conditions at the two
        ends), or None.
    """
    per = agreement.get("experiments") or {}
    names = list(per)
    if len(names) < 2 or any("values_own" not in per[n] for n in names):
        return []
    common = set.intersection(*(set(per[n]["values_own"]) for n in names))
    out = []
    for param in sorted(common):
        values = [per[n]["values_own"][param] for n in names]
        mags = np.abs(values)
        if not np.all(np.isfinite(mags)) or mags.min() <= 0:
            continue
        factor = float(mags.max() / mags.min())
        if factor < MOVES_FACTOR or not _apart(per, names, param):
            continue
        follows = None
        for cond, levels in conditions.items():
            r = _rank_correlation(levels, values)
            if abs(r) >= FOLLOWS_CORRELATION and (follows is None
                                                  or abs(r) > abs(follows["correlation"])):
                lo, hi = int(np.argmin(levels)), int(np.argmax(levels))
                follows = {"condition": cond, "correlation": r,
                           "low": levels[lo], "high": levels[hi],
                           "at_low": values[lo], "at_high": values[hi]}
        out.append({"parameter": param, "values": dict(zip(names, values, strict=True)),
                    "factor": factor, "follows": follows})
    return sorted(out, key=lambda m: -m["factor"])


def trend_text(moving: list[dict], most: int = 3) -> str:
    """The words for the parameters that move: what follows which condition.

    Parameters
    ----------
    moving : list of dict
        :func:`moving_parameters`'s.
    most : int
        How many parameters to name.

    Returns
    -------
    str
        Empty where nothing moves.

    Examples
    --------
    >>> trend_text([{"parameter": "K_e", "factor": 2.1, "values": {},
    ...              "follows": {"condition": "load_kg", "correlation": 1.0, "low": 0.1,
    ...                          "high": 0.5, "at_low": 400.0, "at_high": 840.0}}])
    'K_e rises with load_kg, about x2.1 from 0.1 to 0.5 (400 to 840)'
    """
    parts = []
    for m in moving[:most]:
        f = m["follows"]
        if f is None:
            parts.append(f"{m['parameter']} moves by x{_times(m['factor'])} with no "
                         "declared condition it follows")
            continue
        ratio = abs(f["at_high"] / f["at_low"]) if f["at_low"] else math.inf
        way = "rises" if abs(f["at_high"]) > abs(f["at_low"]) else "falls"
        parts.append(f"{m['parameter']} {way} with {f['condition']}, about "
                     f"x{_times(max(ratio, 1 / ratio))} from {f['low']:.3g} to {f['high']:.3g} "
                     f"({f['at_low']:.3g} to {f['at_high']:.3g})")
    return "; ".join(parts)


def _times(factor: float) -> str:
    """A factor with two significant digits, never in exponent form."""
    return f"{factor:.2g}" if factor < 100 else f"{factor:.0f}"


def agreement_change(base: dict | None, refits: Sequence) -> list[dict]:
    """Each refitted candidate's agreement statistic beside the diagnosed model's.

    Parameters
    ----------
    base : dict or None
        The diagnosed model's agreement test (None for one experiment).
    refits : sequence of Refit
        The refits, each with its own ``agreement`` (or None).

    Returns
    -------
    list of dict
        ``effect``, ``statistic`` (before, after), ``p_value`` (after) and
        ``agree`` (after), for the refits whose agreement was tested; the ones
        that make the experiments agree first, then by the statistic.
    """
    if not base or base.get("agree") is None:
        return []
    out = []
    for r in refits:
        a = getattr(r, "agreement", None)
        if not a or a.get("agree") is None:
            continue
        out.append({"effect": r.effect, "statistic": [base["statistic"], a["statistic"]],
                    "p_value": a["p_value"], "agree": a["agree"]})
    return sorted(out, key=lambda c: (not c["agree"], c["statistic"][1]))
