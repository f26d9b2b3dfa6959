"""The report of a fit: the verdict on the model's fit first, then the parameters, the fit's
quality, convergence and timings, and five figures, on one self-contained page.

The input is a fit as laid out in :mod:`pmabayes.inference.posterior` (an ArviZ 1.x
:class:`xarray.DataTree`, usually read back with :func:`pmabayes.inference.fitfile.load_fit`).
Nothing here simulates or samples: every number and curve comes from the fit file. The
figures are drawn by :mod:`pmabayes.report.figures`.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from pmabayes.criticism.adequacy import Adequacy
from pmabayes.data import Dataset
from pmabayes.inference.fitfile import check_dataset
from pmabayes.inference.search import disagreement_text
from pmabayes.inference.trials import check_trials
from pmabayes.report.fit_data import (
    check_ci_prob,
    check_experiment_data,
    check_tree,
    dataset_from_fit,
    flatten,
    noise_floor,
    opt_float,
    predictive,
    source_name,
    trial_mean_residual,
    units_of,
)
from pmabayes.report.markup import (
    fmt,
    html_figure,
    html_table,
    um,
    write_page,
)
from pmabayes.report.summary import (
    DISPLAY_COLUMNS,
    display_headers,
    map_note,
    summary_table,
    write_summary,
)
from pmabayes.report.verdicts import experiment_adequacy, judge_fit
from pmabayes.util import Progress

__all__ = ["write_report"]


def write_report(
    tree: xr.DataTree,
    out_dir: str | Path,
    *,
    dataset: Dataset | Sequence[Dataset] | None = None,
    ci_prob: float = 0.9,
) -> Path:
    """Write the tables, the figures and a self-contained HTML report of a fit.

    A fit of several experiments gets a section per experiment: its verdict, its
    errors (RMS against the posterior median, the MAP's cost, the noise floor or
    "no repeats", the predictive coverage) and its prediction-against-data and
    residual figures (``ppc_NAME.png``, ``residual_NAME.png``).

    Parameters
    ----------
    tree : xarray.DataTree
        A fit (layout of :mod:`pmabayes.inference.posterior`).
    out_dir : str or Path
        Destination folder, created if needed. Written: ``summary.csv``,
        ``summary.md``, ``trace.png``, ``rank.png``, ``pair.png``, ``ppc.png``,
        ``residual.png`` and ``index.html`` (overwritten if present).
    dataset : Dataset or sequence of Dataset, optional
        The data the fit was made from, one per experiment in the fit's order. When
        given, its trials must equal the fit's observed positions (same shape,
        values within 1e-12 m), and its source names the report.
    ci_prob : float, optional
        Probability of the HDIs in the table and of the central posterior predictive
        band, default 0.9.

    Returns
    -------
    Path
        The path of ``index.html``. The page embeds every figure as a base64 PNG and
        its CSS inline; it loads nothing from the network and has no script.

    Raises
    ------
    ValueError
        If ``dataset`` does not match the fit's observed data, or ``ci_prob`` is not
        in (0, 1).
    TypeError
        If ``dataset`` is not a :class:`~pmabayes.data.Dataset`.
    FitFileError
        If ``tree`` is not a pmabayes fit or lacks a group the report needs.

    Examples
    --------
    >>> from pmabayes import load_fit
    >>> tree = load_fit("results/lab/fit.nc")  # doctest: +SKIP
    >>> write_report(tree, "results/lab/report")  # doctest: +SKIP
    PosixPath('results/lab/report/index.html')
    """
    ci_prob = check_ci_prob(ci_prob)
    info = check_tree(tree, ["posterior", "observed_data", "posterior_predictive"])
    if isinstance(dataset, Sequence) and not isinstance(dataset, str):
        datasets = list(dataset)
        if len(info.get("experiments") or [None]) > 1:
            return _write_experiments_report(tree, info, Path(out_dir), datasets, ci_prob)
        if len(datasets) != 1:
            raise ValueError(f"{len(datasets)} data sets given for a fit of one experiment")
        dataset = datasets[0]
    elif len(info.get("experiments") or [None]) > 1:
        return _write_experiments_report(
            tree, info, Path(out_dir), None if dataset is None else [dataset], ci_prob)
    if dataset is not None:
        check_dataset(tree, dataset)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summary_table(tree, ci_prob=ci_prob)
    pred = predictive(tree, ci_prob)
    adequacy = judge_fit(tree, info, dataset, pred, ci_prob)
    write_summary(rows, out_dir, adequacy=adequacy)
    residual_m, rms_m = trial_mean_residual(pred)
    quality = {"floor_m": noise_floor(info, dataset), "coverage": pred["coverage"],
               "rms_median_m": rms_m}
    captions = _report_figures(tree, rows, pred, residual_m, quality, out_dir, ci_prob)
    body = [
        _meta_block(info, source_name(info, dataset)),
        _adequacy_box(adequacy),
        _trials_line(dataset if dataset is not None else dataset_from_fit(tree, info)),
        _banner(info.get("convergence") or {}),
        _synthetic_note_of(info),
        *_parameter_section(rows, info, ci_prob),
        *_quality_section(info, quality, adequacy, ci_prob),
        *_convergence_section(info, tree),
        *_timings_section(info),
        "<h2>Figures</h2>",
        *[html_figure(out_dir / f"{name}.png", f"{name} plot", text)
          for name, text in captions.items()],
    ]
    return write_page(out_dir, f"pmabayes fit report: {Path(source_name(info, dataset)).name}",
                      body)


def _trials_line(dataset: Dataset) -> str:
    """The verdict of :func:`pmabayes.inference.trials.check_trials` on the fitted trials,
    in one line."""
    check = check_trials(dataset)
    text = html.escape(check.summary())
    return f"<p>{text}</p>" if check.exchangeable else f'<p class="note">{text}</p>'


def _write_experiments_report(tree: xr.DataTree, info: dict, out_dir: Path,
                              datasets: list[Dataset] | None, ci_prob: float) -> Path:
    """:func:`write_report` for a fit of several experiments: shared parameters, then a
    section per experiment."""
    from pmabayes.report import figures as plots
    datasets = check_experiment_data(tree, datasets)
    out_dir.mkdir(parents=True, exist_ok=True)
    flat = flatten(tree)
    rows = summary_table(tree, ci_prob=ci_prob)
    verdicts = experiment_adequacy(tree, datasets=datasets, ci_prob=ci_prob)
    worst = next((a for _, a in verdicts if a.adequate is False), verdicts[0][1])
    write_summary(rows, out_dir, adequacy=worst)
    bar = Progress()
    bar.start(3 + 2 * len(verdicts), "figures", "the report's figures")
    plots.plot_trace(flat, out_dir / "trace.png", units={r["name"]: r["unit"] for r in rows})
    bar.advance()
    plots.plot_rank(flat, out_dir / "rank.png")
    bar.advance()
    n_pair = plots.plot_pair(flat, out_dir / "pair.png", rows)
    bar.advance()
    pct = f"{100 * ci_prob:.4g}%"
    sections = []
    for exp, (name, adequacy) in zip(info["experiments"], verdicts, strict=True):
        pred = predictive(tree, ci_prob, name)
        residual, rms = trial_mean_residual(pred)
        floor = exp.get("noise_floor_m")
        plots.plot_predictive(pred, out_dir / f"ppc_{name}.png", ci_prob=ci_prob)
        bar.advance()
        plots.plot_residual(pred["time"], residual, rms, floor, out_dir / f"residual_{name}.png")
        bar.advance()
        est = exp.get("noise_estimate") or {}
        table = html_table(["quantity", "value"], [
            ["data", str(exp.get("source") or name)],
            ["rig", str((exp.get("rig") or {}).get("name", "?"))],
            ["trials × samples", f"{exp['n_trials']} × {exp['n_samples']}"],
            ["the paper's cost (RMS of trial mean − model) at the MAP",
             um(exp.get("rms_cost_m"))],
            ["RMS of trial mean − posterior median model", um(rms)],
            ["trial-mean noise floor", um(floor) if floor is not None else "no repeats"],
            ["noise (own or tied), learnt from", f"{exp['noise']}, {exp['noise_source']}"],
            ["noise mode: σ, ρ, σ_w", ", ".join(fmt(est.get(k)) for k in
                                                ("sigma_noise_m", "rho_noise", "sigma_white_m"))],
            [f"data inside the {pct} posterior predictive band", f"{100 * pred['coverage']:.1f}%"],
        ])
        sections += [
            f'<h2 id="experiment-{html.escape(name)}">Experiment {html.escape(name)}</h2>',
            _adequacy_box(adequacy), table,
            html_figure(out_dir / f"ppc_{name}.png", f"{name} predictive check",
                 f"{name}: data (black), {pct} predictive band (blue), median model (red)."),
            html_figure(out_dir / f"residual_{name}.png", f"{name} residual",
                 f"{name}: trial-mean residual against the posterior median model (RMS "
                 f"{rms * 1e6:.3g} µm)" + ("; no repeats, so no noise floor." if floor is None
                                           else " and the noise floor (green).")),
        ]
    source = " + ".join(str(e.get("source") or e["name"]) for e in info["experiments"])
    body = [
        _meta_block(info, source),
        *[f"<p><strong>{html.escape(n)}</strong></p>{_adequacy_box(a)}" for n, a in verdicts],
        *_agreement_section(info),
        _banner(info.get("convergence") or {}),
        _synthetic_note_of(info),
        *_parameter_section(rows, info, ci_prob),
        *sections,
        *_convergence_section(info, flat),
        *_timings_section(info),
        "<h2>Figures of the shared posterior</h2>",
        html_figure(out_dir / "trace.png", "trace plot", "Trace of every walker and the pooled "
             "marginal density."),
        html_figure(out_dir / "rank.png", "rank plot", "Fractional-rank Δ-ECDF per walker."),
        html_figure(out_dir / "pair.png", "pair plot",
                    f"Corner plot of {n_pair} evenly spaced draws."),
    ]
    return write_page(out_dir, f"pmabayes fit report: {len(datasets)} experiments", body)


def _report_figures(tree: xr.DataTree, rows: list, pred: Mapping, residual_m: np.ndarray,
                    quality: Mapping, out_dir: Path, ci_prob: float) -> dict[str, str]:
    """Draw the five figures of a fit report; returns each one's caption."""
    from pmabayes.report import figures as plots
    bar = Progress()
    bar.start(5, "figures", "the report's figures")
    trace_note = plots.plot_trace(tree, out_dir / "trace.png",
                                  units={r["name"]: r["unit"] for r in rows})
    bar.advance()
    rank_thin, rank_note = plots.plot_rank(tree, out_dir / "rank.png")
    bar.advance()
    n_pair = plots.plot_pair(tree, out_dir / "pair.png", rows)
    bar.advance()
    plots.plot_predictive(pred, out_dir / "ppc.png", ci_prob=ci_prob)
    bar.advance()
    plots.plot_residual(pred["time"], residual_m, quality["rms_median_m"], quality["floor_m"],
                        out_dir / "residual.png")
    bar.advance()
    post = tree["posterior"]
    n_chain, n_draw = post.sizes["chain"], post.sizes["draw"]
    pct = f"{100 * ci_prob:.4g}%"
    return {
        "trace": (
            f"Trace of every walker ({n_chain} chains × {n_draw} draws after burn-in and "
            "thinning) and the pooled marginal density."
            + (f" {trace_note}" if trace_note else "")
        ),
        "rank": (
            "Fractional-rank Δ-ECDF per walker (ArviZ multi-chain test); curves should "
            "overlap around zero"
            + (f", draws thinned by {rank_thin} for the test." if rank_thin > 1 else ".")
            + (f" {rank_note}" if rank_note else "")
        ),
        "pair": (
            f"Corner plot of {n_pair} evenly spaced draws: MAP (black ×, solid line)"
            + (", paper value (red ○, dashed line; an arrow-head at the edge when off scale)."
               if any(r.get("paper") is not None for r in rows)
               else " (an arrow-head at the edge when off scale).")
        ),
        "ppc": (
            f"Posterior predictive check: data (black), {pct} predictive band pooled over "
            "draws and trials (blue), median model (red); right: the fast end of the run; "
            "bottom: the same on the residual scale."
        ),
        "residual": (
            f"Trial-mean residual against the posterior median model (RMS "
            f"{quality['rms_median_m'] * 1e6:.3g} µm) and the trial-mean noise floor (green)."
        ),
    }


