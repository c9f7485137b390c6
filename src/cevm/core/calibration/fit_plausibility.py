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
from collections.abc import Mapping

import numpy as np

from cevm.core.calibration.solve import FitLike, bounds, value_covariance
from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel
from cevm.core.uncertainty import plausible_range

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


def implausible(model: TermModel, fit: FitLike, idx: np.ndarray, lb: np.ndarray | None = None,
                ub: np.ndarray | None = None,
                plausible: Mapping[str, tuple[float, float]] | None = None) -> tuple[str, str] | None:
    """The first term whose fitted value physics refuses, with the reason (see the module
    docstring); eta included. ``fit`` has ``names``, ``theta`` (coefficients), ``cov``
    (their covariance) and ``free`` (the estimate without bounds); ``lb``, ``ub`` the
    coefficients' bounds in the fit (default :func:`.solve.bounds`); ``plausible`` ranges
    that replace the terms' own (:func:`cevm.core.uncertainty.plausible_range`)."""
    pt = model.vehicle.powertrain
    values, _ = value_covariance(model, fit)
    csd = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    if lb is None or ub is None:
        lb, ub = bounds(model, fit.names)
    for j, name in enumerate(fit.names):
        t = TERMS_BY_POWERTRAIN[(pt, name)]
        v = float(values[name])
        lo, hi = plausible_range(pt, name, plausible)
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
        # a negative power or rate, or (eta's coefficient 1/eta at its lower bound) an
        # efficiency above what the powertrain reaches
        free = float(fit.free[j])
        if not math.isfinite(csd[j]):
            continue
        low_bind = fit.theta[j] <= lb[j] + 1e-12 * max(1.0, abs(lb[j])) and free < lb[j] - 2 * csd[j]
        high_bind = fit.theta[j] >= ub[j] - 1e-12 * max(1.0, abs(ub[j])) and free > ub[j] + 2 * csd[j]
        if name == "eta" and low_bind:
            want = 1.0 / free if free > 0 else math.inf
            return name, (f"implausible: the data want a drive efficiency of {want:.3g}, above the "
                          f"{_fmt(model, name, hi)} a {'battery-electric drive' if model.ev else 'combustion engine'}"
                          f" reaches: {_LESS_THAN_THE_WHEELS}")
        if name == "eta" and high_bind:
            return name, (f"implausible: the data want a drive efficiency of {1.0 / free:.3g}, below the "
                          f"{_fmt(model, name, lo)} of any {'EV' if model.ev else 'combustion engine'} (masses too "
                          "low, or a consumption column in the wrong unit?)")
        if name == "kin":
            continue
        if low_bind:
            return name, (f"implausible: the data want {t.label} = {_fmt(model, name, free)}, below "
                          f"{_fmt(model, name, lb[j])} by more than 2 standard errors: the term does not describe "
                          "these trips")
        if high_bind:
            return name, (f"implausible: the data want {t.label} = {_fmt(model, name, free)}, above the plausible "
                          f"{_fmt(model, name, ub[j])} by more than 2 standard errors")
    share = model.nontraction(fit.names, fit.theta)[idx] / model.data.y[idx]
    if share.size and float(share.max()) > MAX_NONTRACTION_SHARE:
        i = int(np.argmax(share))
        extra = [n for n in fit.names if n in ("aux", "heat", "cool", "warm", "idle", "run")]
        return (extra[-1] if extra else "eta"), (
            f"implausible: {', '.join(extra)} would take {100 * share[i]:.0f} % of trip "
            f"{model.data.ids[idx[i]]}'s measured consumption")
    ev = evidence(model, fit, idx)
    # the model's standstill rate against the logs' (also for a model without an
    # auxiliary or idle term, which draws nothing standing still)
    base = "aux" if model.ev else "idle"
    if ev is not None and ev["ratio"] is not None:
        r = ev["ratio"]
        if r > EVIDENCE_RATIO or r < 1.0 / EVIDENCE_RATIO:
            what = "battery power" if model.ev else "fuel flow"
            has = base in fit.names or (model.vehicle_values().get(base, 0.0) or 0.0) > 0
            model_text = (f"the fitted standstill rate {ev['fitted_text']} is {r:.1f} times" if has else
                          f"the model draws {ev['fitted_text']} standing still (it has no "
                          f"{'auxiliary-power' if model.ev else 'idle'} term), against")
            return base, (f"implausible: {model_text} the {what} the logs measured standing still "
                          f"({ev['measured_text']} over {ev['seconds'] / 60:.0f} min)")
    return None


def evidence(model: TermModel, fit: FitLike, idx: np.ndarray) -> dict | None:
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
        def text(x: float) -> str:
            return f"{x / 1e3:.2f} kW"
    else:
        def text(x: float) -> str:
            return f"{x * 3600:.2f} l/h"
    return {"seconds": total, "trips": int(ok.sum()), "measured": measured, "fitted": fitted,
            "ratio": fitted / measured if measured > 0 else None, "measured_text": text(measured),
            "fitted_text": text(fitted)}
