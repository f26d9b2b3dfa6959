"""The diagnosis in words: the verdict, and each candidate's explanation, from the
numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pmabayes.criticism.bands import band_label, band_rms
from pmabayes.criticism.refit import Refit
from pmabayes.criticism.signature import Signature
from pmabayes.util import format_together


def contribution_text(contribution_m: np.ndarray, base_residual_m: np.ndarray,
                      dt_s: float, bands_hz) -> str:
    """How a refitted effect's contribution to the output matches the base residual, in
    one sentence (empty for a contribution that is zero)."""
    if not np.std(contribution_m) > 0:
        return ""
    corr = float(np.corrcoef(contribution_m, base_residual_m)[0, 1])
    rms = band_rms(contribution_m, dt_s, bands_hz)
    k = int(np.argmax(rms))
    return (f" Its contribution to the output correlates {corr:+.2f} with the base model's "
            f"residual and is largest at {band_label(bands_hz[k])} ({rms[k] * 1e6:.4g} µm RMS).")


def _share(fraction: float, adequate: bool) -> str:
    """A fraction in percent; never 100% for a model that is not adequate (what is left
    is not nothing)."""
    percent = 100.0 * fraction
    return f"{min(percent, 99.0) if not adequate else percent:.0f}%"


def removed_text(explained_rms: float | None, explained: float, ratio: float,
                 adequate: bool) -> str:
    """How much of the misfit a change removes, in words that agree with the RMS errors
    said beside them: the share of the mean-square error above the noise floor where
    there is a floor (:func:`pmabayes.criticism.bands.excess_removed`), else of the
    whitened residual's excess energy; and, while the model is not adequate, how far
    above the floor the error still is.

    Parameters
    ----------
    explained_rms : float or None
        Share of the mean-square error above the floor removed; None without a floor.
    explained : float
        Share of the whitened residual's excess energy removed.
    ratio : float
        The error over the floor afterwards (the worst experiment's); NaN without one.
    adequate : bool
        Whether the model is adequate afterwards.

    Returns
    -------
    str
        ``"removes X% of ..."``, without a full stop.
    """
    if explained_rms is None:  # the energy is under noise identified with each model
        return (f"removes {_share(explained, adequate)} of the whitened residual's excess "
                "energy (with no noise floor the noise is identified with each model and "
                "takes in part of the misfit, so this share can exceed the RMS error's fall)")
    text = f"removes {_share(explained_rms, adequate)} of the mean-square error above the floor"
    if not adequate and math.isfinite(ratio):
        text += f", yet the error is still {ratio:.3g}x the floor"
    return text


def _refit_removed(refit: Refit) -> str:
    ratios = [sig.ratio for sig in refit.signatures if math.isfinite(sig.ratio)]
    return removed_text(refit.explained_rms, refit.explained,
                        max(ratios) if ratios else math.nan, refit.adequate)


def _after_text(signatures: Sequence[Signature], names: Sequence[str]) -> str:
    """The refit's RMS error against the floor: ``X µm (Yx the floor)``, per experiment."""
    def one(sig: Signature) -> str:
        floor = (f"{sig.ratio:.3g}x the floor" if math.isfinite(sig.bands[-1].floor_m)
                 else "no floor")
        return f"{format_together(sig.bands[-1].rms_m * 1e6, digits=4)[0]} µm ({floor})"

    if len(signatures) == 1:
        return one(signatures[0])
    return ", ".join(f"{one(sig)} in {n}" for sig, n in zip(signatures, names, strict=True))


def describe_signatures(signatures: Sequence[Signature], names: Sequence[str]) -> str:
    """Each experiment's residual signature in words (named when there are several)."""
    if len(signatures) == 1:
        return signatures[0].describe()
    return " ".join(f"In {n}: {sig.describe()}" for sig, n in zip(signatures, names, strict=True))


def explanation_text(eff, evidence: float, p_value: float, significant: bool,
                     describe: str, refit: Refit | None, contribution: str,
                     ci_prob: float, names: Sequence[str]) -> str:
    """A candidate's paragraph: what the effect is, the residual's signature, its score
    test and, when refitted, its size and what adding it does."""
    text = f"{eff.name} ({eff.stage} stage): {' '.join(eff.description.split())} "
    text += describe
    text += (f" Score test that {eff.name} is missing: statistic {evidence:.3g}, "
             f"p = {p_value:.2g}, {'significant' if significant else 'not significant'}.")
    if refit is None:
        return text
    parts = []
    for p in eff.parameters:
        if p.name in refit.interval:
            lo, hi = refit.interval[p.name]
            parts.append(f"{p.name} = {refit.values[p.name]:.4g} {p.unit} "
                         f"({ci_prob:.0%} interval {lo:.4g} to {hi:.4g})")
    if getattr(refit, "failed", None):
        return text + f" Added and refitted: {elpd_text(refit)}." + contribution
    text += (f" Added and refitted, it takes {', '.join(parts)}; the RMS error falls to "
             f"{_after_text(refit.signatures, names)}: it {_refit_removed(refit)}; and the "
             f"held-out (leave-one-out) {elpd_text(refit, 'changes by')}.")
    return text + contribution


def elpd_text(refit, verb: str = "") -> str:
    """``ΔELPD +d ± se`` of a refit; ``± n/a`` with the reason where the standard error
    cannot be estimated; that the estimate is not reliable, why, and what its in-sample
    witness says (:attr:`pmabayes.criticism.results.Refit.witnessed`); that the refit failed
    (its numbers are not the effect's), or that its ELPD could not be estimated
    (PSIS-LOO over the refit's Laplace draws gave no finite value, e.g. when its draws
    do not simulate).

    Parameters
    ----------
    refit : Refit
        The refit.
    verb : str
        ``"changes by"`` gives ``ELPD changes by +d ± se``; empty, ``ΔELPD +d ± se``.

    Returns
    -------
    str
    """
    failed = getattr(refit, "failed", None)
    if failed:
        return f"refit failed ({failed}), so no ΔELPD is given"
    if not math.isfinite(refit.elpd_diff):
        return "ΔELPD not estimable: PSIS-LOO over the refit's Laplace draws gave no finite value"
    head = f"ELPD {verb} " if verb else "ΔELPD "
    note = refit.se_note
    if note:
        text = f"{head}{refit.elpd_diff:+.1f} ± n/a ({note})"
    else:
        text = f"{head}{refit.elpd_diff:+.1f} ± {refit.elpd_diff_se:.1f}"
    return text + _reliability_text(refit)


def _reliability_text(refit) -> str:
    """`` (not reliable: WHY; ...)`` after an unreliable ΔELPD, with its witness; empty
    for a reliable one."""
    why = getattr(refit, "elpd_note", None)
    if not why:
        return ""
    d = getattr(refit, "plugin_diff", math.nan)
    se = getattr(refit, "plugin_diff_se", math.nan)
    if not math.isfinite(d):
        return f" (not reliable: {why}; with no in-sample witness it names nothing)"
    pm = f"{se:.1f}" if math.isfinite(se) else "n/a"
    verdict = ("agrees" if refit.witnessed else
               "does not clear two standard errors, so it names nothing")
    return (f" (not reliable: {why}; the in-sample log likelihood at the two MAPs less the "
            f"added parameters, {d:+.1f} ± {pm}, {verdict})")


def elpd_short(refit) -> str:
    """A refit's ΔELPD for a table cell: ``+d ± se``, ``+d ± n/a`` (no standard error),
    either with `` (not reliable)`` where its estimate is not, ``refit failed`` or ``not
    estimable`` (the words of :func:`elpd_text`, shortened).

    Parameters
    ----------
    refit : Refit
        The refit.

    Returns
    -------
    str
    """
    if getattr(refit, "failed", None):
        return "refit failed"
    if not math.isfinite(refit.elpd_diff):
        return "not estimable"
    se = f"{refit.elpd_diff_se:.1f}" if math.isfinite(refit.elpd_diff_se) else "n/a"
    flag = " (not reliable)" if getattr(refit, "elpd_note", None) else ""
    return f"{refit.elpd_diff:+.1f} ± {se}{flag}"


def _sig_text(signature: Signature) -> str:
    overall = signature.bands[-1]
    if math.isfinite(overall.floor_m):
        rms, floor_um = format_together(overall.rms_m * 1e6, overall.floor_m * 1e6, digits=4)
        floor = f"against a floor of {floor_um} µm"
    else:
        rms, floor = format_together(overall.rms_m * 1e6, digits=4)[0], \
            "with no noise floor (no repeats)"
    return (f"RMS error {rms} µm {floor}; whitened residual energy "
            f"{signature.energy:.3g} (p = {signature.energy_p:.2g}), Ljung-Box "
            f"p = {signature.ljung_box_p:.2g}")


def verdict_text(name: str, effects: tuple, experiments: tuple, adequate: bool,
                 missing: str | None, refits: dict, findings: list, min_explained: float,
                 twins: list | None = None, partial: str | None = None,
                 data: str = "DATA.csv") -> str:
    """The diagnosis' conclusion in words: what is missing (or the best partial step, or
    that nothing is, or that nothing in the library explains the misfit), where the
    misfit shows, and the next command.

    ``findings`` are in the order the ranking shows them (refits by ELPD gain): the
    verdict's "top-ranked" refit is the first of them, as in the list. ``data`` names
    the data files in the ``pmabayes design`` command offered where near twins cannot
    be told apart.
    """
    names = [e.name for e in experiments]
    if len(experiments) == 1:
        sig = _sig_text(experiments[0].signature)
    else:
        sig = "; ".join(f"{e.name}: {_sig_text(e.signature)}" for e in experiments)
    where = ""
    if len(experiments) > 1 and not adequate:
        bad = [e.name for e in experiments if not e.adequate]
        good = [e.name for e in experiments if e.adequate]
        where = (f"The misfit shows in {', '.join(bad)}"
                 + (f"; {', '.join(good)} {'is' if len(good) == 1 else 'are'} consistent with "
                    "the noise." if good else "."))
    floors = all(math.isfinite(e.signature.bands[-1].floor_m) for e in experiments)
    text = _verdict_core(name, effects, sig, adequate, missing, refits, findings,
                         min_explained, names, twins, partial, floors, data)
    return paragraphs(text, where, *(f"{e.floor_note()}." for e in experiments
                                     if e.floor_note()))


#: what separates the paragraphs of a verdict (:func:`paragraphs`; a page splits on it)
PARAGRAPH_BREAK = "\n\n"


def paragraphs(*parts: str) -> str:
    """The verdict's parts as paragraphs: the conclusion and its next command first, then
    each finding that qualifies it on its own, so that a reader can stop after the first.

    Parameters
    ----------
    *parts : str
        Sentences; empty ones are left out.

    Returns
    -------
    str
        The parts, stripped, separated by blank lines.

    Examples
    --------
    >>> print(paragraphs("base: adequate.", "", " The misfit shows in a."))
    base: adequate.
    <BLANKLINE>
    The misfit shows in a.
    """
    return PARAGRAPH_BREAK.join(p.strip() for p in parts if p.strip())


def _verdict_core(name: str, effects: tuple, sig: str, adequate: bool, missing: str | None,
                  refits: dict, findings: list, min_explained: float, names: list,
                  twins: list | None = None, partial: str | None = None,
                  floors: bool = True, data: str = "DATA.csv") -> str:
    if missing is not None:
        r = refits[missing]
        tied = [t[0] for t in twins or ()]
        others = [f.effect for f in findings
                  if f.refit is not None and f.effect != missing and f.effect not in tied]
        text = (f"{name}: {missing} is missing ({sig}). Adding it lowers the RMS error to "
                f"{_after_text(r.signatures, names)} and {_refit_removed(r)}.")
        for twin, diff, se in twins or ():
            text += (f" But {missing} and {twin} cannot be told apart by these data: both "
                     f"account for the misfit and their leave-one-trial-out ELPDs differ by "
                     f"only {diff:+.1f} ± {se:.1f} (less than two standard errors), so "
                     f"{missing} is named for its slightly better ELPD, not proven.")
        if tied:
            # the next experiment that separates them is what pmabayes design chooses
            base = f" --effects {','.join(effects)}" if effects else ""
            text += (" Data that excite where they differ would separate them; `pmabayes "
                     f"design {data}{base} --candidates {','.join([missing, *tied])} "
                     "--input-range LO,HI --out next` designs that experiment (LO,HI: the "
                     "rig's safe input range, in the data file's units).")
        if others:
            text += (f" It predicts left-out trials better than the other refitted "
                     f"candidate(s) ({', '.join(others)}).")
        return text + (f" Next: add it (--effects {','.join([*effects, missing])}) and "
                       "diagnose again.")
    significant = [f for f in findings if f.significant]
    if adequate and not significant:
        return (f"{name} is adequate: the residual is consistent with the noise floor ({sig}) "
                "and no candidate effect is significantly missing.")
    above = "above the noise floor" if floors else "not consistent with the noise"
    if not significant:
        return (f"{name}: the residual is {above} ({sig}), but no effect in "
                "the library is significantly missing; something outside the library is. "
                "See the residual signature figures, and register an effect that describes "
                "it.")
    if adequate:
        def refit_text(refit) -> str:  # elpd_text of a failed refit says "refit" itself
            text = elpd_text(refit)
            return text if text.startswith("refit") else f"refit {text}"

        named = ", ".join(f"{f.effect} (p = {f.p_value:.2g}" + (
            f", {refit_text(f.refit)})" if f.refit else ")") for f in significant)
        return (f"{name} is adequate: the residual is consistent with the noise floor ({sig}). "
                f"The score test flags {named}, but no refit predicts left-out trials "
                "clearly better, so nothing is named; with a family-wise level of 5%, this "
                "is what a false alarm looks like.")
    if partial is not None:
        return _partial_text(name, effects, sig, refits[partial], names, floors, above,
                             min_explained)
    top = next((f.refit for f in findings if f.refit is not None), None)
    detail = ""
    if top is not None:
        # the list's first, in the list's order: never called "best" (it may predict worse)
        detail = f": the top-ranked refit, {top.effect}, has {elpd_text(top)}"
        if top.failed is None and top.implausible:
            detail += f", and its estimates are implausible ({top.implausible})"
        elif top.failed is None and floors:
            detail += f"; it {_refit_removed(top)}"
    return (f"{name}: the residual is {above} ({sig}); candidates are significant but no "
            "refit predicts held-out data clearly better (ΔELPD above two standard errors, "
            "a reliable estimate or one its in-sample witness confirms, plausible estimates, "
            "a search that succeeded and, where experiments are left out in turn, a better "
            f"prediction of them){detail}. Something outside the library is missing; no "
            "candidate is named.")


def _partial_text(name: str, effects: tuple, sig: str, r: Refit, names: list, floors: bool,
                  above: str, min_explained: float) -> str:
    """The verdict that names a partial step: a refit that clearly predicts held-out data
    better without accounting for all of the misfit (or, without a floor, with no way
    to tell whether it does)."""
    why = (f"no candidate accounts for the misfit (at least {min_explained:.0%} of its "
           "excess, or an adequate model)" if floors else
           "with no noise floor these data cannot tell whether a candidate accounts for "
           "all of the misfit")
    removes = f" and {_refit_removed(r)}" if floors else ""
    return (f"{name}: the residual is {above} ({sig}); {why}, but {r.effect} adds a partial "
            f"improvement: adding it lowers the RMS error to {_after_text(r.signatures, names)}"
            f"{removes}, and predicts held-out data better ({elpd_text(r)}, above two "
            f"standard errors). Next: add it (--effects {','.join([*effects, r.effect])}) "
            "and diagnose again; "
            + ("it is a step, not all that is missing." if floors else
               "what it leaves shows there."))


def transfer_words(refits: dict, named: str | None) -> str:
    """The verdict's sentences on the experiments left out in turn
    (:attr:`~pmabayes.criticism.refit.Refit.transfer`): how the effect named predicts
    them, and each candidate passed over because it predicts them worse.

    Parameters
    ----------
    refits : dict
        Effect name to refit.
    named : str or None
        The effect the verdict names (missing, or the partial step).

    Returns
    -------
    str
        Empty where no experiment was left out.
    """
    words = ""
    if named is not None and refits[named].transfer is not None:
        words += (f" {named} carries to the experiments it was not fitted to: "
                  f"{refits[named].transfer.text()}.")
    for r in sorted(refits.values(), key=lambda r: -r.elpd_diff):
        if r.transfer is not None and r.transfer.carries is False:
            words += (f" {r.effect} ({elpd_text(r)}) is not named: {r.transfer.text()}, "
                      "so it fits the experiments it was given and not the next one.")
    return words
