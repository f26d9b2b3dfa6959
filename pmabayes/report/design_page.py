"""The page of a design: the chosen experiment, every candidate experiment's score, and
the candidates' predicted responses to the chosen input."""

from __future__ import annotations

import html
import math
from pathlib import Path

from pmabayes.design.files import write_design_files
from pmabayes.report.markup import html_figure, html_table, write_page

__all__ = ["write_design"]


def write_design(result, out_dir: str | Path) -> Path:
    """Write a design's files (``next.csv``, ``next.json``, ``design.json``:
    :func:`pmabayes.design.files.write_design_files`), its figure and ``index.html``.

    Parameters
    ----------
    result : DesignResult
        The result of :func:`pmabayes.design.api.design`.
    out_dir : str or Path
        Destination folder, created if needed (a command stages it:
        :func:`pmabayes.outputs.staged`).

    Returns
    -------
    Path
        The path of ``index.html`` (self-contained: the figure embedded, no script).
    """
    from pmabayes.report.figures.design import plot_design

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_design_files(result, out_dir)
    png = out_dir / "design.png"
    plot_design(result, path=png)
    s = result.settings
    discriminate = result.goal == "discriminate"
    aim = (f"tell apart {', '.join(result.candidates)}" if discriminate else
           f"shrink the 90% intervals of {', '.join(s['parameters'])} "
           f"(model {result.candidates[0]})")
    body = [
        f'<p class="meta">goal: {html.escape(aim)} · {len(result.experiments)} candidate '
        f"experiments · {s['n_draws']} posterior draws per model · {s['n_trials']} trials · "
        f"input range {s['input_range'][0]:.6g} to {s['input_range'][1]:.6g} (SI) · seed "
        f"{html.escape(str(s['seed']))} · {result.seconds:.1f} s</p>",
        f"<p><strong>Next experiment:</strong> {html.escape(result.experiment.label())}; "
        f"its input is <code>next.csv</code> (columns and rig in <code>next.json</code>). "
        f"{html.escape(_score_words(result))}</p>",
        "<p>" + html.escape(_method_words(discriminate)) + "</p>",
    ]
    for name, why in result.left_out.items():
        body.append(f'<p class="note">{html.escape(name)} was left out: {html.escape(why)}</p>')
    for note in result.notes:
        body.append(f'<p class="note">Note: {html.escape(note)}</p>')
    body.append(html_figure(png, "predicted responses to the chosen input",
                            "Top: the chosen input. Middle: each candidate's response at its "
                            "MAP, with the 5%-95% band of its posterior draws. Bottom: each "
                            "MAP response less the first candidate's: where they differ."))
    head = (["#", "experiment", "score", "MC se", "true model named", "named MC se",
             "named beyond 2 se", "MC se"]
            if discriminate else ["#", "experiment", "log shrinkage", "MC se",
                                  "shrinkage factor"])
    rows = []
    order = sorted(range(len(result.experiments)),
                   key=lambda i: -result.scores[i]["score"]
                   if math.isfinite(result.scores[i]["score"]) else math.inf)
    for i in order:
        sc, e = result.scores[i], result.experiments[i]
        label = e.label() + (" (chosen)" if i == result.chosen else "")
        if discriminate:
            rows.append([i, label, sc["score"], sc["mc_se"], sc.get("named_rate"),
                         sc.get("named_rate_mc_se"), sc.get("named_decisively_rate"),
                         sc.get("named_decisively_mc_se")])
        else:
            rows.append([i, label, sc["score"], sc["mc_se"], sc.get("factor")])
    body.append("<h2>Every candidate experiment</h2>")
    body.append(html_table(head, rows, num_from=2))
    return write_page(out_dir, "pmabayes design: the next experiment", body)


def _score_words(result) -> str:
    """The chosen experiment's score beside repeating the first input's (the notes and
    the candidates left out have their own paragraphs)."""
    return " ".join(line for line in result.lines()[1:]
                    if not line.startswith(("  note: ", "  left out ")))


def _method_words(discriminate: bool) -> str:
    if discriminate:
        return ("Score: the expected log Bayes factor of the true candidate over the strongest "
                "other one, by Monte Carlo over the true model, a posterior draw of it and "
                "the fitted noise; each model's predictive density of the new trial mean is "
                "Gaussian, its draws' spread added to the noise (Box and Hill's criterion). "
                "'True model named': the expected rate at which the true candidate has the "
                "highest predictive density; 'beyond 2 se': the rate at which its sum of "
                "per-trial differences from every other exceeds two of their standard "
                "errors, as pmabayes diagnose names a candidate. MC se: the Monte Carlo "
                "standard error.")
    return ("Score: the mean log factor by which the experiment is expected to shrink the "
            "parameters' 90% intervals (in the fit's unconstrained coordinates), from the "
            "Laplace covariance of the data so far and the experiment's Fisher information "
            "at posterior draws; MC se over the draws.")