def _adequacy_box(adequacy: Adequacy) -> str:
    """The verdict on the model's fit, first on the page."""
    cls = {True: "ok", False: "bad", None: "unknown"}[adequacy.adequate]
    out = [f'<div class="verdict {cls}" id="adequacy"><strong>{html.escape(adequacy.headline)}'
           f"</strong>: {html.escape(adequacy.evidence())}."]
    out += [f"<p>{html.escape(line)}</p>" for line in adequacy.advice()]
    if adequacy.next_step:
        out.append(f'<p class="next">Next: <code>{html.escape(adequacy.next_step)}</code> '
                   "finds what the model is missing.</p>")
    return "".join(out) + "</div>"


def _agreement_section(info: dict) -> list[str]:
    """Whether the experiments agree on one parameter set
    (:func:`~pmabayes.inference.search.experiments_agreement`), with each one's RMS cost
    alone and at the joint MAP; nothing for a fit that did not test it."""
    agreement = (info.get("map") or {}).get("agreement")
    if not agreement:
        return []
    text = disagreement_text(agreement)
    p = agreement.get("p_value")
    test = (f"likelihood ratio {agreement['statistic']:.3g} on {agreement['df']} degrees of "
            f"freedom, p = {p:.2g}" if p is not None else "no parameter beyond the joint's")
    if text:
        reason = text.split(": ", 1)[1] if text.startswith("the experiments disagree: ") \
            else text
        box = (f'<div class="verdict bad" id="agreement"><strong>THE EXPERIMENTS DISAGREE'
               f"</strong>: {html.escape(reason)}.</div>")
    else:
        box = ('<div class="verdict ok" id="agreement"><strong>The experiments agree on one '
               f"parameter set</strong> ({html.escape(test)}; MAP from the "
               f"{html.escape(str(agreement.get('start', 'joint search')))}).</div>")
    rows = [[name, um(e.get("rms_cost_own_m")), um(e.get("rms_cost_joint_m"))]
            for name, e in (agreement.get("experiments") or {}).items()]
    return ["<h2>Do the experiments agree?</h2>", box,
            html_table(["experiment", "RMS cost, its own MAP", "RMS cost, the joint MAP"], rows)]


