"""The figure of ``cevm gtfs --plot``: each block's state of charge (or tank) through the
day, a line per block and date, the reserve dashed (a PNG, matplotlib's object API as
:mod:`cevm.io.replay_plot`)."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from cevm.io.plots import save_figure
from cevm.text import printable

#: Blocks named in the legend; the rest drawn grey.
PLOT_MAX_NAMED = 12


def plot_blocks(path: Path, curves: list, *, reserve_pct: float, zone, what: str, title: str) -> None:
    """``curves``: (label, epoch seconds, level [%], completes) per block and date; the
    time of day in ``zone`` on the x axis (each date drawn over the same day)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 5.5))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for k, (label, t, level, ok) in enumerate(curves):
        local = [datetime.fromtimestamp(float(s), UTC).astimezone(zone) for s in t]
        base = local[0].replace(hour=0, minute=0, second=0)
        hours = np.array([(x - base).total_seconds() / 3600.0 for x in local])
        named = k < PLOT_MAX_NAMED
        ax.plot(hours, level, lw=1.0 if named else 0.6, color=f"C{k % 10}" if named else "0.6",
                ls="-" if ok else ":", label=printable(label) if named else None)
    ax.axhline(reserve_pct, color="r", lw=1.2, ls="--", label=f"reserve ({reserve_pct:g} %)")
    ax.set(xlabel="hour of the service day (feed's time zone)", ylabel=f"{what} [%]", title=printable(title))
    ax.set_ylim(0, 105)
    if curves:
        ax.legend(fontsize=7, loc="lower left", ncol=2)
    fig.tight_layout()
    save_figure(fig, path)
