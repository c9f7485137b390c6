"""The figures of ``cevm calibrate``, ``cevm simulate`` and ``cevm predict`` (PNG files).

Drawn with matplotlib's object API (a :class:`matplotlib.figure.Figure` on its own
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg`, imported when a figure is
drawn): no pyplot state, so drawing a figure neither selects nor switches the backend
of a program or notebook that calls these functions, and leaves no figure open."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from cevm.errors import OutputError, os_error_text
from cevm.io.outputs import OutFile
from cevm.text import printable

if TYPE_CHECKING:
    from cevm.core.calibration import CalibrationResult
    from cevm.core.sweep import PredictionSet, Source
    from cevm.core.vehicle import Vehicle

#: Lines drawn at most by ``--plot`` (one per source and vehicle).
PLOT_MAX_LINES = 12


def _figure(figsize: tuple[float, float]):
    """A new figure of ``figsize`` [in] on its own Agg canvas (PNG), outside pyplot."""
    # matplotlib (0.3 s) is imported when a figure is drawn, never by importing cevm.io
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def plot_calibration(result: CalibrationResult, path: Path, title: str) -> None:
    """Three panels: predicted against measured with the 1:1 line (the paper's figures 5
    and 7), each held-out prediction with its interval; the percent error against trip
    distance, in-sample and cross-validated; and the calibration of the intervals: the
    share of held-out trips inside their central interval against its nominal level
    (on the diagonal when the intervals are honest), with its binomial 95 % band."""
    from scipy.special import ndtri
    from scipy.stats import binom

    from cevm.core.calibration import display_value

    unit = "kWh" if result.unit == "J" else "l"
    rows = result.rows
    meas = np.array([display_value(result, r.measured) for r in rows])
    ins = np.array([display_value(result, r.predicted_in_sample) for r in rows])
    cv = np.array([display_value(result, r.predicted_cv) for r in rows])
    lo = np.array([display_value(result, r.predicted_low) for r in rows])
    hi = np.array([display_value(result, r.predicted_high) for r in rows])
    dist = np.array([r.distance_m for r in rows]) / 1e3
    fig = _figure((16, 4.8))
    a1, a2, a3 = fig.subplots(1, 3)
    top = max(meas.max(), np.nanmax(hi) if np.isfinite(hi).any() else 0, ins.max()) * 1.05
    lim = [0, top]
    a1.plot(lim, lim, "k-", lw=1, label="1:1")
    a1.scatter(meas, ins, s=18, label="CE model, in-sample")
    ok = np.isfinite(cv) & np.isfinite(lo) & np.isfinite(hi)
    if ok.any():
        a1.errorbar(meas[ok], cv[ok], yerr=[cv[ok] - lo[ok], hi[ok] - cv[ok]], fmt="x", ms=5, lw=0.8, capsize=2,
                    label=f"cross-validated, {100 * result.interval:g} % interval")
    a1.set(xlim=lim, ylim=lim, xlabel=f"measured [{unit}]", ylabel=f"modelled [{unit}]", title=title)
    a1.legend(fontsize=8)
    a2.axhline(0, color="k", lw=1)
    a2.scatter(dist, [r.error_pct_in_sample for r in rows], s=18, label="in-sample")
    if np.isfinite(cv).any():
        a2.scatter(dist, [r.error_pct_cv for r in rows], s=18, marker="x", label="cross-validated")
    a2.set(xlabel="trip distance [km]", ylabel="error (modelled - measured) / measured [%]")
    a2.legend(fontsize=8)
    sd = np.array([r.sd_cv for r in rows])
    zs = (np.array([r.measured for r in rows]) - np.array([r.predicted_cv for r in rows])) / sd
    zs = np.abs(zs[np.isfinite(zs)])
    levels = np.linspace(0.05, 0.99, 48)
    a3.plot([0, 1], [0, 1], "k-", lw=1, label="nominal")
    if zs.size:
        emp = np.array([np.mean(zs <= ndtri(0.5 + 0.5 * lv)) for lv in levels])
        band_lo = binom.ppf(0.025, zs.size, levels) / zs.size
        band_hi = binom.ppf(0.975, zs.size, levels) / zs.size
        a3.fill_between(levels, band_lo, band_hi, color="0.85", label=f"binomial 95 % band ({zs.size} trips)")
        a3.plot(levels, emp, "-", lw=1.5, label="held-out trips inside")
        a3.axvline(result.interval, color="0.5", lw=0.8, ls="--")
    a3.set(xlim=(0, 1), ylim=(0, 1), xlabel="nominal level of the central interval",
           ylabel="share of held-out trips inside", title="coverage of the intervals")
    a3.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)


def plot_simulation(frame, res, path: Path, title: str) -> None:
    """State of charge (EV, the paper's figure 4) or fuel used (ICE, figure 6) against
    time, with the elevation, from :meth:`SimulationResult.to_frame` (or a mapping of
    those columns: ``time_s``, ``soc_pct`` or ``fuel_cum_l``, ``elevation_m``)."""
    fig = _figure((10, 4.5))
    ax = fig.subplots()
    t_min = frame["time_s"] / 60.0
    if res.powertrain == "ev":
        ax.plot(t_min, frame["soc_pct"], label="state of charge")
        ax.set_ylabel("state of charge [%]")
    else:
        ax.plot(t_min, frame["fuel_cum_l"], label="fuel used")
        ax.set_ylabel("fuel used [l]")
    ax.set_xlabel("time [min]")
    ax.set_title(title)
    if "elevation_m" in frame:
        ax2 = ax.twinx()
        ax2.plot(t_min, frame["elevation_m"], color="0.6", lw=0.8, label="elevation")
        ax2.set_ylabel("elevation [m]")
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path) -> None:
    """Write the figure to ``path`` (PNG, or the format its suffix names) whole or not at
    all (:class:`cevm.io.outputs.OutFile`): a failed write (a full disk) is an
    :class:`~cevm.errors.OutputError` naming the file (exit 3), and leaves no half-written
    file. The figure goes to a file cevm opened, not to a path: matplotlib, given a path,
    wrote to ``/dev/full`` without a word."""
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    try:
        with OutFile(path, binary=True) as fh:
            fig.savefig(fh, format=fmt, dpi=120)
    except OSError as exc:
        raise OutputError(os_error_text(exc, str(path))) from None


def vehicle_label(vehicle) -> str:
    """A vehicle in a legend: its name and its id (two calibrations of one vehicle share
    a name, never an id)."""
    name = printable(vehicle.name)
    return name if not vehicle.id or vehicle.id == vehicle.name else f"{name} [{printable(vehicle.id)}]"


def plot_predictions(path: Path, sources: list[Source], pset: PredictionSet | Sequence[PredictionSet],
                     sweep_data: list, soc_start: float | Sequence[float], reserve_pct: float,
                     ice_braking: str | None,
                     warn: Callable[[str], None] | None = None) -> None:
    """SoC (EV) or fuel (ICE) along each source for each vehicle (one mass each: the
    paper's figure 4), or energy / fuel against payload when vehicles have several
    masses. ``pset``: one prediction set for every source, or one per source (each
    stored trip at its own mass); ``soc_start`` [%]: one for every source, or one per
    source (a stored trip's logged start). ``warn`` is called with a message when only the first
    :data:`PLOT_MAX_LINES` (source, vehicle) pairs are drawn."""
    per_source = list(pset) if isinstance(pset, (list, tuple)) else None
    first = cast("PredictionSet", per_source[0] if per_source else pset)  # the first set gives the vehicles
    from cevm.core.sweep import energy_trajectory

    counts = np.bincount(first.vehicle_index)
    pairs = [(s, v) for s in range(len(sources)) for v in range(len(first.vehicles))]
    if len(pairs) > PLOT_MAX_LINES:
        if warn is not None:
            warn(f"cevm: warning: --plot draws the first {PLOT_MAX_LINES} of {len(pairs)} (source, vehicle) pairs")
        pairs = pairs[:PLOT_MAX_LINES]
    has_ev = any(first.vehicles[v].is_ev for _, v in pairs)
    has_ice = any(not first.vehicles[v].is_ev for _, v in pairs)
    n_ax = int(has_ev) + int(has_ice)
    fig = _figure((9, 4.5 * n_ax))
    axes = fig.subplots(n_ax, 1, squeeze=False)
    ax_ev = axes[0, 0] if has_ev else None
    ax_ice = axes[-1, 0] if has_ice else None

    def axis(veh: Vehicle) -> Any:
        ax = ax_ev if veh.is_ev else ax_ice
        assert ax is not None  # has_ev / has_ice
        return ax
    if counts.max() > 1:  # a mass sweep: energy against payload (or mass)
        use_payload = bool(np.all(np.isfinite(first.payload_kg)))
        xname = "payload [kg]" if use_payload else "gross mass [kg]"
        for s, v in pairs:
            sel = first.vehicle_index == v
            x = (first.payload_kg if use_payload else first.mass_kg)[sel]
            veh = first.vehicles[v]
            ys = sweep_data[s]
            label = f"{vehicle_label(veh)} on {printable(sources[s].name)}"
            axis(veh).plot(x, ys["energy_kwh" if veh.is_ev else "fuel_l"][sel], marker="o", ms=3, label=label)
            over = first.over_max_gross[sel]
            if over.any():
                axis(veh).plot(x[over], (ys["energy_kwh"] if veh.is_ev else ys["fuel_l"])[sel][over], "x", color="red")
        if ax_ev is not None:
            ax_ev.set(xlabel=xname, ylabel="battery energy [kWh]",
                      title="EV energy against load (x: over max_gross_kg)")
        if ax_ice is not None:
            ax_ice.set(xlabel=xname, ylabel="fuel [l]", title="ICE fuel against load (x: over max_gross_kg)")
    else:  # state of charge along the route (the paper's figure 4)
        for s, v in pairs:
            veh = first.vehicles[v]
            ps = per_source[s] if per_source else first
            m = float(ps.mass_kg[ps.vehicle_index == v][0])
            _, dist, e = energy_trajectory(sources[s], veh, m, ice_braking=ice_braking)
            label = f"{vehicle_label(veh)} on {printable(sources[s].name)} ({m:,.0f} kg)"
            if veh.is_ev:
                assert veh.battery_j is not None  # an EV's (vehicle files require it)
                soc = (soc_start[s] if isinstance(soc_start, (list, tuple)) else soc_start) - 100.0 * e / veh.battery_j
                empty = np.flatnonzero(soc < 0)
                if empty.size:  # the line ends where the battery runs empty: no charge below 0
                    soc = soc.copy()
                    soc[empty[0]:] = np.nan
                    label += f", empty at {dist[empty[0]] / 1000.0:,.1f} km"
                axis(veh).plot(dist / 1000.0, soc, label=label)
            else:
                axis(veh).plot(dist / 1000.0, e, label=label)
        if ax_ev is not None:
            ax_ev.axhline(reserve_pct, color="red", ls="--", lw=1, label=f"reserve {reserve_pct:g} %")
            ax_ev.set(xlabel="distance [km]", ylabel="state of charge [%]", title="State of charge along the route")
        if ax_ice is not None:
            ax_ice.set(xlabel="distance [km]", ylabel="fuel burnt [l]", title="Fuel along the route")
    for ax in axes[:, 0]:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