def _synthetic_note_of(info: dict) -> str:
    if not (info.get("data") or {}).get("synthetic"):
        return ""
    return ('<p class="note"><strong>Synthetic data.</strong> These measurements were '
            "simulated, not measured on hardware; the estimates say nothing about a "
            "real actuator.</p>")


def _parameter_section(rows: list, info: dict, ci_prob: float) -> list[str]:
    pct = f"{100 * ci_prob:.4g}%"
    out = [f"<h2>Parameters</h2><p>Posterior mean, sd and {pct} highest density "
           "interval over all walkers; R-hat is ArviZ's rank-normalised split R-hat "
           "over walkers; ESS (tau) is the autocorrelation-time ESS used for the "
           "convergence decision.</p>",
           html_table(display_headers(rows),
                      [[r["name"], r.get("unit") or "\u2014"]
                       + [r.get(k) for k, _ in DISPLAY_COLUMNS[2:]] for r in rows],
                      num_from=2)]
    if map_note(rows):
        out.append(f'<p class="note">{html.escape(map_note(rows))}</p>')
    fixed = (info.get("model") or {}).get("fixed") or {}
    if fixed:
        units = units_of(info)
        out.append("<p>Fixed: " + ", ".join(
            f"<code>{html.escape(k)}</code> = {html.escape(fmt(v))} "
            f"{html.escape(units.get(k, ''))}" for k, v in fixed.items()) + "</p>")
    return out


