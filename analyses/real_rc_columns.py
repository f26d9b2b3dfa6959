"""Real measurements as force-input rigs: the reinforced-concrete columns of Ortiz, Alvarez
and Bedoya-Ruiz (Computers & Structures 2015), fitted in kN and in N.

The data stay in ``../shared/external/real/rc_columns`` beside the checkout (read-only,
never copied into the repository). Each specimen keeps its load (kN) and displacement
(mm) in two one-column files with no time: the tests are quasi-static, and the paper
reads them as the force on a one-mass Bouc-Wen oscillator on a fictitious 0.02 s step,
with a mass per specimen (the README: chiu 1360 kg, gill 3200 kg, kunnath 456 kg, sharma
187.2 kg). This reads both files (``pmabayes.data.read_columns``, the units in the
names), and writes, into ``--out``, each specimen as a data file declared two ways:

* ``NAME_kn.csv``: columns ``time_s,force_kn,position_mm``, as the lab's units;
* ``NAME_n.csv``: columns ``time_s,force_n,position_m``, in SI;

each with its sidecar (``"input_kind": "force"``, the mass, no gravity, area 1 m^2, the
record starting at rest). Then, as a user would, for each specimen and declaration:
``pmabayes fit`` and ``pmabayes validate --in-sample`` of the fit on its own record (for
the NRMSE and the yardsticks on the same footing), and, on the kN file, ``pmabayes
diagnose``. The default priors of a force-input rig follow the data's scale, so the two
declarations must give the same NRMSE; ``diagnose`` must finish on each.

Usage::

    python analyses/real_rc_columns.py [--quick] [--out DIR] [--seed 0] [--specimens ...]

``--quick`` (CI, docs) fits gill and kunnath only (the two shortest), with short chains,
and lets ``diagnose`` test two candidates (``coulomb_friction``, ``cubic_stiffness``).
The table is printed last; ``--out`` keeps the data files, fits and JSON outputs.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
from _real import pmabayes, real_folder

MASS_KG = {"chiu": 1360.0, "gill": 3200.0, "kunnath": 456.0, "sharma": 187.2}
STEP_S = 0.02
QUICK_SPECIMENS = ("gill", "kunnath")
QUICK_CANDIDATES = "coulomb_friction,cubic_stiffness"


def declare(out: Path, name: str) -> dict[str, Path]:
    """Write one specimen as two data files (kN and mm as the lab wrote them; N and m as
    pmabayes reads them) with their sidecars."""
    import warnings

    from pmabayes.data import DataWarning, read_columns

    folder = real_folder("rc_columns", "real_rc_columns.py")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)  # the conversions, said in the header
        force_n = read_columns(folder / f"load_kN_{name}.txt", {"1": "force_kn"})["force_n"]
        x_m = read_columns(folder / f"displ_{name}.txt", {"1": "position_mm"})["position_m"]
    load_kn = np.loadtxt(folder / f"load_kN_{name}.txt", ndmin=1)  # the lab's numbers as they are
    displ_mm = np.loadtxt(folder / f"displ_{name}.txt", ndmin=1)
    n = min(force_n.size, x_m.size)
    if force_n.size != x_m.size:
        print(f"{name}: load_kN_{name}.txt has {force_n.size} values and displ_{name}.txt "
              f"{x_m.size}: the first {n} of each are read", flush=True)
    t = np.arange(n) * STEP_S
    rig = {"name": name, "input_kind": "force", "moving_mass_kg": MASS_KG[name],
           "gravity_sign": 0, "area_m2": 1.0}
    meta = {"description": f"RC column {name} (Ortiz, Alvarez & Bedoya-Ruiz, Computers & "
                           "Structures 2015), on a fictitious 0.02 s step",
            "rig": rig, "initial_state": "rest"}
    paths = {}
    for unit, header, cols in (
            ("kn", "time_s,force_kn,position_mm", (t, load_kn[:n], displ_mm[:n])),
            ("n", "time_s,force_n,position_m", (t, force_n[:n], x_m[:n]))):
        path = out / f"{name}_{unit}.csv"
        rows = (",".join(repr(float(v)) for v in row) for row in np.column_stack(cols))
        path.write_text(header + "\n" + "\n".join(rows) + "\n")  # shortest exact digits
        path.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
        paths[unit] = path
    return paths


def main(argv: list[str] | None = None) -> int:
    """Fit, validate and diagnose each specimen; print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="two specimens, short chains (CI)")
    ap.add_argument("--out", type=Path, default=Path("real_rc_columns"),
                    help="folder for the data files, fits and JSON (real_rc_columns)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--specimens", nargs="+", choices=sorted(MASS_KG), default=None,
                    help="specimens to run (all four; --quick: gill and kunnath)")
    args = ap.parse_args(argv)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    specimens = args.specimens or (QUICK_SPECIMENS if args.quick else sorted(MASS_KG))
    steps = ["--steps", "60"] if args.quick else ["--steps", "600"]
    candidates = ["--candidates", QUICK_CANDIDATES] if args.quick else []
    seed = ["--seed", str(args.seed)]
    rows = []
    for name in specimens:
        paths = declare(out, name)
        row: dict = {"specimen": name}
        for unit, path in paths.items():
            fit = out / f"{name}_{unit}.nc"
            pmabayes("fit", str(path), "--out", str(fit), "--restart", *steps, *seed, "--quiet")
            val = out / f"{name}_{unit}_validate.json"
            pmabayes("validate", str(fit), str(path), "--json", str(val), "--draws", "40",
                     "--in-sample", *seed, "--quiet")
            e = json.loads(val.read_text())["experiments"][0]
            row[f"nrmse_{unit}"] = e["nrmse"]
            if unit == "kn":
                row["linear_nrmse"] = e["baselines"]["linear"]["nrmse"]
                row["play_nrmse"] = e["baselines"]["play"]["nrmse"]
        diag = out / f"{name}_diagnose.json"
        row["diagnose_s"] = pmabayes("diagnose", str(paths["kn"]), "--json", str(diag),
                                     *candidates, *seed, "--quiet")[0]
        found = json.loads(diag.read_text())
        row["adequate"] = found["adequate"]
        row["missing"] = found["missing"] or "-"  # the effect diagnose says is missing
        rows.append(row)

    with open(out / "table.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print("\nRC columns: fitted on each record, NRMSE on it (validate of the fit on its data)")
    print(f"{'specimen':<9} {'NRMSE kN':>9} {'NRMSE N':>9} {'linear':>7} {'play':>7} "
          f"{'diagnose':>9} {'adequate':>8}  missing")
    for r in rows:
        print(f"{r['specimen']:<9} {r['nrmse_kn']:>9.4f} {r['nrmse_n']:>9.4f} "
              f"{r['linear_nrmse']:>7.3f} {r['play_nrmse']:>7.3f} {r['diagnose_s']:>8.0f}s "
              f"{str(r['adequate']):>8}  {r['missing']}")
    same = all(abs(r["nrmse_kn"] - r["nrmse_n"]) <= 1e-3 * max(r["nrmse_kn"], 1e-12)
               for r in rows)
    print(f"kN and N give the same NRMSE (within 0.1%) on every specimen: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
