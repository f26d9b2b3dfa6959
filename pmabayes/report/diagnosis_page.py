"""The page of a diagnosis: its verdict, each experiment's errors, signature and figures,
the candidates, and the discrepancy.
"""

from __future__ import annotations

import html
from pathlib import Path

from pmabayes.criticism.prose import PARAGRAPH_BREAK, elpd_short
from pmabayes.report.markup import (
    BAND_HEADER,
    band_rows,
    fmt,
    html_figure,
    html_table,
    result_folder,
    synthetic_note,
    write_page,
)

__all__ = ["write_diagnosis"]


def write_diagnosis(diagnosis, out_dir: str | Path) -> Path:
    """Write the figures, ``diagnosis.json`` and an HTML page of a diagnosis.

    Parameters
    ----------
    diagnosis : pmabayes.criticism.results.Diagnosis
        The result of :func:`pmabayes.criticism.diagnosis.diagnose`.
    out_dir : str or Path
        Destination folder, created if needed. Written: ``comparison.png``,
        ``bands.png``, ``signature.png``, ``whiteness.png``, ``ranking.png``,
        ``discrepancy.png`` (when the diagnosis has a discrepancy), ``diagnosis.json``
        (:meth:`~pmabayes.criticism.results.Diagnosis.to_dict`) and ``index.html``.
        For several experiments the first four are per experiment
        (``comparison_NAME.png``, ...), and the page has a section per experiment
        (``id="experiment-NAME"``).

    Returns
    -------
    Path
        The path of ``index.html`` (self-contained: figures embedded).
    """
    d = diagnosis
    out_dir = result_folder(out_dir, "diagnosis.json", d.to_dict())
    exps = list(d.experiments)
    several = len(exps) > 1
    label = " + ".join(["base", *d.effects])
    cls = "ok" if d.adequate and d.missing is None else "bad"
    body = [
        f'<p class="meta">{_meta(exps)} · model: {html.escape(label)} · '
        f"seed {html.escape(str(d.settings.get('seed')))}</p>",
        *dict.fromkeys(synthetic_note(e.dataset) for e in exps),
        f'<div class="banner {cls}">'
        + "".join(f"<p>{html.escape(part)}</p>" for part in d.verdict.split(PARAGRAPH_BREAK))
        + "</div>",
    ]
    figs: dict[str, str] = {}
    for e in exps:
        suffix = f"_{e.name}" if several else ""
        figs.update(_experiment_figures(e, label, out_dir, suffix))
        if several:
            body.append(f'<h2 id="experiment-{html.escape(e.name)}">Experiment '
                        f"{html.escape(e.name)}: <code>{html.escape(e.dataset.source or '')}"
                        f"</code> (adequate: {'yes' if e.adequate else 'no'})</h2>")
        body += _diagnosis_experiment_section(e, several)
        if several:
            for name in ("comparison", "bands", "signature", "whiteness"):
                body.append(html_figure(out_dir / f"{name}{suffix}.png",
                                        f"{name} plot of {e.name}",
                                        figs.pop(f"{name}{suffix}")))
    figs.update(_diagnosis_figures(d, out_dir, several))
    body += _ranking_section(d, several)
    if d.discrepancy is not None:
        body += _discrepancy_section(d.discrepancy)
    body.append("<h2>Figures</h2>")
    for name, caption in figs.items():
        body.append(html_figure(out_dir / f"{name}.png", f"{name} plot", caption))
    title = " + ".join(Path(e.dataset.source or "(in memory)").name for e in exps)
    return write_page(out_dir, f"pmabayes diagnosis: {title}", body)


def _meta(exps: list) -> str:
    """The data line of the page: the file, or each experiment's with its rig."""
    sources = [e.dataset.source or "(in memory)" for e in exps]
    if len(exps) > 1:
        return (f"{len(exps)} experiments: "
                + ", ".join(f"<code>{html.escape(src)}</code> ({e.dataset.n_trials} trial(s) × "
                            f"{e.dataset.n_samples} samples, rig {html.escape(e.model.rig.name)})"
                            for src, e in zip(sources, exps, strict=True)))
    ds = exps[0].dataset
    return (f"data: <code>{html.escape(sources[0])}</code> · {ds.n_trials} trials × "
            f"{ds.n_samples} samples")


def _diagnosis_figures(d, out_dir: Path, several: bool) -> dict[str, str]:
    """Draw the ranking figure (and the discrepancy's); returns each one's caption."""
    from pmabayes.report import figures as plots

    fig = plots.plot_ranking(d.ranking, threshold=d.score_threshold, level=d.settings["level"])
    fig.savefig(out_dir / "ranking.png", dpi=plots.REPORT_DPI)
    figs = {"ranking": ("Score-test evidence that each candidate effect is missing (red: "
                        "significant)" + (", all experiments together" if several else "")
                        + ".")}
    if d.discrepancy is not None:
        fig = plots.plot_discrepancy(d.discrepancy)
        fig.savefig(out_dir / "discrepancy.png", dpi=plots.REPORT_DPI)
        figs["discrepancy"] = ("The missing force estimated from the data"
                               + (f" of experiment {d.discrepancy_experiment}" if several
                                  else "")
                               + ": its partial dependence on each state (centred; band: two "
                               "posterior sd), red where dropping the state loses predictive "
                               "accuracy.")
    return figs


