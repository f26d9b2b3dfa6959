"""The model-criticism case study on the lab-like data: base, + one effect, + two effects.

``data/pma_chirp_lab.csv`` is synthetic and hides a 45 ms regulator lag and 0.8 N of
Coulomb friction that the base model lacks. Three steps, each a
``pmabayes.criticism.diagnosis.diagnose`` of the model so far (what is missing, from the
residual's signature, the score test and refits), then a full posterior fit of each
model (``pmabayes.inference.sampler.fit``) compared side by side
(``pmabayes.criticism.compare.compare_fits``: error per frequency band against the noise
floor, whiteness, leave-one-trial-out ELPD). The base model is not told what to
add: each step adds the effect that the previous diagnosis named missing, and the
script stops when a diagnosis names nothing.

Usage::

    python analyses/paper/paper_criticism.py [--out-root paper] [--quick] [--seed 1]

Writes ``figures/criticism_bands.png`` (error per band for every step),
``figures/criticism_signature_<k>.png`` (the residual signature of step ``k`` that
led to the next), ``figures/criticism_ranking_<k>.png``, ``figures/criticism_whiteness.png``,
``tables/criticism.tex`` and ``tables/numbers_criticism.tex``; prints the band
figure's path last. The final fit (``fits/lab_final*.nc``) is the one the robustness
sweep uses.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time

import arviz as az
from _paper import (
    ROUND_ONE_EFFECTS,
    Numbers,
    cached_fit,
    lab_dataset,
    out_dirs,
    parser,
    pval,
    sig,
    symbol,
    tex_escape,
)

from pmabayes.criticism.compare import compare_fits
from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.inference.fitfile import fit_info
from pmabayes.report.figures import (
    plot_band_errors,
    plot_ranking,
    plot_residual_signature,
    plot_whiteness,
    plt,
)

#: at most this many effects are added (the library could in principle keep going)
MAX_STEPS = 3
#: how each parameter of an effect is shown: unit, factor from SI, digits (the symbol
#: is the parameter's own, Parameter.latex)
SHOWN = {"tau_reg": ("ms", 1e3, 4), "F_c": ("N", 1.0, 3), "t_delay": ("ms", 1e3, 3),
         "x_offset": ("µm", 1e6, 3), "K3": ("N/m³", 1.0, 3), "K_p": ("N/(m Pa)", 1.0, 3)}
WORDS = ("Zero", "One", "Two", "Three")
#: quick mode: one refit per step and fewer Laplace draws (the defaults are 3 and 400)
QUICK_DIAGNOSE = {"max_refits": 1, "n_draws": 100}


def _band(band_hz: tuple[float, float]) -> str:
    lo, hi = band_hz
    return f"{lo:g}--{hi:g}~Hz" if math.isfinite(hi) else f"above {lo:g}~Hz"


def _label(effects: list[str]) -> str:
    return " + ".join(["base", *effects])


def _estimate_text(finding) -> str:
    parts = []
    for name, value in finding.estimate.items():
        if name not in SHOWN or name not in finding.interval:
            continue
        unit, k, digits = SHOWN[name]
        lo, hi = finding.interval[name]
        parts.append(f"${symbol(name)} = {sig(value * k, digits)}$ {tex_escape(unit)} "
                     f"[{sig(lo * k, digits)}, {sig(hi * k, digits)}]")
    return "; ".join(parts)


def main(argv: list[str] | None = None) -> int:
    """Run the diagnoses and fits, write figures, table and numbers."""
    args = parser(__doc__).parse_args(argv)
    figures, tables = out_dirs(args.out_root)
    ds = lab_dataset(args.quick)
    nums = Numbers("criticism", args.quick)

    effects: list[str] = []
    diagnoses = []
    for k in range(MAX_STEPS + 1):
        start = time.perf_counter()
        with tempfile.TemporaryDirectory() as folder:  # a proposal, if any, not in cwd
            settings = DiagnoseSettings(candidates=ROUND_ONE_EFFECTS,
                                        **QUICK_DIAGNOSE if args.quick else {})
            d = diagnose(ds, effects=effects, settings=settings, seed=args.seed,
                         plugin_dir=folder)
        secs = time.perf_counter() - start
        first = d.experiments[0]  # the one data set
        diagnoses.append((list(effects), d))
        print(f"step {k} ({_label(effects)}): RMS {d.rms_m * 1e6:.3g} um = "
              f"{first.signature.ratio:.3g}x floor, missing {d.missing}, adequate {d.adequate}, "
              f"{secs:.0f} s", flush=True)
        if d.missing is None or k == MAX_STEPS:
            break
        plt.close(plot_residual_signature(ds, first.simulation, first.frequency_hz,
                                          label=_label(effects),
                                          path=figures / f"criticism_signature_{k}.png"))
        plt.close(plot_ranking(d.ranking, threshold=d.score_threshold,
                               path=figures / f"criticism_ranking_{k}.png"))
        effects = [*effects, d.missing]

    trees, labels = [], []
    for k, (eff, _) in enumerate(diagnoses):
        key = "lab_final" if k == len(diagnoses) - 1 else f"lab_step{k}"
        tree, secs = cached_fit(args.out_root, key, ds, eff, quick=args.quick, seed=args.seed)
        trees.append(tree)
        labels.append(_label(eff))
        print(f"fit {labels[-1]}: " + ("cached" if secs is None else f"{secs:.0f} s"),
              flush=True)
    comp = compare_fits(trees, ds, labels=labels)
    band_path = figures / "criticism_bands.png"
    plt.close(plot_band_errors(comp.bands, path=band_path))
    plt.close(plot_whiteness(comp.whiteness_curves(), path=figures / "criticism_whiteness.png"))

    # the table: one row per step, from the diagnosis (MAP) and the full fit
    head = (r"\begin{tabular}{lrrrl}" "\n" r"\toprule" "\n"
            r"model & RMS [\textmu m] & / floor & LB $p$ & diagnosis: missing (estimate "
            r"[90\% int.]) \\" "\n" r"\midrule")
    body = []
    for k, (_eff, d) in enumerate(diagnoses):
        label = labels[k]
        b = comp.bands[label]
        lb = comp.whiteness[label]["ljung_box_p"]
        if d.missing is None:
            says = "adequate" if d.adequate else "above the floor, nothing named"
        else:
            finding = next(f for f in d.ranking if f.effect == d.missing)
            says = tex_escape(d.missing) + " (" + _estimate_text(finding) + ")"
        body.append(f"{tex_escape(label)} & {sig(b[-1].rms_m * 1e6, 3)} & "
                    f"{sig(b[-1].ratio, 3)} & {pval(lb)} & {says} \\\\")
        w = WORDS[k]
        nums.add(f"pbCritStep{w}Label", tex_escape(label))
        nums.add(f"pbCritStep{w}RMS", sig(b[-1].rms_m * 1e6, 3))
        nums.add(f"pbCritStep{w}Ratio", sig(b[-1].ratio, 3))
        per_band = [x for x in b[:-1] if x.n_samples > 0]
        lo_band = min(per_band, key=lambda x: x.ratio)
        hi_band = max(per_band, key=lambda x: x.ratio)
        nums.add(f"pbCritStep{w}RatioMin", sig(lo_band.ratio, 3))
        nums.add(f"pbCritStep{w}RatioMinBand", _band(lo_band.band_hz))
        nums.add(f"pbCritStep{w}RatioMax", sig(hi_band.ratio, 3))
        nums.add(f"pbCritStep{w}RatioMaxBand", _band(hi_band.band_hz))
        nums.add(f"pbCritStep{w}LB", pval(lb))
        nums.add(f"pbCritStep{w}Missing", tex_escape(d.missing or "nothing"))
        nums.add(f"pbCritStep{w}Adequate", "adequate" if d.adequate else "not adequate")
        signature = d.experiments[0].signature
        if abs(signature.ccf_peak) > signature.ccf_bound and signature.ccf_lag_s > 0:
            nums.add(f"pbCritStep{w}LagMs", f"{signature.ccf_lag_s * 1e3:.0f}")
            nums.add(f"pbCritStep{w}LagBound",
                     f"{abs(signature.ccf_peak) / signature.ccf_bound:.0f}")
        else:
            nums.add(f"pbCritStep{w}LagMs", "none")
            nums.add(f"pbCritStep{w}LagBound", "0")
    for k in range(len(diagnoses), MAX_STEPS):  # the loop stopped early: say so, not blank
        w = WORDS[k]
        for field in ("Label", "RMS", "Ratio", "RatioMin", "RatioMinBand", "RatioMax",
                      "RatioMaxBand", "LB", "Missing", "Adequate", "LagMs", "LagBound"):
            nums.add(f"pbCritStep{w}{field}", "n/a")
    (tables / "criticism.tex").write_text(
        head + "\n" + "\n".join(body) + "\n" + r"\bottomrule" + "\n" + r"\end{tabular}" + "\n")

    nums.add("pbCritNSteps", len(diagnoses))
    nums.add("pbCritFloor", sig(comp.bands[labels[0]][-1].floor_m * 1e6, 3))
    nums.add("pbCritFinalEffects", tex_escape(", ".join(diagnoses[-1][0]) or "none"))
    found = diagnoses[-1][0] == list(["regulator_lag", "coulomb_friction"])
    nums.add("pbCritFoundBoth", "found both hidden effects, in the order lag then friction"
             if found else "did not recover the two hidden effects in order (found: "
             + tex_escape(", ".join(diagnoses[-1][0]) or "none") + ")")
    for i in range(MAX_STEPS - 1):
        w = WORDS[i + 1]
        step = comp.elpd_steps[i] if i < len(comp.elpd_steps) else None
        nums.add(f"pbCritElpdStep{w}", "n/a" if step is None else sig(step["elpd_diff"], 3))
        nums.add(f"pbCritElpdStep{w}SE", "n/a" if step is None else sig(step["se"], 2))
    final = trees[-1]
    post = final["posterior"]
    for name in ("tau_reg", "F_c"):  # the two the text discusses; n/a if not in the model
        _unit, k, digits = SHOWN[name]
        macro = "".join(ch for ch in name.title() if ch.isalpha())
        if name in post:
            hdi = az.hdi(final, prob=0.9)[name].values
            low, high = sig(float(hdi[0]) * k, digits + 1), sig(float(hdi[1]) * k, digits + 1)
        else:
            low = high = "n/a"
        nums.add(f"pbCritFinal{macro}Low", low)
        nums.add(f"pbCritFinal{macro}High", high)
    conv = fit_info(final)["convergence"]
    nums.add("pbCritFinalConverged", "converged" if conv["converged"] else "did not converge")
    nums.write(tables)
    if not math.isfinite(comp.bands[labels[-1]][-1].ratio):
        print("warning: the final ratio is not finite")
    print(f"figure: {band_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
