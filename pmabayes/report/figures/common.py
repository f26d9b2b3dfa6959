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


#: Colour of the stretches where nothing was observed (a lab's gaps, a warm-up).
GAP_COLOUR = "0.82"


def shade_gaps(ax, time_s: np.ndarray, seen: np.ndarray, *, label: bool = True) -> bool:
    """Shade the stretches of samples not observed (not data: gaps in a lab's clock, a
    declared warm-up); nothing for a complete record.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        The axes, time along x.
    time_s : numpy.ndarray
        The samples' times (of the part drawn).
    seen : numpy.ndarray
        Boolean, True where a sample is observed.
    label : bool
        Label the first stretch for the legend.

    Returns
    -------
    bool
        Whether anything was shaded.
    """
    missing = ~np.asarray(seen, dtype=bool)
    if not missing.any():
        return False
    t = np.asarray(time_s, dtype=float)
    half = 0.5 * float(t[1] - t[0]) if t.size > 1 else 0.0
    edges = np.flatnonzero(np.diff(np.concatenate([[0], missing.astype(np.int8), [0]])))
    for i, (a, b) in enumerate(zip(edges[::2], edges[1::2], strict=True)):
        ax.axvspan(t[a] - half, t[b - 1] + half, color=GAP_COLOUR, lw=0, zorder=0,
                   label="not observed" if label and i == 0 else None)
    return True
