"""Shared plumbing of the analyses on real measurements (not a public API): where the
data are (``../shared/external/real`` beside the checkout, never copied into it) and
running pmabayes' commands as a user would."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "external" / "real"


def real_folder(name: str, script: str) -> Path:
    """The folder ``name`` of the real measurements, or a clear error naming ``script``.

    Parameters
    ----------
    name : str
        ``"cavatappi"`` or ``"rc_columns"``.
    script : str
        The analysis, for the message.

    Returns
    -------
    Path
    """
    folder = REAL / name
    if not folder.is_dir():
        sys.exit(f"{script}: {folder} is not there: the real measurements are read from "
                 "../shared/external/real beside the checkout (see its README); mount or "
                 "check out the shared folder there.")
    return folder


def pmabayes(*args: str, refusal_ok: bool = False) -> tuple[float, str | None]:
    """Run one pmabayes command as a user would, its output shown.

    Parameters
    ----------
    *args : str
        The command and its arguments.
    refusal_ok : bool
        Return a refusal (exit status 2: pmabayes' own error) as its message instead of
        stopping.

    Returns
    -------
    seconds : float
        How long it took.
    refusal : str or None
        The refusal's error line, None when the command succeeded.
    """
    print("$ pmabayes " + " ".join(args), flush=True)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pmabayes", *args], cwd=ROOT,
                          stderr=subprocess.PIPE, text=True, check=False)
    sys.stderr.write(done.stderr)
    took = time.perf_counter() - started
    print(f"[{took:.0f} s]", flush=True)
    if refusal_ok and done.returncode == 2:
        return took, next((line for line in done.stderr.splitlines() if ": error: " in line),
                          done.stderr.strip().splitlines()[-1])
    if done.returncode != 0:
        raise SystemExit(f"pmabayes {args[0]} failed (exit status {done.returncode})")
    return took, None
