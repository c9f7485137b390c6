"""Which fitted values physics refuses, and the logs' standstill evidence (pure).

:func:`implausible`: a value outside the term's physical range (:class:`~.terms.Term`
``plausible``): an efficiency above what a powertrain reaches or below what any reaches,
a negative power or rate the bounds only hid (the unbounded estimate more than 2
standard errors below 0); terms that take more than the trip's whole measured
consumption; a standstill rate (the model's: an EV's auxiliary power at the trips'
temperatures, an ICE's idle, heating and cooling fuel) several times
(:data:`EVIDENCE_RATIO`) the rate the logs measured while standing still (battery power,
fuel flow), or a fraction of it, whether or not the model has an auxiliary or idle term
(without one, it draws nothing standing still: that is what the logs contradict).
"""

from __future__ import annotations

import math

import numpy as np

from cevm.core.calibration.solve import Fit, bounds, value_covariance
from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel

#: A fitted standstill rate more than this factor above (or below 1 / this) the
#: measured one is refused.
EVIDENCE_RATIO = 3.0
#: Standstill measured over less than this, in all, is not evidence enough [s].
EVIDENCE_MIN_S = 300.0
#: Non-traction terms may take at most this share of any trip's measured consumption.
MAX_NONTRACTION_SHARE = 1.0

_LESS_THAN_THE_WHEELS = ("the trips measured less energy than their wheels needed (masses too high, elevation "
                         "wrong, or a consumption column in the wrong unit?)")


def _fmt(model: TermModel, name: str, value: float) -> str:
    unit, scale = TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, name)].display
    return f"{value * scale:.3g} {unit}".strip()


def implausible(model: TermModel, fit: Fit, idx: np.ndarray) -> tuple[str, str] | None:
    """The first term whose fitted value physics refuses, with the reason (see the module
    docstring); eta included."""
    pt = model.vehicle.powertrain
    values, cov = value_covariance(model, fit)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    lb, _ = bounds(model, fit.names)
    for j, name in enumerate(fit.names):
        t = TERMS_BY_POWERTRAIN[(pt, name)]
        v = float(values[name])
        lo, hi = t.plausible
        if not math.isfinite(v) or v < lo or v > hi:
            if name in ("eta", "regen", "kin") and v > 1:
                why = f"above 1: {_LESS_THAN_THE_WHEELS}"
            else:
                why = f"outside the plausible {_fmt(model, name, lo)} to " + (
                    _fmt(model, name, hi) if math.isfinite(hi) else "infinity")
                if name == "eta":
                    why += f" for {'an EV' if model.ev else 'a combustion engine'}"
            return name, f"implausible: {t.label} {_fmt(model, name, v)} is {why}"
        # a bound that binds where the free estimate is clearly beyond it: the data want
        # a negative power or rate, or (eta's coefficient 1/eta below 1) an efficiency
        # above 1; the coefficient's standard error is sd_eta / eta^2
        free = float(fit.free[j])
        sd_coef = sd[j] * (fit.theta[j] ** 2 if name == "eta" else 1.0)
        if fit.theta[j] <= lb[j] + 1e-12 and math.isfinite(sd_coef) and free < lb[j] - 2 * sd_coef:
            if name == "eta":
                want = 1.0 / free if free > 0 else math.inf
                return name, f"implausible: the data want a drive efficiency of {want:.3g}: {_LESS_THAN_THE_WHEELS}"
            return name, (f"implausible: the data want {t.label} = {_fmt(model, name, free)}, below "
                          f"{_fmt(model, name, lb[j])} by more than 2 standard errors: the term does not describe "
                          "these trips")
    share = model.nontraction(fit.names, fit.theta)[idx] / model.data.y[idx]
    if share.size and float(share.max()) > MAX_NONTRACTION_SHARE:
        i = int(np.argmax(share))
        extra = [n for n in fit.names if n in ("aux", "heat", "cool", "warm", "idle", "run")]
        return (extra[-1] if extra else "eta"), (
            f"implausible: {', '.join(extra)} would take {100 * share[i]:.0f} % of trip "
            f"{model.data.ids[idx[i]]}'s measured consumption")
    ev = evidence(model, fit, idx)
    # the term meant to be the standstill rate: an EV's auxiliary power, an ICE's idle
    # rate (without it, a standstill load is absorbed by eta and comparing says nothing)
    base = "aux" if model.ev else "idle"
    if ev is not None and ev["ratio"] is not None and base in fit.names:
        r = ev["ratio"]
        if r > EVIDENCE_RATIO or r < 1.0 / EVIDENCE_RATIO:
            what = "battery power" if model.ev else "fuel flow"
            return base, (f"implausible: the fitted standstill rate {ev['fitted_text']} is {r:.1f} times the "
                          f"{what} the logs measured standing still ({ev['measured_text']} over "
                          f"{ev['seconds'] / 60:.0f} min)")
    return None


def evidence(model: TermModel, fit: Fit, idx: np.ndarray) -> dict | None:
    """The modelled standstill rate against the one the logs measured (EV: battery power
    while standing still; ICE: fuel flow at idle), standstill-time weighted over the
    trips ``idx`` that measured it; None when less than :data:`EVIDENCE_MIN_S` was
    measured."""
    data = model.data
    s = data.standstill_s[idx]
    r = data.standstill_rate[idx]
    ok = np.isfinite(s) & np.isfinite(r) & (s > 0)
    total = float(s[ok].sum())
    if total < EVIDENCE_MIN_S:
        return None
    measured = float(np.sum(s[ok] * r[ok]) / total)
    fitted = float(np.sum(s[ok] * model.standstill_rate(fit.names, fit.theta)[idx][ok]) / total)
    if model.ev:
        def text(x):
            return f"{x / 1e3:.2f} kW"
    else:
        def text(x):
            return f"{x * 3600:.2f} l/h"
    return {"seconds": total, "trips": int(ok.sum()), "measured": measured, "fitted": fitted,
            "ratio": fitted / measured if measured > 0 else None, "measured_text": text(measured),
            "fitted_text": text(fitted)}
