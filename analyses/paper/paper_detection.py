"""Detection limits of model criticism: false alarms on null data, detection rate vs size.

Runs ``analyses/detection.py`` (its ``main``; the study itself is defined there) into
``<out-root>/tables``, then reads its ``detection.csv`` and draws the rate at which
each hidden effect is flagged and named missing against its size, with exact 90%
binomial intervals, and writes the LaTeX table and the numbers the text needs.

Usage::

    python analyses/paper/paper_detection.py [--out-root paper] [--quick] [--seed 1]
                                       [--null N] [--seeds N] [--sizes K] [--max-refits R]

Full mode uses ``detection.py``'s sizes unless given (20 null data sets, 5 per size,
4 sizes per effect, 3 refits, three effects); quick mode 1 null data set and the
largest friction only, with 1 refit, on ``detection.py``'s short quick chirps. Writes
``figures/detection.png``, ``tables/detection.tex``, ``tables/numbers_detection.tex``
(and ``detection.py``'s ``detection.csv``, ``detection.md``, ``null.md``); prints the
figure's path last.
"""

from __future__ import annotations

import csv
import sys

import matplotlib.pyplot as plt
import numpy as np
from _paper import Numbers, out_dirs, parser, tex_escape

QUICK = {"null": 1, "seeds": 1, "sizes": 1, "max_refits": 1}
#: the quick mode sweeps one effect only (each diagnosis with a refit costs ~20 s)
QUICK_EFFECTS = ("coulomb_friction",)


def _truthy(text: str) -> bool:
    return text == "True"