def _quality_section(info: dict, quality: Mapping, adequacy: Adequacy,
                     ci_prob: float) -> list[str]:
    point = info.get("map") or {}
    gs = point.get("global_search") or {}
    floor = quality["floor_m"]
    map_cost = opt_float(point, "rms_cost_m")
    ratio = (f"{map_cost / floor:.3g}"
             if map_cost is not None and floor and math.isfinite(floor) else None)
    verdict = {True: "yes", False: "NO", None: "unknown (no noise estimate)"}
    rows = [
        ["the paper's cost (RMS of trial mean − model) at the MAP", um(map_cost)],
        ["trial-mean noise floor (a perfect model's RMS cost)", um(floor)],
        ["MAP cost / noise floor", ratio],
        ["the paper's cost at the paper-style global search optimum",
         um(opt_float(gs, "rms_cost_m"))],
        ["RMS of trial mean − posterior median model", um(quality["rms_median_m"])],
        [f"data inside the {100 * ci_prob:.4g}% posterior predictive band",
         f"{100 * quality['coverage']:.1f}%"],
        ["whitened residual energy (1 for pure noise)", adequacy.energy],
        ["Ljung-Box p of the whitened residual", adequacy.ljung_box_p],
        ["model adequate (energy ≤ "
         f"{1 + adequacy.energy_tolerance:g}, Ljung-Box p ≥ {adequacy.level_adequate:g})",
         verdict[adequacy.adequate]],
        ["log posterior at the MAP", opt_float(point, "log_posterior")],
    ]
    return ["<h2>Fit quality</h2>", html_table(["quantity", "value"], rows)]


