"""The figure of ``cevm replay --plot``: each duty's energy (or fuel) against the
candidate's usable battery (or tank) and its reserve (a PNG), drawn with matplotlib's
object API (a Figure on its own Agg canvas: no pyplot state, no backend switched)."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from cevm.io.plots import save_figure
from cevm.text import printable

#: Vehicles drawn in their own colour; the rest share one.
PLOT_MAX_VEHICLES = 10


def plot_duties(path: Path, *, vehicle: list[str], start_s: np.ndarray, energy: np.ndarray, low: np.ndarray,
                high: np.ndarray, completes: np.ndarray, usable: float, above_reserve: float, unit: str,
                title: str) -> None:
    """Duties' energies [``unit``] at their start dates, with their intervals (``low``,
    ``high``), a cross where a duty does not complete; lines at the ``usable`` energy
    (the start level) and at what is usable above the reserve."""
    # matplotlib (0.3 s) is imported when a figure is drawn, never by importing cevm.io
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 5))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    when = np.array([datetime.fromtimestamp(float(s), UTC) for s in start_s], dtype=object)
    names = list(dict.fromkeys(vehicle))
    own = names[:PLOT_MAX_VEHICLES]
    vid = np.array(vehicle, dtype=object)
    for k, name in enumerate(own + (["other vehicles"] if len(names) > len(own) else [])):
        sel = np.isin(vid, own, invert=True) if name == "other vehicles" and k == len(own) else vid == name
        if not sel.any():
            continue
        err = np.vstack([energy[sel] - low[sel], high[sel] - energy[sel]])
        color = f"C{k % 10}"
        ax.errorbar(when[sel], energy[sel], yerr=np.maximum(err, 0.0), fmt="o", ms=4, color=color, capsize=2,
                    label=printable(name))
        bad = sel & ~completes
        if bad.any():
            ax.plot(when[bad], energy[bad], "x", ms=9, color="k")
    ax.axhline(usable, color="k", lw=1.2, label=f"usable at the start ({usable:,.0f} {unit})")
    ax.axhline(above_reserve, color="r", lw=1.2, ls="--", label=f"above the reserve ({above_reserve:,.0f} {unit})")
    ax.set(xlabel="duty start (UTC)", ylabel=f"duty's energy [{unit}]", title=printable(title))
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8, loc="best")
    fig.autofmt_xdate()
    fig.tight_layout()
    save_figure(fig, path)  # whole or not at all; a full disk is exit 3
