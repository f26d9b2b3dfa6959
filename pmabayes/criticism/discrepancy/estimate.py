"""The estimate: the flexible force with its evidence per state, then a closed form over
the dictionary (or the flexible shape, tabulated) written as a user effect and checked by
a nonlinear refit."""

from __future__ import annotations

import math
import re
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pmabayes.criticism.adequacy import ENERGY_TOLERANCE
from pmabayes.criticism.bands import band_errors, excess_removed
from pmabayes.criticism.discrepancy.dictionary import (
    best_hinges,
    best_period,
    dictionary_terms,
    tabulated_term,
)
from pmabayes.criticism.discrepancy.linalg import a_b
from pmabayes.criticism.discrepancy.plugin import describe_terms, effect_name, write_plugin
from pmabayes.criticism.discrepancy.problem import (
    LOOP_WIDTHS_M,
    MEMORY_TAUS_S,
    STATES,
    WRITABLE,
    Block,
    LinearProblem,
    bspline_design,
)
from pmabayes.criticism.discrepancy.reading import ReadingError, reading_error
from pmabayes.criticism.discrepancy.regression import (
    PenalisedFit,
    correction,
    fit_blocks,
    forward_path,
    loo_scores,
    stlsq,
    stlsq_path,
)
from pmabayes.criticism.discrepancy.results import Discrepancy, Proposal, StateEvidence
from pmabayes.criticism.discrepancy.verify import verify_proposal
from pmabayes.criticism.elpd import paired_difference
from pmabayes.criticism.prose import removed_text
from pmabayes.criticism.signature import residual_signature
from pmabayes.inference.likelihood import Likelihood
from pmabayes.model.simulator import Simulation
from pmabayes.outputs import check_folder_for_new_files
from pmabayes.util import format_together

__all__ = ["estimate_discrepancy"]