def _convergence_section(info: dict, tree: xr.DataTree) -> list[str]:
    conv = info.get("convergence") or {}
    post = tree["posterior"]
    settings = html_table(["setting", "value"], [
        ["independent ensembles", conv.get("n_ensembles")],
        ["walkers per ensemble", conv.get("n_walkers")],
        ["steps per ensemble", conv.get("n_steps")],
        ["burn-in (steps)", conv.get("burn")],
        ["thin", conv.get("thin")],
        ["chains × draws kept", f"{post.sizes['chain']} × {post.sizes['draw']}"],
        ["required steps / tau (tau multiple)", conv.get("tau_multiple")],
        ["required ESS (min ESS)", conv.get("min_ess")],
    ])
    per_parameter = html_table(
        ["parameter", "tau [steps]", "ESS (tau)", "R-hat (fit)", "R-hat (ensembles)"],
        [[n, opt_float(conv.get("tau"), n), opt_float(conv.get("ess"), n),
          opt_float(conv.get("rhat"), n), opt_float(conv.get("rhat_ensembles"), n)]
         for n in post.data_vars],
    )
    return ["<h2>Convergence</h2>", settings, per_parameter]


def _timings_section(info: dict) -> list[str]:
    timings = info.get("timings_s") or {}
    if not timings:
        return []
    return ["<h2>Timings</h2>",
            html_table(["stage", "time [s]"], [[k, v] for k, v in timings.items()])]


def _meta_block(info: dict, source: str) -> str:
    d = info.get("data") or {}
    m = info.get("model") or {}
    noise = (info.get("noise") or {}).get("model")
    items = [
        f"data: <code>{html.escape(source)}</code>",
        f"{d.get('n_trials', '?')} trials × {d.get('n_samples', '?')} samples"
        + (f" at {1.0 / d['dt_s']:.4g} Hz" if d.get("dt_s") else ""),
        f"input: {html.escape(str(d.get('input_name', '?')))}",
        "effects: " + html.escape(", ".join(m.get("effects") or []) or "none"),
    ]
    if noise:
        items.append(f"noise: {html.escape(str(noise))}")
    items.append(f"pmabayes {html.escape(str(info.get('pmabayes_version', '?')))}, "
                 f"seed {html.escape(str(info.get('seed')))}")
    return '<p class="meta">' + " · ".join(items) + "</p>"


def _banner(conv: Mapping) -> str:
    messages = [str(m) for m in conv.get("messages") or []]
    listed = "".join(f"<li>{html.escape(m)}</li>" for m in messages)
    listed = f"<ul>{listed}</ul>" if listed else ""
    if conv.get("converged") is True:
        return (f'<div class="banner ok">Sampling converged: the posterior of this model is '
                "well sampled. Whether the model fits the data is the verdict above."
                f"{listed}</div>")
    return (
        '<div class="banner bad" id="not-converged"><strong>NOT CONVERGED.</strong> '
        "The sampler did not meet its convergence criteria; the intervals below are not "
        f"reliable.{listed}</div>"
    )