def _ranking_section(d, several: bool) -> list[str]:
    """The candidates' table, and the explanation of each significant one."""
    out = [
        "<h2>What is missing: the candidate effects</h2>",
        "<p>Refitted candidates first (by leave-one-trial-out ELPD"
        + (", over every trial of every experiment" if several else "")
        + "), then the others by score statistic"
        + (" (the experiments' scores and informations summed)" if several else "")
        + ". The excess removed is that of the whitened residual's energy over pure noise "
        "(the rule's measure; first order for candidates not refitted) and that of the "
        "mean-square error over the noise floor (refits, with a floor). Estimates and "
        "intervals of refitted candidates come from the "
        f"refit's MAP and Laplace draws ({d.settings['ci_prob']:.0%} intervals); the others "
        "are the score test's one-step values. A candidate that cannot act on these "
        "data is left out of the score tests (its reason below the table); an estimate "
        "outside its plausible range is marked implausible, not a finding.</p>",
        html_table(["effect", "evidence", "p", "significant", "estimate", "interval",
                    "excess energy removed", "excess mean square removed", "ΔELPD ± se"],
                   [[f.effect + (" (left out)" if f.left_out else ""),
                     None if f.left_out else f.evidence, None if f.left_out else f.p_value,
                     "yes" if f.significant else "no",
                     ", ".join(f"{k} = {fmt(v)}" for k, v in f.estimate.items())
                     + (" (implausible)" if f.implausible else ""),
                     ", ".join(f"{fmt(a)} to {fmt(b)}" for a, b in f.interval.values()),
                     f"{f.explained:.0%}",
                     "—" if f.refit is None or f.refit.explained_rms is None
                     else f"{f.refit.explained_rms:.0%}",
                     elpd_short(f.refit) if f.refit else "—"]
                    for f in d.ranking], num_from=1),
    ]
    return out + [f"<h3>{html.escape(f.effect)}</h3><p>{html.escape(f.explanation)}</p>"
                  for f in d.ranking if f.significant or f.left_out]


def _discrepancy_section(disc) -> list[str]:
    """The discrepancy's states, evidence and proposal, for the diagnosis page."""
    out = ["<h2>Beyond the library: the missing force estimated from the data</h2>",
           f"<p>{html.escape(disc.text)}</p>",
           html_table(["state", "ΔELPD if dropped ± se", "force amplitude [N]", "needed"],
                      [[s.state, f"{s.elpd_loss:+.1f} ± {s.se:.1f}", s.amplitude_n,
                        "yes" if s.needed else "no"] for s in disc.states], num_from=2)]
    if disc.proposal is not None:
        pr = disc.proposal
        out.append(f"<p>Proposed ({html.escape(pr.kind)}): <code>{html.escape(pr.expression)}"
                   f"</code>; ΔELPD against the flexible estimate {pr.elpd_diff:+.1f} ± "
                   f"{pr.elpd_diff_se:.1f}. Plugin: "
                   + (f"<code>{html.escape(str(pr.plugin))}</code>" if pr.plugin else
                      "not kept (diagnose with --proposal-dir DIR to keep it)") + "</p>")
    return out


def _diagnosis_experiment_section(e, several: bool) -> list[str]:
    """One experiment's error table, whiteness and signature (h2 for one experiment,
    h3 under its heading for several)."""
    sig = e.signature
    h = "h3" if several else "h2"
    note = e.floor_note()
    return [
        f"<{h}>Compare: error against the noise floor</{h}>",
        html_table(BAND_HEADER, band_rows(sig.bands)),
        (f"<p>{html.escape(note)}.</p>" if note else ""),
        f"<p>Whitened residual: energy {sig.energy:.4g} (1 for pure noise, p = "
        f"{sig.energy_p:.2g}); Ljung-Box p = {sig.ljung_box_p:.2g}. "
        f"Adequate: <strong>{'yes' if e.adequate else 'no'}</strong>.</p>",
        f"<{h}>See where it fails</{h}>", f"<p>{html.escape(sig.describe())}</p>",
    ]


def _experiment_figures(e, label: str, out_dir: Path, suffix: str = "") -> dict[str, str]:
    """Draw an experiment's four figures of a diagnosis (``NAME{suffix}.png``); returns each
    one's caption."""
    from pmabayes.report import figures as plots
    ds = e.dataset
    figs = {
        "comparison": (plots.plot_comparison(ds, e.simulation.position_m[0],
                                             label=f"{label} (MAP)"),
                       "Trials, their mean and the model at its MAP; the residual beside the "
                       "noise floor; the hysteresis loop."),
        "bands": (plots.plot_band_errors({label: e.signature.bands}),
                  "RMS error of the trial mean per frequency band (octaves over the band the "
                  "input excites, from the residual's spectrum; the bands' mean squares add "
                  "up to the total), with the noise floor (black): the error a perfect model "
                  "would have, from the spectrum of the deviations between the trials."),
        "signature": (plots.plot_residual_signature(ds, e.simulation, e.frequency_hz,
                                                    label=label, floor_m=e.noise_floor_m),
                      "Where the model fails: the residual against time, frequency, velocity, "
                      "pressure and position."),
        "whiteness": (plots.plot_whiteness(e.whiteness_curves()),
                      "Whiteness and independence tests: the residual whitened by the noise "
                      "model should stay inside the bounds at almost every lag."),
    }
    for name, (fig, _) in figs.items():
        fig.savefig(out_dir / f"{name}{suffix}.png", dpi=plots.REPORT_DPI)
    return {f"{name}{suffix}": caption for name, (_, caption) in figs.items()}