def estimate_discrepancy(
    likelihood: Likelihood,
    noise,
    values: dict,
    simulation: Simulation,
    *,
    plugin_dir: str | Path | None | bool = None,
    verify: bool = True,
    command: str | None = None,
    effects=(),
    start=None,
) -> Discrepancy:
    """Estimate the missing force from the data and propose a closed form for it.

    Parameters
    ----------
    likelihood : Likelihood
        Data and the diagnosed model.
    noise : object
        Identified noise (``sigma``, ``rho``, ``white``).
    values : dict
        The model's MAP.
    simulation : Simulation
        The model at its MAP, with its states.
    plugin_dir : str or Path or False, optional
        The folder where the proposal's ``.py`` file is kept (created if missing,
        checked first by :func:`pmabayes.outputs.check_folder_for_new_files`). An
        existing file of the same name is never overwritten: a numbered name is
        chosen instead. None or False (the default): the file is written to a
        temporary folder for the refit and not kept (the proposal's ``plugin`` is then
        None, and its text says how to keep it).
    verify : bool
        Refit the model with the written effect (nonlinear, through the simulator)
        and report what it achieves.
    command : str, optional
        The data's path for the suggested command line.
    effects : iterable of str
        The diagnosed model's effects, for the suggested command line.
    start : numpy.ndarray, optional
        The experiment's estimated start ``(3,)`` at the MAP (None for a declared one).

    Returns
    -------
    Discrepancy

    Raises
    ------
    pmabayes.outputs.OutputError
        If ``plugin_dir`` is a file or cannot be written in (before any work).

    Examples
    --------
    :func:`pmabayes.diagnose` calls it on the diagnosed model at its MAP
    (``Diagnosis.discrepancy``). Called directly, on three short chirps with 2 N of
    Coulomb friction the base model lacks (about 5 s; ``verify=False`` skips the refit):

    >>> import numpy as np
    >>> from pmabayes import Model
    >>> from pmabayes.criticism.discrepancy import estimate_discrepancy
    >>> from pmabayes.criticism.refits import fit_base
    >>> from pmabayes.criticism.settings import DiagnoseSettings
    >>> from pmabayes.synthetic import Chirp, generate_chirp_dataset
    >>> data = generate_chirp_dataset(n_trials=3, chirp=Chirp(duration_s=4.0, sample_rate_hz=200.0),
    ...                               effects={"coulomb_friction": 2.0}, seed=1)
    >>> base = fit_base([Model.for_dataset(data)], [data], ["friction"],
    ...                 DiagnoseSettings(substeps=1), np.random.default_rng(0))
    >>> found = estimate_discrepancy(base.likelihoods[0], base.noises[0], base.points[0][0],
    ...                              base.simulations[0], verify=False)
    >>> found.states[0].state  # the state the missing force depends on most
    'velocity'
    >>> found.proposal.expression
    '2.066 N * tanh(v/5 mm/s)'
    """
    keep = plugin_dir is not None and plugin_dir is not False
    if keep:
        check_folder_for_new_files(plugin_dir, "plugin_dir")
    problem = LinearProblem(likelihood, noise, values, simulation, start)
    n = problem.n_counted
    e0 = float(problem.r_w @ problem.r_w)
    # the memory state's time constant, then the loop state's width, by the evidence
    fits = {}
    width = LOOP_WIDTHS_M[len(LOOP_WIDTHS_M) // 2]
    for tau in MEMORY_TAUS_S:
        fits[tau, width] = fit_blocks(problem, problem.blocks(tau, width))
    tau = max(fits, key=lambda k: fits[k].log_evidence)[0]
    for w in LOOP_WIDTHS_M:
        if (tau, w) not in fits:
            fits[tau, w] = fit_blocks(problem, problem.blocks(tau, w))
    tau, width = max(fits, key=lambda k: fits[k].log_evidence)
    full = fits[tau, width]
    blocks = full.blocks
    only_j = fit_blocks(problem, [], [])
    loo_full = loo_scores(problem, blocks, full.log_lambda)
    loo_none = loo_scores(problem, [], [])
    gain, gain_se = paired_difference(loo_full, loo_none)
    excess = max(e0 - n, 1e-12)
    explained = float(np.clip((only_j.energy - full.energy) / excess, 0.0, 1.0)) \
        if e0 > n else 0.0
    corr = correction(problem, blocks, full.coef)
    before = band_errors(problem.dataset, problem.x0)[-1]
    after_band = band_errors(problem.dataset, problem.x0 + corr)[-1]
    ratio_after = after_band.ratio
    removed = excess_removed([before.rms_m], [after_band.rms_m], [before.floor_m], [n])
    energy_after = full.energy / n
    states, pdep = _state_evidence(problem, full, loo_full)
    # without repeats there is no floor: near it means a whitened residual near pure noise
    near = bool(ratio_after <= 1.5) if math.isfinite(ratio_after) else \
        bool(energy_after <= 1.0 + ENERGY_TOLERANCE)
    st = problem.states(tau, width)
    proposal = None
    # errors of the reading as good as any force: a force proposal would only imitate them
    reading = reading_error(problem, loo_full, loo_none) if gain > max(2.0 * gain_se, 2.0) \
        else None
    not_force = reading is not None and reading.as_good
    if gain > max(2.0 * gain_se, 2.0) and not not_force:
        if not keep:  # checked, not kept: nothing is written outside a temporary folder
            with tempfile.TemporaryDirectory(prefix="pmabayes-proposal-") as tmp:
                proposal = _propose(problem, st, (tau, width), blocks, full, loo_full, gain, states,
                                    tmp, verify, command)
            if proposal is not None:
                proposal = replace(proposal, plugin=None)
        else:
            proposal = _propose(problem, st, (tau, width), blocks, full, loo_full, gain, states,
                                plugin_dir, verify, command)
    left = (problem.resid - corr)[problem.seen]
    after = _level(ratio_after, float(np.sqrt(np.mean(left ** 2))),
                   energy_after)
    if not_force:
        other = _reading_text(reading)
    else:
        other = None if near and explained >= 0.5 else _other_cause(
            likelihood, noise, simulation, explained, after)
    text = _text(states, explained, removed, ratio_after, after, gain, gain_se, proposal,
                 other, command, tuple(effects),
                 "left-out stretches of the record" if problem.by_stretches
                 else "left-out trials", before.rms_m)
    return Discrepancy(states=states, explained=explained, explained_rms=removed,
                       ratio_after=float(ratio_after),
                       elpd_gain=gain, elpd_gain_se=gain_se, memory_tau_s=float(tau),
                       loop_width_m=float(width),
                       partial_dependence=pdep, proposal=proposal, near_floor=near,
                       other_cause=other, text=text, energy_after=float(energy_after),
                       not_a_force=bool(not_force or other is not None))


def _level(ratio: float, rms_m: float, energy: float) -> str:
    """Where a model stands: ``"2.1x the floor"``, or, for a record without repeats (no
    floor), its RMS error and its whitened residual's energy."""
    if math.isfinite(ratio):
        return f"{ratio:.3g}x the floor"
    return (f"an RMS error of {rms_m * 1e6:.4g} µm (no floor; whitened residual energy "
            f"{energy:.3g} under the noise identified with the diagnosed model)")


def _good(v: dict | None) -> bool:
    """A verified proposal that brings the model to adequate within 1.5x the floor; without
    a floor, to a whitened residual no larger than the noise (the noise identified with
    the diagnosed model holds part of its misfit, so adequacy under it means little)."""
    if v is None:
        return False
    if not math.isfinite(v["ratio"]):
        return bool(v["energy"] <= 1.0 + ENERGY_TOLERANCE)
    return bool(v["adequate"] and v["ratio"] <= 1.5)


def _closeness(v: dict) -> tuple:
    """Order of verified proposals: adequate first, then nearer the floor (nearer pure
    noise without a floor)."""
    return (v["adequate"], -v["ratio"] if math.isfinite(v["ratio"]) else -v["energy"])


def _block_slice(problem: LinearProblem, blocks: list, i: int) -> slice:
    """Where block ``i``'s coefficients are among a fit's (after the parameters')."""
    start = problem.j.shape[1] + sum(c.white.shape[1] for c in blocks[:i])
    return slice(start, start + blocks[i].white.shape[1])


def _state_evidence(problem: LinearProblem, full: PenalisedFit, loo_full: np.ndarray
                    ) -> tuple[list, dict]:
    """Each state's evidence (the ELPD lost by dropping its terms), most first, and the
    flexible force's partial dependence on it."""
    blocks = full.blocks
    states, pdep = [], {}
    units = {s: u for s, u, _ in STATES}
    for i, b in enumerate(blocks):
        rest = [c for c in blocks if c is not b]
        ll = np.delete(full.log_lambda, i)
        loss, se = paired_difference(loo_full, loo_scores(problem, rest, ll))
        sl = _block_slice(problem, blocks, i)
        w = full.coef[sl] / b.scale
        along = a_b(b.basis, w)
        amp = float(np.std(along))
        states.append(StateEvidence(b.state, units[b.state], loss, se, amp,
                                    bool(loss > max(2.0 * se, 2.0))))
        pdep[b.state] = _partial(b, w, full.cov[sl, sl] / b.scale**2, float(np.mean(along)))
    states.sort(key=lambda s: -s.elpd_loss)
    return states, pdep


def _partial(b: Block, w: np.ndarray, cov: np.ndarray, mean: float) -> dict:
    lo, hi = b.grid
    if b.state == "direction":
        grid = np.array([-1.0, 1.0])
        basis = grid[:, None]
    else:
        grid = np.linspace(lo, hi, 120)
        basis, _ = bspline_design(grid, b.basis.shape[1], lo, hi)
    f = basis @ w - mean
    sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", basis, cov, basis), 0.0))
    return {"grid": grid, "force_n": f, "sd_n": sd,
            "unit": {s: u for s, u, _ in STATES}[b.state]}


@dataclass(frozen=True)
class _Dictionary:
    """The dictionary's terms along the trajectory, and their responses scaled to unit
    whitened norm."""

    terms: list
    raw: np.ndarray
    white: np.ndarray
    scale: np.ndarray

    def fit(self, problem: LinearProblem, support) -> list:
        """The terms of a support with their coefficients (least squares, with the
        model's parameters)."""
        idx = list(support)
        sub = np.concatenate([problem.j_w, self.white[:, idx]], axis=1)
        w = stlsq(sub, problem.r_w, 0.0, keep=range(sub.shape[1]))
        k0 = problem.j_w.shape[1]
        return [(self.terms[j][0], float(w[k0 + i] / self.scale[j])) for i, j in enumerate(idx)]


def _dictionary(problem: LinearProblem, st: dict, tau: float, width: float) -> _Dictionary:
    period = best_period(problem, st["position"])
    terms = dictionary_terms(st, tau, period, best_hinges(problem, st["position"]), width)
    raw, white = problem.responses(np.stack([t[1] for t in terms], axis=1))
    scale = np.linalg.norm(white, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    return _Dictionary(terms, raw / scale, white / scale, scale)


def _scored_supports(problem: LinearProblem, dic: _Dictionary, loo_full: np.ndarray) -> list:
    """``(ELPD against the flexible estimate, its se, support)`` of every support on
    STLSQ's threshold path and on the greedy forward path, sparsest first."""
    a = np.concatenate([problem.j_w, dic.white], axis=1)
    k0 = problem.j_w.shape[1]
    supports = stlsq_path(a, problem.r_w, k0) | forward_path(problem.j_w, dic.white, problem.r_w)
    scored = []
    for support in sorted(supports, key=lambda t: (len(t), t)):
        if {dic.terms[j][0].state for j in support} >= {"memory", "loop"}:
            continue  # an effect has one state of its own: not both
        loo = loo_scores(problem, [], [], extra=(dic.white, dic.raw, list(support)))
        scored.append((*paired_difference(loo, loo_full), support))
    return scored


def _sparsest(scored: list):
    """The sparsest support within two standard errors (or 2) of the best, if any."""
    if not scored:
        return None
    top_d = max(c[0] for c in scored)
    return min((c for c in scored if c[0] >= top_d - max(2.0 * c[1], 2.0)),
               key=lambda c: (len(c[2]), -c[0]))


def _discard(proposal: Proposal, existing: set) -> None:
    """Remove a proposal's file if this run wrote it and it is not kept."""
    if proposal.plugin is not None and proposal.plugin not in existing:
        Path(proposal.plugin).unlink(missing_ok=True)


def _propose(problem, st, scales, blocks, full, loo_full, gain, states, plugin_dir, verify,
             command):
    """STLSQ over the dictionary, the threshold by LOO ELPD; else the tabulated shape.
    ``scales``: the memory's time constant and the loop's width."""
    dic = _dictionary(problem, st, *scales)
    scored = _scored_supports(problem, dic, loo_full)
    best = _sparsest(scored)
    closed = None
    if best is not None:
        d, se, support = best
        # near the flexible estimate: within its noise, or a small share of its gain
        closed = (dic.fit(problem, support), d, se, d > -max(2.0 * se, 4.0, 0.02 * gain))
    series = {t.slug: v for t, v in dic.terms}
    folder = Path(plugin_dir)
    existing = {str(f) for f in folder.glob("*.py")} if folder.is_dir() else set()

    def write(chosen, kind, d, se, **kw) -> Proposal:
        return _write_proposal(problem, chosen, kind, d, se, plugin_dir, verify, command, **kw)

    top = states[0].state if states else None
    if closed is not None and closed[3]:
        prop = _closed_form(problem, dic, closed, scored, series, existing, write)
        if not verify or _good(prop.verified) or top not in WRITABLE:
            return prop
        # a closed form near the linearised estimate can still refit far from the floor
        # (a force whose shape no term has, a bump): the tabulated shape is refitted too,
        # and the nonlinear refit decides
        tab = _tabulated(problem, blocks, full, top, loo_full, write)
        better = tab.verified is not None and (prop.verified is None or _closeness(
            tab.verified) > _closeness(prop.verified))
        keep, drop = (tab, prop) if better else (prop, tab)
        _discard(drop, existing)
        return keep
    if closed is not None and verify and all(t.writable for t, _ in closed[0]):
        # the linearisation may be what keeps it from the flexible estimate (a steep
        # force, a period slightly off): the nonlinear refit decides
        prop = write(closed[0], "closed form", closed[1], closed[2], series=series)
        v = prop.verified
        if _good(v):
            return prop
        _discard(prop, existing)
    # no closed form near the flexible estimate: the flexible shape itself, tabulated
    if top in WRITABLE:
        return _tabulated(problem, blocks, full, top, loo_full, write)
    if closed is not None:
        return write(closed[0], "closed form", closed[1], closed[2], series=series)
    return None


def _closed_form(problem, dic: _Dictionary, closed: tuple, scored: list, series: dict,
                 existing: set, write) -> Proposal:
    """The closed form near the flexible estimate, written and refitted; when it has terms
    in z or a state of its own and its refit fails, the best of it, the best support
    without terms in z, and the best in (x, v, p) alone."""
    chosen, d, se, _ = closed
    prop = write(chosen, "closed form", d, se, series=series)
    # terms in z (or a state of its own) trade against the base model's own parameters
    # in the nonlinear refit: simpler supports are refitted too, nearest the data kept
    tried = set()
    for allowed in (lambda t: t.state != "hysteresis", lambda t: t.state in WRITABLE):
        v = prop.verified
        if v is None or _good(v) or all(allowed(t) for t, _ in chosen):
            break
        plain = [c for c in scored if all(allowed(dic.terms[j][0]) for j in c[2])]
        if not plain or max(plain, key=lambda c: c[0])[2] in tried:
            continue
        d2, se2, support2 = max(plain, key=lambda c: c[0])
        tried.add(support2)
        prop2 = write(dic.fit(problem, support2), "closed form", d2, se2, series=series)
        v2 = prop2.verified
        better = v2 is not None and _closeness(v2) > _closeness(v)
        keep, drop = (prop2, prop) if better else (prop, prop2)
        _discard(drop, existing)
        prop = keep
    return prop


def _tabulated(problem: LinearProblem, blocks: list, full: PenalisedFit, top: str,
               loo_full: np.ndarray, write) -> Proposal:
    """The flexible force's shape in its strongest state, tabulated with one amplitude."""
    i = next(k for k, b in enumerate(blocks) if b.state == top)
    b = blocks[i]
    w = full.coef[_block_slice(problem, blocks, i)] / b.scale
    term, shape_w = tabulated_term(b, w)
    r, wh = problem.responses(term[1][:, None])
    loo = loo_scores(problem, [], [], extra=(wh, r, [0]))
    d, se = paired_difference(loo, loo_full)
    return write([(term[0], 1.0)], "tabulated", d, se, tables=shape_w)


def _write_proposal(problem, chosen, kind, d, se, plugin_dir, verify, command, tables=None,
                    series=None):
    """Write the proposal as an effect, refit it, and drop terms the refit finds negligible."""
    taken = set(problem.model.parameter_names) | {f"c_{n}" for n in problem.model.effect_names}
    renamed = []
    for t, c in chosen:  # a model that already holds an earlier proposal keeps its names
        slug, k = t.slug, 2
        while f"c_{slug}" in taken:
            slug, k = f"{t.slug}{k}", k + 1
        taken.add(f"c_{slug}")
        if series is not None:
            series = {**series, slug: series[t.slug]}
        renamed.append((replace(t, slug=slug), c))
    chosen = renamed
    plugin = verified = None
    told = chosen
    if all(t.writable for t, _ in chosen):
        path, created = write_plugin(chosen, kind, tables, plugin_dir)
        if verify:
            verified = verify_proposal(problem, path, chosen)
            told = [(t, verified["values"][f"c_{t.slug}"]) for t, _ in chosen]
            if kind == "closed form" and series is not None and len(chosen) > 1:
                # a term that only compensated the linearisation shrinks in the refit
                amps = [float(np.std(c * series[t.slug])) for t, c in told]
                keep = [tc for tc, a in zip(told, amps, strict=True) if a >= 0.1 * max(amps)]
                if len(keep) < len(told):
                    path2, created2 = write_plugin(keep, kind, tables, plugin_dir)
                    v2 = verify_proposal(problem, path2, keep)
                    # kept without the term only when that refits no worse (a loop's
                    # small force can still carry its shape)
                    if _closeness(v2) >= _closeness(verified):
                        if created:
                            path.unlink()  # written by this run, and superseded
                        chosen, path, created, verified = keep, path2, created2, v2
                        told = [(t, verified["values"][f"c_{t.slug}"]) for t, _ in chosen]
                    elif created2:
                        path2.unlink()
        plugin = str(path)
    if verified is not None and "L_period" in verified["values"]:
        mm = verified["values"]["L_period"] * 1e3  # the refitted period, in the words too
        told = [(replace(t, name=re.sub(r"/ [0-9.e+-]+ mm\)", f"/ {mm:.4g} mm)", t.name),
                         words=re.sub(r"period of [0-9.e+-]+ mm", f"period of {mm:.4g} mm",
                                      t.words)), c) for t, c in told]
    if verified is not None and "x_break" in verified["values"]:
        mm = verified["values"]["x_break"] * 1e3  # the refitted breakpoint, in the words too
        told = [(replace(t, name=re.sub(r"-?[0-9.]+(e[+-]?[0-9]+)? mm", f"{mm:.3g} mm", t.name),
                         words=re.sub(r"-?[0-9.]+(e[+-]?[0-9]+)? mm", f"{mm:.3g} mm", t.words))
                 if t.breakpoint_m is not None else t, c) for t, c in told]
    if verified is not None and "tau_memory" in verified["values"]:
        tau = f"{verified['values']['tau_memory']:.3g}"  # the refitted time constant too
        told = [(replace(t, name=re.sub(r"tau=[0-9.e+-]+ s", f"tau={tau} s", t.name),
                         words=re.sub(r"over [0-9.e+-]+ s", f"over {tau} s", t.words))
                 if t.memory_tau_s is not None else t, c) for t, c in told]
    if verified is not None and "w_loop" in verified["values"]:
        mm = f"{verified['values']['w_loop'] * 1e3:.3g} mm"  # the refitted width too
        told = [(replace(t, name=re.sub(r"width=[0-9.e+-]+ mm", f"width={mm}", t.name),
                         words=re.sub(r"over [0-9.e+-]+ mm", f"over {mm}", t.words))
                 if t.loop_width_m is not None else t, c) for t, c in told]
    expression, description = describe_terms(told, kind)
    terms = [{"term": t.name, "unit": t.unit, "coefficient": c, "parameter": f"c_{t.slug}",
              "words": t.words, "writable": t.writable} for t, c in told]
    return Proposal(effect=effect_name(chosen), expression=expression,
                    description=description, terms=terms, kind=kind, elpd_diff=float(d),
                    elpd_diff_se=float(se), plugin=plugin, verified=verified)


def _reading_text(reading: ReadingError) -> str:
    """The verdict when errors of the reading do as well as any force."""
    return ("The missing piece is not a force of the states tried: an error of the "
            f"position reading ({' and '.join(reading.terms)}) predicts the left-out data "
            f"as well as a flexible force does (ΔELPD {reading.elpd_vs_force:+.1f} ± "
            f"{reading.se:.1f} against it, {reading.elpd_gain:+.1f} over the model alone), "
            "so no force is proposed: check the sensor and its mounting.")


def _other_cause(lik, noise, sim, explained: float, after: str) -> str:
    """What the flexible force leaves, and which non-force cause the signature suggests."""
    sig = residual_signature(lik, noise, sim)
    corr = sig.correlations
    name, value = max(corr.items(), key=lambda kv: abs(kv[1])) if corr else ("", 0.0)
    text = (f"Even a flexible force in the states leaves the model at {after} "
            f"(it explains {explained:.0%} of the excess residual): the missing piece "
            "may not be a force.")
    timing = abs(sig.ccf_peak) > sig.ccf_bound and sig.ccf_lag_s > 0
    if "position" in name and abs(value) > 0.5:
        text += (f" The residual follows the position (r = {value:+.2f}): an error "
                 "proportional to the position suggests the sensor (its scale or zero).")
    elif timing or "rate" in name or "command" in name:
        text += (f" The whitened residual correlates with the command's rate "
                 f"{sig.ccf_lag_s * 1e3:.0f} ms earlier (correlation {sig.ccf_peak:+.2f}): a "
                 "timing problem (a delay or a clock between command and measurement).")
    else:
        text += (" The residual follows no state or rate clearly: suspect the input (the "
                 "pressure acting differs from the command recorded) or the noise model.")
    return text


def _worse(verified: dict | None, rms_before_m: float) -> bool:
    """Whether a proposal's own refit leaves the model no better than without it (its RMS
    error no lower than the diagnosed model's): then it is not advised."""
    return (verified is not None and math.isfinite(rms_before_m)
            and not verified["rms_m"] < rms_before_m)


def _text(states, explained, removed, ratio_after, after, gain, gain_se, proposal, other,
          command, effects, held_out: str = "left-out trials",
          rms_before_m: float = math.nan) -> str:
    needed = [s for s in states if s.needed]
    if not needed and not gain > max(2.0 * gain_se, 2.0):
        return (f"A flexible force in the states does not predict {held_out} better "
                f"(ΔELPD {gain:+.1f} ± {gain_se:.1f}): no discrepancy in the force is found.")
    dep = ", ".join(f"{s.state} (ΔELPD {s.elpd_loss:+.1f} ± {s.se:.1f})" for s in needed) or \
        "no single state"
    # linearised: never called adequate, so never "100%" while above the floor
    text = (f"A flexible force estimated from the data "
            f"{removed_text(removed, explained, ratio_after, False)}"
            + ("" if math.isfinite(ratio_after) else f" (to {after})")
            + f" (linearised; ΔELPD {gain:+.1f} ± {gain_se:.1f}). It depends on {dep}.")
    if proposal is not None:
        text += f" Proposed: {proposal.description} ({proposal.expression})."
        v = proposal.verified
        if v is not None:
            judged = (f" ({'adequate' if v['adequate'] else 'not adequate'})"
                      if math.isfinite(v["ratio"]) else "")
            text += (f" Refitted with it, the model reaches "
                     f"{_level(v['ratio'], v['rms_m'], v['energy'])}{judged}.")
        if _worse(v, rms_before_m):
            rms_v, rms_b = format_together(v["rms_m"] * 1e6, rms_before_m * 1e6)
            # never advise adding what its own refit shows makes the model worse
            text += (f" That is no better than without it (RMS error {rms_v} µm against "
                     f"{rms_b} µm): the linearised estimate does not hold once refitted, so "
                     "it is not advised"
                     + (f"; its file is kept for inspection only ({proposal.plugin})."
                        if proposal.plugin else "."))
        elif proposal.plugin:
            data = command or "DATA"
            names = ",".join([*effects, proposal.effect])
            text += (f" To add it: pmabayes --plugin {proposal.plugin} diagnose {data} "
                     f"--effects {names}")
        elif v is not None:
            text += (" Its effect file was not kept: diagnose again with --proposal-dir DIR "
                     "(plugin_dir in Python) to write it there as a --plugin effect.")
        else:
            text += " It could not be written as an effect."
    if other:
        text += " " + other
    return text
