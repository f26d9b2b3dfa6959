"""The three yardsticks alone on the real records, held out in time and across loads.

For each reinforced-concrete column (``analyses/real_rc_columns.py`` declares them) the
yardsticks are fitted on the first 70% of its record and predict the whole record from
its load; the table gives their NRMSE on the last 30% (free run from the record's start).
For the cavatappi muscle (``analyses/real_cavatappi.py`` declares it) they are fitted on
the 300 g load, and on the 100, 300 and 500 g loads together (the NARX with the load as
an input), and predict the held-out 200 and 400 g loads.

Usage::

    python analyses/yardsticks_real.py [--out DIR]

A few seconds per record.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import real_cavatappi
import real_rc_columns

from pmabayes.criticism.baselines import fit_baselines
from pmabayes.data import Dataset, load

TRAIN_SHARE = 0.7


def head(ds: Dataset, share: float) -> Dataset:
    """The first ``share`` of a record (no gaps) as a data set of its own."""
    c = int(round(share * ds.n_samples))
    return Dataset(time_s=ds.time_s[:c], input=ds.input[:, :c], position_m=ds.position_m[:, :c],
                   trial_ids=ds.trial_ids, input_name=ds.input_name, metadata=ds.metadata,
                   source=f"{ds.source} (first {100 * share:.0f}%)")


def row(what: str, held: str, b, scores: dict) -> str:
    cells = [f"{what:34s}", f"{held:22s}"]
    for name in ("linear", "play", "narx"):
        s = scores.get(name)
        cells.append("left out" if s is None else f"{s['nrmse']:.3f} ({s['order_text']})")
    return " | ".join(cells)


def tail_scores(b, ds: Dataset, share: float) -> dict:
    """Each yardstick's NRMSE on the last ``1 - share`` of a record, simulated from its
    start."""
    from pmabayes.criticism.observed import observed_mean
    from pmabayes.criticism.yardsticks import nrmse

    y = observed_mean(ds)
    cut = int(round(share * ds.n_samples))
    full = b.scores(ds, arrays=True)
    out = {}
    for name, s in full.items():
        _, nr = nrmse(y[cut:], s["prediction_m"][cut:]) if "failed" not in s else (0, np.inf)
        out[name] = {"nrmse": nr, "order_text": s["order_text"]}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="yardsticks_real_"))
    out.mkdir(parents=True, exist_ok=True)
    lines = []
    for name in ("chiu", "gill", "kunnath", "sharma"):
        ds = load(real_rc_columns.declare(out, name)["n"])
        b = fit_baselines(head(ds, TRAIN_SHARE))
        lines.append(row(f"rc {name} (first 70%)", "last 30%", b,
                         tail_scores(b, ds, TRAIN_SHARE)))
        lines += [f"    {r}" for r in b.lines()]
    paths = real_cavatappi.declare(out)
    data = {g: load(p) for g, p in paths.items()}
    for train in ((300,), (100, 300, 500)):
        b = fit_baselines([data[g] for g in train])
        for g in (200, 400):
            lines.append(row(f"cavatappi {'+'.join(map(str, train))} g ({b.seconds:.1f} s)",
                             f"{g} g", b, b.scores(data[g])))
        lines += [f"    {r}" for r in b.lines()]
    print("fitted on                          | held out               | NRMSE linear | "
          "play | narx")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
