"""The page of a validation: predictions of held-out experiments against their data."""

from __future__ import annotations

import html
from pathlib import Path

from pmabayes.criticism.yardsticks import REGISTRY
from pmabayes.report.markup import (
    BAND_HEADER,
    band_rows,
    html_figure,
    html_table,
    result_folder,
    write_page,
)

__all__ = ["write_validation"]


def write_validation(validation, out_dir: str | Path) -> Path:
    """Write the figures, ``validation.json`` and an HTML page of a validation.

    Parameters
    ----------
    validation : pmabayes.criticism.validation.Validation
        The result of :func:`pmabayes.criticism.validation.validate`.
    out_dir : str or Path
        Destination folder, created if needed. Written: one
        ``validation_<i>_<name>.png`` per experiment, ``validation.json`` and
        ``index.html``.

    Returns
    -------
    Path
        The path of ``index.html`` (self-contained: figures embedded, no script).
    """
    from pmabayes.report import figures as plots
    v = validation
    out_dir = result_folder(out_dir, "validation.json", v.to_dict())
    settings = v.settings
    pct = f"{100 * settings['ci_prob']:.4g}%"
    model = " + ".join(["base", *v.effects])
    # the yardsticks fitted (linear, play, narx where the records are long enough)
    yards = [n for n in REGISTRY if any(n in e.baselines for e in v.experiments)]
    body = [
        f'<p class="meta">fit: <code>{html.escape(str(v.fit_source or "(in memory)"))}</code>'
        f" · model: {html.escape(model)} · {len(v.experiments)} held-out experiment(s) · "
        f"{settings['n_draws']} posterior draws each · seed {html.escape(str(settings['seed']))}"
        "</p>",
    ]
    if any(e.synthetic for e in v.experiments):
        body.append('<p class="note"><strong>Synthetic data.</strong> Experiments marked '
                    "synthetic were simulated, not measured on hardware.</p>")
    body += [
        f"<p>Each experiment is simulated on its own rig with posterior draws of the fit. The "
        f"{pct} predictive band is the model's prediction plus the fit's noise (AR(1) "
        "disturbance and white sensor noise drawn from the fit's noise posterior), not the "
        "held-out data's own noise. RMSE: RMS of the trial mean minus the posterior-mean "
        "prediction. NRMSE: RMSE over the RMS of the trial mean's variation about its own "
        "mean. Noise floor: the error a perfect model would have, from the spread between "
        "repeated trials (none with one trial). Coverage: the share of all measured "
        f"samples inside the {pct} band (about {pct} for a model and noise that describe "
        "the data). The model-only band holds the parameters' uncertainty alone: what "
        "counts for noiseless held-out data.</p>",
        f"<p>{html.escape(_discrepancy_words(v, pct))} {html.escape(_yardstick_words(v))}"
        "</p>",
        html_table(["experiment", "rig", "noise from", "trials", "samples", "RMSE [µm]",
                "noise floor [µm]", "RMSE / floor", "NRMSE",
                *(f"NRMSE {n} yardstick" for n in yards), f"inside the {pct} band",
                f"inside the {pct} band with the discrepancy",
                "trial mean inside the model-only band"],
               [[e.name, e.rig.get("name"), e.noise["from"], e.n_trials, e.n_samples,
                 e.rmse_m * 1e6, None if e.noise_floor_m is None else e.noise_floor_m * 1e6,
                 e.ratio_to_floor, e.nrmse,
                 *(e.baselines[n]["nrmse"] if n in e.baselines else None for n in yards),
                 f"{100 * e.band_coverage:.1f}%",
                 "—" if e.coverage is None else f"{100 * e.coverage:.1f}%",
                 f"{100 * e.model_band_coverage:.1f}%"]
                for e in v.experiments], num_from=3),
    ]
    for i, e in enumerate(v.experiments):
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in e.name)
        png = out_dir / f"validation_{i}_{safe}.png"
        plots.plot_validation(e, path=png)
        src = f" (<code>{html.escape(e.source)}</code>)" if e.source else ""
        body.append(f"<h2>{html.escape(e.name)}{src}</h2>")
        body.append(f"<p>{html.escape(e.summary())}.</p>")
        for note in e.notes:
            body.append(f'<p class="note">{html.escape(note)}</p>')
        if e.band_errors:
            body.append(html_table(BAND_HEADER, band_rows(e.band_errors)))
        body.append(html_figure(png, f"validation of {e.name}",
                         f"{e.name}: measured trials (grey), the {pct} predictive band "
                         "(blue), the band with the model's discrepancy (light blue), the "
                         "posterior-mean prediction (red) and the yardsticks' predictions "
                         "(dotted: linear output-error green, Prandtl-Ishlinskii purple, "
                         "polynomial NARX orange); "
                         "bottom: the same less the prediction, with the trial mean "
                         "(black)."))
    return write_page(out_dir, "pmabayes validation on held-out experiments", body)


def _discrepancy_words(v, pct: str) -> str:
    """What the discrepancy band adds, in one or two sentences."""
    d = v.discrepancy
    if d is None:
        return "The model's discrepancy could not be learnt from the training data."
    if not d.significant:
        return (f"The training residual ({d.residual_rms_m * 1e6:.3g} µm RMS) is consistent "
                f"with the fit's noise ({d.noise_rms_m * 1e6:.3g} µm for the trial mean): no "
                f"discrepancy is added, and the {pct} band with it is the predictive band.")
    return (f"The model's discrepancy, learnt from the training residual beyond the fit's "
            f"noise (Kennedy and O'Hagan; a stationary process of {d.sigma_m * 1e6:.3g} µm "
            f"RMS with a correlation time of {d.corr_time_s:.3g} s), is added to the draws "
            f"to make the {pct} band with the discrepancy: the band that still means what "
            "it says when the model is wrong, as long as the held-out input is of the "
            "training input's kind.")


def _yardstick_words(v) -> str:
    """What the yardsticks are and where they were fitted."""
    b = v.baselines
    if b is None:
        return "The yardsticks could not be fitted to the training data."
    fitted = [REGISTRY[n].describe(f.to_dict()) for n, f in b.fitted.items()]
    left = "".join(f" The {n} yardstick was left out: {reason.split(': ', 1)[-1]}."
                   for n, reason in b.left_out.items())
    if not fitted:
        return "No yardstick could be fitted to the training data." + left
    return (f"The yardsticks, fitted to the fit's training data in {b.seconds:.2g} s: "
            + ", ".join(fitted[:-1]) + (" and " if len(fitted) > 1 else "") + fitted[-1]
            + "; a physics model that predicts no better than they do has not earned its "
            "parameters." + left)