def main(argv: list[str] | None = None) -> int:
    """Run the study through ``detection.main`` and write figure, table and numbers."""
    p = parser(__doc__)
    p.add_argument("--null", type=int, default=None)
    p.add_argument("--seeds", type=int, default=None)
    p.add_argument("--sizes", type=int, default=None)
    p.add_argument("--max-refits", type=int, default=None)
    p.add_argument("--reuse", action="store_true",
                   help="redraw from an existing tables/detection.csv instead of rerunning "
                        "the study (its sizes must match the other options)")
    args = p.parse_args(argv)
    import detection  # after _paper, which puts the checkout on the path

    figures, tables = out_dirs(args.out_root)
    opts = {"null": args.null, "seeds": args.seeds, "sizes": args.sizes,
            "max_refits": args.max_refits}
    if args.quick:
        opts = {k: QUICK[k] if v is None else v for k, v in opts.items()}
    det_argv = ["--out", str(tables), "--seed", str(args.seed)]
    det_argv += ["--quick"] if args.quick else []
    for k, v in opts.items():
        if v is not None:
            det_argv += [f"--{k.replace('_', '-')}", str(v)]
    if args.quick:
        det_argv += ["--effects", *QUICK_EFFECTS]
    if not (args.reuse and (tables / "detection.csv").is_file()):
        detection.main(det_argv)

    with open(tables / "detection.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    null = [r for r in rows if r["effect"] == "none"]
    k_flag = sum(_truthy(r["flagged"]) for r in null)
    k_inad = sum(not _truthy(r["adequate"]) for r in null)
    lo, hi = detection.clopper_pearson(k_flag, len(null))

    body = []
    nums = Numbers("detection", args.quick)
    swept = [sw for sw in detection.SWEEPS if any(r["effect"] == sw[0] for r in rows)]
    fig, axes = plt.subplots(1, len(swept), figsize=(3.0 * len(swept) + 0.5, 3.0),
                             sharey=True, layout="constrained", squeeze=False)
    axes = axes[0]
    for effect, _param, _unit, _scale, _sizes in detection.SWEEPS:
        if effect not in [sw[0] for sw in swept]:  # not swept in this run: say so
            name = "".join(w.capitalize() for w in effect.split("_"))
            nums.add(f"pbDet{name}Largest", "not run in this mode")
            nums.add(f"pbDet{name}LargestNamed", "n/a")
    for ax, (effect, param, unit, scale, _sizes) in zip(axes, swept, strict=True):
        sel = [r for r in rows if r["effect"] == effect]
        sizes = sorted({float(r["size"]) for r in sel})
        for key, style, label in (("flagged", "o-", "anything flagged"),
                                  ("named", "s--", "named missing")):
            rate, err_lo, err_hi = [], [], []
            for s in sizes:
                at = [r for r in sel if float(r["size"]) == s]
                k = sum(_truthy(r["flagged"]) if key == "flagged" else r["missing"] == effect
                        for r in at)
                a, b = detection.clopper_pearson(k, len(at))
                rate.append(k / len(at))
                err_lo.append(k / len(at) - a)
                err_hi.append(b - k / len(at))
            ax.errorbar(np.array(sizes) * scale, rate, yerr=[err_lo, err_hi], fmt=style,
                        capsize=2, label=label)
        for s in sizes:
            at = [r for r in sel if float(r["size"]) == s]
            named = sum(r["missing"] == effect for r in at)
            cov = [_truthy(r["covered"]) for r in at if r["covered"] != ""]
            other = sorted({r["missing"] for r in at if r["missing"] not in ("", effect)})
            n_other = sum(r["missing"] not in ("", effect) for r in at)
            body.append(f"{tex_escape(effect)} & {s * scale:g} {tex_escape(unit)} & "
                        f"{sum(_truthy(r['flagged']) for r in at)}/{len(at)} & "
                        f"{named}/{len(at)} & {n_other}/{len(at)}"
                        f"{' (' + tex_escape(', '.join(other)) + ')' if other else ''} & "
                        f"{sum(cov)}/{len(cov)} & "
                        f"{np.median([float(r['ratio']) for r in at]):.3g} \\\\")
        ax.set_xscale("log")
        ax.minorticks_off()
        ax.set_xticks([v * scale for v in sizes], [f"{v * scale:g}" for v in sizes])
        ax.set_xlabel(f"{effect} {param} [{unit}]", fontsize=8)
        ax.set_ylim(-0.05, 1.05)
        ax.tick_params(labelsize=7)
        largest = [r for r in sel if float(r["size"]) == sizes[-1]]
        name = "".join(w.capitalize() for w in effect.split("_"))
        nums.add(f"pbDet{name}Largest", f"{sizes[-1] * scale:g}~{tex_escape(unit)}")
        nums.add(f"pbDet{name}LargestNamed",
                 f"{sum(r['missing'] == effect for r in largest)}/{len(largest)}")
    axes[0].set_ylabel("rate (90% exact interval)", fontsize=8)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.suptitle(f"{len(null)} null data sets: {k_flag} flagged; "
                 f"{len(rows) - len(null)} with one hidden effect", fontsize=9)
    path = figures / "detection.png"
    fig.savefig(path, dpi=130)
    plt.close(fig)

    table = [r"\begin{tabular}{llrrlrr}", r"\toprule",
             r"hidden effect & size & flagged & named & other named & int. covers & "
             r"RMS/floor \\",
             r"\midrule", *body, r"\bottomrule", r"\end{tabular}"]
    (tables / "detection.tex").write_text("\n".join(table) + "\n")
    nums.add("pbDetNull", len(null))
    nums.add("pbDetNullFlagged", k_flag)
    nums.add("pbDetNullInadequate", k_inad)
    nums.add("pbDetNullCILow", f"{100 * lo:.0f}")
    nums.add("pbDetNullCIHigh", f"{100 * hi:.0f}")
    sized = [r for r in rows if r["effect"] != "none"]
    per_size = len({(r["effect"], r["size"]) for r in sized})
    nums.add("pbDetSeedsPerSize", len(sized) // max(per_size, 1))
    nums.add("pbDetSizesPerEffect", per_size // max(len(swept), 1))
    nums.add("pbDetEffectsSwept", len(swept))
    nums.add("pbDetDiagnoses", len(rows))
    nums.add("pbDetSized", len(sized))
    nums.add("pbDetNamedRight", sum(r["missing"] == r["effect"] for r in sized))
    nums.add("pbDetNamedWrong", sum(r["missing"] not in ("", r["effect"]) for r in sized))
    nums.add("pbDetMaxRefits", 3 if opts["max_refits"] is None else opts["max_refits"])
    nums.add("pbDetChirp", "5~s chirps (0.3--2~Hz), 4 trials" if args.quick
             else "8~s chirps (0.3--3~Hz), 6 trials")
    nums.write(tables)
    print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
