"""What every figure shares: the report's resolution, colour maps, saving, and the
enlarged fast end of a run.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure

#: Resolution of the report's figures.
REPORT_DPI = 100

#: the enlarged end of a run, in s
_ZOOM_S = 1.0


def colormap(name: str):
    """A matplotlib colour map by name (no pyplot)."""
    return matplotlib.colormaps[name]


def finish(fig: Figure, path: str | Path | None, dpi: int) -> Figure:
    """Save a figure where asked (format from the suffix); the figure."""
    if path is not None:
        fig.savefig(path, dpi=dpi)
    return fig


def zoom_slice(t: np.ndarray) -> slice:
    """The last ``_ZOOM_S`` seconds (the chirp's fast end), at most a quarter of the run."""
    span = float(t[-1] - t[0])
    width = min(_ZOOM_S, 0.25 * span)
    return slice(int(np.searchsorted(t, t[-1] - width)), None)
