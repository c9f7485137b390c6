"""The figures of ``cevm calibrate``, ``cevm simulate`` and ``cevm predict`` (PNG files,
matplotlib with the Agg backend, imported when a figure is drawn)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm.core.calibration import CalibrationResult, display_value


def plot_calibration(result: CalibrationResult, path: Path, title: str) -> None:
    """Predicted against measured with the 1:1 line (the paper's figures 5 and 7), and the
    percent error against trip distance, in-sample and cross-validated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    unit = "kWh" if result.unit == "J" else "l"
    meas = np.array([display_value(result, r.measured) for r in result.rows])
    ins = np.array([display_value(result, r.predicted_in_sample) for r in result.rows])
    cv = np.array([display_value(result, r.predicted_cv) for r in result.rows])
    dist = np.array([r.distance_m for r in result.rows]) / 1e3
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.8))
    lim = [0, max(meas.max(), np.nanmax(cv) if np.isfinite(cv).any() else 0, ins.max()) * 1.05]
    a1.plot(lim, lim, "k-", lw=1, label="1:1")
    a1.scatter(meas, ins, s=18, label="CE model, in-sample")
    if np.isfinite(cv).any():
        a1.scatter(meas, cv, s=18, marker="x", label="CE model, cross-validated")
    a1.set(xlim=lim, ylim=lim, xlabel=f"measured [{unit}]", ylabel=f"modelled [{unit}]", title=title)
    a1.legend()
    a2.axhline(0, color="k", lw=1)
    a2.scatter(dist, [r.error_pct_in_sample for r in result.rows], s=18, label="in-sample")
    if np.isfinite(cv).any():
        a2.scatter(dist, [r.error_pct_cv for r in result.rows], s=18, marker="x", label="cross-validated")
    a2.set(xlabel="trip distance [km]", ylabel="error (modelled - measured) / measured [%]")
    a2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
