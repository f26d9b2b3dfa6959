"""The worked example beyond the library: a missing force found, proposed, added.

The README's worked example (section "Beyond the library"), through the public API:

1. synthetic trials of the paper's model plus a quadratic drag of 300 N s²/m² that no
   library holds: ``pmabayes.synthetic.HiddenDrag``, ``hidden_drag`` (parameter
   ``c_hidden``), as ``pmabayes --plugin hidden.py simulate drag.csv --effect
   hidden_drag=300 --duration 8 --trials 6 --seed 3`` makes them;
2. ``pmabayes.criticism.diagnosis.diagnose`` of the base model, with the built-in library as
   the candidates (``pmabayes diagnose drag.csv``): no library effect explains the
   misfit, so the discrepancy step estimates the missing force, ranks its states and
   writes a closed form as a ``.py`` plugin;
3. the written plugin loaded as ``--plugin`` loads it
   (:func:`pmabayes.model.effects.load_plugin`), and ``diagnose`` again with the proposed
   effect added (``pmabayes --plugin diag/proposed_vabsv.py diagnose drag.csv
   --effects proposed_vabsv``).

The hidden effect is registered only to generate the data; it is never a candidate.
The proposal is written into ``<out-root>/fits/discrepancy_proposal/`` (emptied of
earlier proposals first, so its name is not numbered).

With ``--detection-table PATH`` (default ``paper/tables/discrepancy.md``), the
Markdown table of ``analyses/detection.py --discrepancy`` is copied to
``tables/discrepancy.md`` and turned into ``tables/discrepancy.tex`` and macros
(``\\pbDiscDet...``); nothing is written for it when the file does not exist.

Usage::

    python analyses/paper/paper_discrepancy.py [--out-root paper] [--quick] [--seed 1]
                                         [--data-seed 3] [--detection-table PATH]

Writes ``figures/discrepancy_example.png``: (a) the flexible force's partial
dependence on velocity with the proposed closed form (refitted) and the hidden drag,
each less its least-squares line in velocity along the trajectory (the linear part is
what the refitted damping takes; the diagnosis page's ``discrepancy.png``, from
:func:`pmabayes.report.figures.plot_discrepancy`, shows the estimate with it), (b) the
leave-one-trial-out ELPD lost when each state is dropped, (c) the residual of the
trial mean before and after, against the noise floor. Also
``tables/numbers_discrepancy.tex``; prints the figure's path last.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from _paper import (
    PAPER_DIR,
    QUICK_CHIRP,
    QUICK_TRIALS,
    Numbers,
    out_dirs,
    parser,
    pval,
    sig,
    tex_escape,
)
from matplotlib.figure import Figure

from pmabayes.criticism.diagnosis import diagnose
from pmabayes.criticism.settings import DiagnoseSettings
from pmabayes.model.effects import get_effect, load_plugin, registered_effects
from pmabayes.synthetic import Chirp, HiddenDrag, generate_chirp_dataset

#: the hidden drag coefficient in N s²/m² (the README's example)
TRUE_DRAG = 300.0
#: the README's chirp and trials (``--duration 8 --trials 6``)
CHIRP = Chirp(duration_s=8.0)
N_TRIALS = 6
#: quick mode: one refit per diagnosis and fewer Laplace draws (defaults 3 and 400)
QUICK_DIAGNOSE = {"max_refits": 1, "n_draws": 100}
NA = "n/a"


def _verdict(d) -> str:
    """A short verdict of one diagnosis, for the table."""
    if d.adequate and d.missing is None:
        return "adequate, nothing missing"
    if d.missing is not None:
        return f"library effect {tex_escape(d.missing)} named missing"
    if d.discrepancy is not None and d.discrepancy.proposal is not None:
        return (r"no library effect explains it; proposes \texttt{"
                + tex_escape(d.discrepancy.proposal.effect) + "}")
    return "above the floor, nothing proposed"


def _detrended(f_along: np.ndarray, v_along: np.ndarray, f_grid: np.ndarray,
               grid: np.ndarray) -> np.ndarray:
    """``f`` on ``grid`` minus its least-squares line in velocity along the trajectory.

    The flexible force is estimated with the model's parameters refitted jointly, so
    the part of the missing force linear in velocity is taken by the damping ``d``
    (and a constant by the other parameters): only the rest is comparable."""
    a = np.stack([np.ones_like(v_along), v_along], axis=1)
    c = np.linalg.lstsq(a, f_along, rcond=None)[0]
    return f_grid - (c[0] + c[1] * grid)


def _effect_force(effect, values: dict, sim, v: np.ndarray) -> np.ndarray:
    """A force effect's force at velocities ``v``, averaged over the trajectory's
    positions and pressures (its partial dependence on velocity)."""
    q = np.array([values[p.name] for p in effect.parameters], dtype=float)
    x, p = sim.true_position_m[0], sim.pressure_pa[0]
    f = effect.force_n  # whatever the effect's signature (z and a state at rest)
    return np.array([np.mean([f(q, xi, g, pi)[0] for xi, pi in zip(x, p, strict=True)])
                     for g in v])


def _figure(ds, before, after, proposal_effect, path: Path) -> None:
    """(a) the missing force against velocity, estimated and proposed, against the
    hidden one; (b) the evidence for each state; (c) the residual before and after."""
    d = before.discrepancy
    sim = before.experiments[0].simulation
    v_along = sim.velocity_m_s[0]
    fig = Figure(figsize=(7.0, 2.4), layout="constrained")
    ax_v, ax_e, ax_r = fig.subplots(1, 3, width_ratios=(1.0, 0.8, 1.3))
    pd = d.partial_dependence["velocity"]
    grid = pd["grid"]
    flex_along = np.interp(v_along, grid, pd["force_n"])
    ax_v.plot(grid, _detrended(flex_along, v_along, pd["force_n"], grid), color="tab:red",
              lw=2.0, label="flexible estimate")
    drag = TRUE_DRAG * grid * np.abs(grid)
    ax_v.plot(grid, _detrended(TRUE_DRAG * v_along * np.abs(v_along), v_along, drag, grid),
              color="k", ls="--", lw=1.0, label="hidden drag")
    if proposal_effect is not None and after is not None:
        prop = _effect_force(proposal_effect, after.values, sim, grid)
        ax_v.plot(grid, _detrended(np.interp(v_along, grid, prop), v_along, prop, grid),
                  color="tab:blue", ls=":", lw=1.8, label="proposal, refitted")
    ax_v.axhline(0.0, color="k", lw=0.4)
    ax_v.set_xlabel("velocity [m/s]")
    ax_v.set_ylabel("force, less a line in v [N]")
    ax_v.legend(fontsize=6, loc="upper left")
    ax_v.set_title("(a) missing force", fontsize=8)

    states = d.states
    loss = np.array([s.elpd_loss for s in states])
    se = np.array([s.se for s in states])
    colors = ["tab:red" if s.needed else "tab:gray" for s in states]
    pos = np.arange(len(states))
    ax_e.bar(pos, loss, yerr=2 * se, color=colors, capsize=2)
    ax_e.set_yscale("symlog", linthresh=1.0)  # from 0 (or below) to thousands
    ax_e.axhline(0.0, color="k", lw=0.4)
    ax_e.set_xticks(pos, [s.state for s in states], rotation=45, ha="right", fontsize=6)
    ax_e.set_ylabel("ELPD lost when dropped (±2 se)")
    ax_e.set_title("(b) its states", fontsize=8)

    t = ds.time_s
    floor_um = before.noise_floor_m * 1e6
    ax_r.plot(t, (ds.mean_position_m - sim.position_m[0]) * 1e6, color="tab:gray", lw=0.6,
              label=f"base ({before.experiments[0].signature.ratio:.3g}x floor)")
    if after is not None:
        ax_r.plot(t, (ds.mean_position_m - after.experiments[0].simulation.position_m[0]) * 1e6,
                  color="tab:blue", lw=0.6,
                  label=f"+ proposal ({after.experiments[0].signature.ratio:.3g}x floor)")
    ax_r.axhspan(-floor_um, floor_um, color="tab:green", alpha=0.3, lw=0,
                 label="noise floor (RMS)")
    ax_r.set_xlabel("time [s]")
    ax_r.set_ylabel("residual of the mean [µm]")
    lo, hi = ax_r.get_ylim()
    ax_r.set_ylim(lo, hi + 0.6 * (hi - lo))  # room for the legend above the residual
    ax_r.legend(fontsize=6, loc="upper right")
    ax_r.set_title("(c) the error falls to the floor", fontsize=8)
    for ax in (ax_v, ax_e, ax_r):
        ax.tick_params(labelsize=7)
        ax.xaxis.label.set_size(7)
        ax.yaxis.label.set_size(7)
    fig.savefig(path, dpi=200)


def _detection(md_path: Path, tables: Path, nums: Numbers) -> bool:
    """Copy the detection study's Markdown table, write it as LaTeX and its macros.

    Returns whether the table was there.
    """
    if not md_path.is_file():
        print(f"no detection table at {md_path}: tables/discrepancy.tex not written")
        return False
    text = md_path.read_text()
    target = tables / "discrepancy.md"
    if md_path.resolve() != target.resolve():
        shutil.copyfile(md_path, target)
    rows = [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in text.splitlines() if line.strip().startswith("|")]
    if len(rows) < 3 or not all(set(c) <= set("-: ") for c in rows[1]):
        raise ValueError(f"{md_path}: expected a Markdown table (header, separator, rows) as "
                         "analyses/detection.py --discrepancy writes it; give that file")
    head, body = rows[0], rows[2:]
    lines = [r"\begin{tabular}{l" + "r" * (len(head) - 1) + "}", r"\toprule",
             " & ".join(tex_escape(c) for c in head) + r" \\", r"\midrule"]
    for r in body:
        if len(r) != len(head):
            raise ValueError(f"{md_path}: row {r} has {len(r)} cells, the header {len(head)}")
        lines.append(" & ".join(tex_escape(c.replace("\\|", "|")) for c in r) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    (tables / "discrepancy.tex").write_text("\n".join(lines) + "\n")
    # the text quotes the null and the outside-the-library rows
    null = next((r for r in body if re.match(r"^\d+ null$", r[0])), None)
    outside = next((r for r in body if r[0].endswith("outside the library")), None)
    if null is None or outside is None:
        raise ValueError(f"{md_path}: no 'N null' or 'N outside the library' row")
    nums.add("pbDiscDetNull", null[0].split()[0])
    nums.add("pbDiscDetFalse", null[1].split()[0])
    nums.add("pbDiscDetFalseRate", tex_escape(null[3]))
    nums.add("pbDiscDetOutside", outside[0].split()[0])
    nums.add("pbDiscDetCorrect", outside[2].split()[0])
    nums.add("pbDiscDetCorrectRate", tex_escape(outside[3]))
    return True


def main(argv: list[str] | None = None) -> int:
    """Make the data, diagnose, add the proposal, diagnose again; write figure and numbers."""
    p = parser(__doc__)
    p.add_argument("--data-seed", type=int, default=3,
                   help="seed of the synthetic data's noise (3, as in the README)")
    p.add_argument("--detection-table", type=Path, default=PAPER_DIR / "tables" / "discrepancy.md",
                   help="discrepancy.md of analyses/detection.py --discrepancy "
                        "(default paper/tables/discrepancy.md)")
    args = p.parse_args(argv)
    figures, tables = out_dirs(args.out_root)
    nums = Numbers("discrepancy", args.quick)
    proposal_dir = Path(args.out_root) / "fits" / "discrepancy_proposal"
    proposal_dir.mkdir(parents=True, exist_ok=True)
    for old in proposal_dir.glob("proposed_*.py"):  # this script's earlier proposals
        old.unlink()

    library = tuple(registered_effects())  # the built-ins; the hidden drag is never registered
    chirp, n_trials = (QUICK_CHIRP, QUICK_TRIALS) if args.quick else (CHIRP, N_TRIALS)
    ds = generate_chirp_dataset(n_trials=n_trials, seed=args.data_seed, chirp=chirp,
                                effects={HiddenDrag: {"c_hidden": TRUE_DRAG}},
                                description="paper model plus a hidden quadratic drag "
                                            "(synthetic)")
    settings = DiagnoseSettings(candidates=library, **(QUICK_DIAGNOSE if args.quick else {}))
    kw = dict(settings=settings, seed=args.seed, plugin_dir=proposal_dir)
    load = os.getloadavg()[0]
    start = time.perf_counter()
    before = diagnose(ds, **kw)
    secs_before = time.perf_counter() - start
    print(f"base: RMS {before.rms_m * 1e6:.1f} um = "
          f"{before.experiments[0].signature.ratio:.3g}x floor, "
          f"{secs_before:.0f} s\n{before.verdict}", flush=True)
    d = before.discrepancy
    prop = None if d is None else d.proposal
    after = effect = None
    secs_after = float("nan")
    if prop is not None and prop.plugin is not None:
        load_plugin(prop.plugin)  # as --plugin does
        effect = get_effect(prop.effect)
        start = time.perf_counter()
        after = diagnose(ds, effects=[prop.effect], **kw)
        secs_after = time.perf_counter() - start
        print(f"base + {prop.effect}: RMS {after.rms_m * 1e6:.1f} um = "
              f"{after.experiments[0].signature.ratio:.3g}x floor, {secs_after:.0f} s\n"
              f"{after.verdict}",
              flush=True)
    else:
        print("warning: no plugin was written; the example stops at the base model")

    nums.add("pbDiscTrue", sig(TRUE_DRAG, 3))
    nums.add("pbDiscTrials", ds.n_trials)
    nums.add("pbDiscDuration", sig(ds.time_s[-1] - ds.time_s[0] + ds.dt_s, 2))
    nums.add("pbDiscDataSeed", args.data_seed)
    nums.add("pbDiscNLibrary", len(library))
    nums.add("pbDiscFloor", sig(before.noise_floor_m * 1e6, 3))
    nums.add("pbDiscBaseRMS", sig(before.rms_m * 1e6, 3))
    nums.add("pbDiscBaseRatio", sig(before.experiments[0].signature.ratio, 3))
    nums.add("pbDiscBaseVerdict", _verdict(before))
    refitted = [f for f in before.ranking if f.refit is not None]
    nums.add("pbDiscBestRefit", tex_escape(refitted[0].effect) if refitted else NA)
    nums.add("pbDiscBestRefitExplained",
             f"{100 * refitted[0].explained:.0f}" if refitted else NA)
    nums.add("pbDiscSecondsBase", f"{secs_before:.0f}")
    nums.add("pbDiscLoad", f"{load:.0f}")
    if d is not None:
        nums.add("pbDiscExplained", f"{100 * d.explained:.0f}")
        nums.add("pbDiscFlexRatio", sig(d.ratio_after, 3))
        nums.add("pbDiscGain", sig(d.elpd_gain, 3))
        nums.add("pbDiscGainSE", sig(d.elpd_gain_se, 2))
        nums.add("pbDiscMemoryTau", sig(d.memory_tau_s, 2))
        lead = d.states[0]
        nums.add("pbDiscLeadState", lead.state)
        nums.add("pbDiscLeadLoss", sig(lead.elpd_loss, 3))
        nums.add("pbDiscLeadSE", sig(lead.se, 2))
        second = d.states[1] if len(d.states) > 1 else None
        nums.add("pbDiscSecondState", second.state if second else NA)
        nums.add("pbDiscSecondLoss", sig(second.elpd_loss, 3) if second else NA)
        nums.add("pbDiscSecondSE", sig(second.se, 2) if second else NA)
        needed = [s.state for s in d.states if s.needed]
        nums.add("pbDiscNNeeded", len(needed))
        nums.add("pbDiscStatesNeeded", ", ".join(needed) or "none")
    else:
        for name in ("Explained", "FlexRatio", "Gain", "GainSE", "MemoryTau", "LeadState",
                     "LeadLoss", "LeadSE", "SecondState", "SecondLoss", "SecondSE", "NNeeded",
                     "StatesNeeded"):
            nums.add(f"pbDisc{name}", NA)
    if prop is not None:
        nums.add("pbDiscEffect", tex_escape(prop.effect))
        nums.add("pbDiscExpression", tex_escape(prop.expression))
        nums.add("pbDiscDescription", tex_escape(prop.description))
        nums.add("pbDiscKind", tex_escape(prop.kind))
        nums.add("pbDiscPropElpd", sig(prop.elpd_diff, 3))
        nums.add("pbDiscPropElpdSE", sig(prop.elpd_diff_se, 2))
        nums.add("pbDiscNTerms", len(prop.terms))
        nums.add("pbDiscTerms", tex_escape(", ".join(t["term"] for t in prop.terms)))
        v = prop.verified
        nums.add("pbDiscVerifiedRatio", sig(v["ratio"], 3) if v else NA)
        first = prop.terms[0]
        nums.add("pbDiscCoefName", tex_escape(first["parameter"] or first["term"]))
        nums.add("pbDiscCoefUnit", tex_escape(first["unit"]))
        nums.add("pbDiscCoefLinear", sig(first["coefficient"], 4))
        found = NA
        if after is not None and first["parameter"] in after.values:
            found = sig(after.values[first["parameter"]], 4)
        nums.add("pbDiscCoefFound", found)
    else:
        for name in ("Effect", "Expression", "Description", "Kind", "PropElpd", "PropElpdSE",
                     "NTerms", "Terms", "VerifiedRatio", "CoefName", "CoefUnit", "CoefLinear",
                     "CoefFound"):
            nums.add(f"pbDisc{name}", NA)
    if after is not None:
        nums.add("pbDiscAddedRMS", sig(after.rms_m * 1e6, 3))
        nums.add("pbDiscAddedRatio", sig(after.experiments[0].signature.ratio, 3))
        nums.add("pbDiscAddedLB", pval(after.experiments[0].signature.ljung_box_p))
        nums.add("pbDiscAddedVerdict", _verdict(after))
        nums.add("pbDiscSecondsAdded", f"{secs_after:.0f}")
    else:
        for name in ("AddedRMS", "AddedRatio", "AddedLB", "AddedVerdict", "SecondsAdded"):
            nums.add(f"pbDisc{name}", NA)
    _detection(args.detection_table, tables, nums)
    nums.write(tables)

    path = figures / "discrepancy_example.png"
    if d is not None:
        _figure(ds, before, after, effect, path)
    else:  # still a figure, saying why it is empty (quick sizes may fall short)
        fig = Figure(figsize=(4, 1.5))
        fig.text(0.5, 0.5, "no discrepancy was estimated: " + before.verdict[:60],
                 ha="center", va="center", fontsize=7, wrap=True)
        fig.savefig(path, dpi=150)
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
