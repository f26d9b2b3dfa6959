"""Wall time of the full robustness sweep: 500 samples x 8 frequencies x 2 controllers.

Each of the 8000 runs is a 10 s closed loop (plant at 1 kHz, controller at 100 Hz,
regulator command at 20 Hz) on the control rig, with the plant drawn from the
posterior and the controllers on the posterior mean (mode ``plant``). The kernel is
compiled (or loaded from the cache), and both controllers are tuned on the posterior
mean (or the tuning loaded from the cache), by a small warm-up sweep before the
clock starts. Without ``--fit`` the bundled ``data/pma_chirp_paper.csv`` is fitted
first (not timed).

Usage::

    python analyses/bench_robustness.py [--fit FIT.nc] [--processes N] [--mode plant|model]

The last line printed is ``sweep_seconds: <number>``. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pmabayes.control.robustness import robustness_sweep, summarise_robustness
from pmabayes.data import load
from pmabayes.inference.fitfile import save_fit
from pmabayes.inference.sampler import FitSettings, fit
from pmabayes.model.model import Model

DEFAULT_DATA = Path(__file__).resolve().parents[1] / "data" / "pma_chirp_paper.csv"


def main(argv: list[str] | None = None) -> int:
    """Run the sweep, print its summary, and print ``sweep_seconds`` last."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fit", type=Path, help="a fit (the bundled data is fitted if absent)")
    parser.add_argument("--samples", type=int, default=500)
    parser.add_argument("--processes", type=int, default=None,
                        help="local worker processes (all cores by default)")
    parser.add_argument("--mode", default="plant")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    fit_path = args.fit
    if fit_path is None:
        start = time.perf_counter()
        fit_path = Path(tempfile.mkdtemp(prefix="pmabayes-bench-")) / "fit.nc"
        save_fit(fit(load(DEFAULT_DATA), Model(), seed=0,
                     settings=FitSettings(progress=False)), fit_path)
        print(f"fitted {DEFAULT_DATA.name} in {time.perf_counter() - start:.1f} s (not timed)")
    start = time.perf_counter()
    robustness_sweep(fit_path, samples=2, frequencies_hz=(1.0,), duration_s=3.0, processes=1,
                     progress=False, mode=args.mode)
    print(f"kernel compile/load and gain tuning before timing: "
          f"{time.perf_counter() - start:.1f} s")

    start = time.perf_counter()
    ds = robustness_sweep(fit_path, samples=args.samples, mode=args.mode, seed=args.seed,
                          processes=args.processes, progress=True)
    seconds = time.perf_counter() - start
    summary = summarise_robustness(ds)
    print(f"{ds.sizes['sample']} samples x {ds.sizes['frequency']} frequencies x "
          f"{ds.sizes['controller']} controllers of {ds.attrs['duration_s']:g} s, mode "
          f"{args.mode}, on {ds.attrs['runner']}")
    print(f"gains ({ds.attrs['gains_source']}): {ds.attrs['gains']}")
    print(f"{'f [Hz]':>7} {'PID RMS mm (5-50-95%)':>24} {'CT RMS mm (5-50-95%)':>24} "
          f"{'P(CT<PID)':>10} {'MC error':>8} {'dead PID/CT':>12}")
    for f in summary["frequency"].values:
        cells = []
        for c in ("pid", "ct"):
            s = summary.sel(frequency=f, controller=c)
            cells.append(" / ".join(f"{1e3 * float(s[f'rms_error_m_{q}']):.2f}"
                                    for q in ("q05", "median", "q95")))
        dead = summary["dead_zone_fraction_mean"].sel(frequency=f)
        print(f"{f:7.3f} {cells[0]:>24} {cells[1]:>24} "
              f"{float(summary['p_ct_beats_pid'].sel(frequency=f)):10.3f} "
              f"{float(summary['p_ct_beats_pid_mc_error'].sel(frequency=f)):8.3f} "
              f"{float(dead.sel(controller='pid')):5.2f}/{float(dead.sel(controller='ct')):.2f}")
    print(f"sweep_seconds: {seconds:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
