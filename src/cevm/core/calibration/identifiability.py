"""Which terms the trips can identify (pure).

Before a fit (:func:`unsupported`): a term needs k + 2 usable trips for k terms, a feature
that is not zero on every trip, and for the temperature terms trips that carry a
temperature on the side of the balance temperature that drives them, at least
:data:`MIN_TRIPS_PER_TERM` of them on :data:`MIN_GROUPS_PER_TERM` days, spread over at
least :data:`MIN_SPREAD_K`.

After a fit:

- :func:`confounded`: the multiple correlation of a term's weighted Jacobian column with
  the others' exceeds ``max_correlation`` (0.98; for two terms this is abs(correlation of
  the estimates)). Example: aux power and 1/eta when every trip has the same speed
  profile and mass (aux energy ~ duration ~ distance / speed, traction ~ distance).
- :func:`imprecise`: its standard error exceeds ``max_rel_se`` (50 %) of max(abs(value),
  reference), the reference being 10 % of the median consumption rate y_i / D_i for the
  rate terms (so a well-measured zero is accepted), abs(value) otherwise.

With priors (:mod:`.priors`) a term the trips cannot identify is not dropped: it keeps
its prior, and these functions say why the data could not tell.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cevm.core.calibration.solve import FitLike, value_covariance
from cevm.core.calibration.terms import TERMS_BY_POWERTRAIN, TermModel

#: A temperature term needs at least this many trips on the side of its balance
#: temperature that drives it, on at least this many days, spread over this many kelvin.
MIN_TRIPS_PER_TERM = 3
MIN_GROUPS_PER_TERM = 2
MIN_SPREAD_K = 3.0


def _hint(model: TermModel, name: str) -> str:
    return TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, name)].hint


def unsupported(model: TermModel, names: Sequence[str], idx: np.ndarray) -> tuple[str, str] | None:
    """The first term (never eta) the trips ``idx`` cannot support, with the reason."""
    data = model.data
    n = len(idx)
    k = len(names)
    if n < k + 2:
        return names[-1], f"needs at least {k + 2} usable trips to fit {k} parameters, {n} are usable"
    vals = model.vehicle_values()
    groups = np.array([g if g is not None else f"\0{i}" for i, g in enumerate(data.groups)], dtype=object)[idx]
    for name in names:
        if name == "eta":
            continue
        t = TERMS_BY_POWERTRAIN[(model.vehicle.powertrain, name)]
        if t.temperature:
            missing = int(np.sum(~np.isfinite(data.ambient_c[idx])))
            if missing:
                return name, (f"not identifiable: {missing} of {n} trips have no ambient temperature "
                              "(map the logger's temperature column in its profile)")
            f = model.h[idx] if name in ("heat", "warm") else model.c[idx]
            side = (f"colder than {model.vehicle.heating_below_c:g} degC" if name in ("heat", "warm")
                    else f"warmer than {model.vehicle.cooling_above_c:g} degC")
            on = f > 0
            if on.sum() < MIN_TRIPS_PER_TERM or len(set(groups[on])) < MIN_GROUPS_PER_TERM:
                return name, (f"not identifiable: {int(on.sum())} of {n} trips ({len(set(groups[on]))} days) are "
                              f"{side}; needs {MIN_TRIPS_PER_TERM} on {MIN_GROUPS_PER_TERM} days ({t.hint})")
            spread = float(np.ptp(f))  # of the kelvin of demand over all the trips: 0 where none
            if spread < MIN_SPREAD_K:
                return name, (f"not identifiable: the trips' kelvin of {'cooling' if name == 'cool' else 'heating'} "
                              f"demand span {spread:.1f} K; needs {MIN_SPREAD_K:g} K (temperatures that differ, "
                              f"some of them {side}; {t.hint})")
        if t.linear:
            col = model.feature(name, vals["cda"], vals["cr"])[idx]
            if not np.any(np.abs(col) > 0):
                return name, f"has no effect on any used trip ({t.hint})"
    return None


def confounded(jw: np.ndarray, names: Sequence[str], max_correlation: float,
               model: TermModel) -> tuple[str, str] | None:
    """The extra term (never eta) to refuse for a weak or confounded Jacobian column."""
    norms = np.linalg.norm(jw, axis=0)
    for j in reversed(range(len(names))):
        if names[j] != "eta" and not norms[j] > 0:
            return names[j], f"has no effect on any used trip ({_hint(model, names[j])})"
    if len(names) < 2:
        return None
    jn = jw / norms
    cos = jn.T @ jn
    mult = np.zeros(len(names))
    for j in range(len(names)):
        others = np.delete(jn, j, axis=1)
        coef, *_ = np.linalg.lstsq(others, jn[:, j], rcond=None)
        resid = jn[:, j] - others @ coef
        mult[j] = math.sqrt(max(0.0, 1.0 - float(resid @ resid)))
    worst, worst_r = None, -1.0
    for j, name in enumerate(names):
        if name != "eta" and mult[j] > max_correlation and mult[j] >= worst_r - 1e-9:
            worst, worst_r = j, mult[j]
    if worst is None:
        return None
    c = np.abs(cos[worst]).copy()
    c[worst] = -1
    partner = names[int(np.argmax(c))]
    with_ = partner if len(names) == 2 else f"{', '.join(n for n in names if n != names[worst])} (mostly {partner})"
    return names[worst], (
        f"not identifiable: its effect on the trips is confounded with {with_} "
        f"(correlation {worst_r:.4f} > {max_correlation:g}); {_hint(model, names[worst])}"
    )


def imprecise(model: TermModel, fit: FitLike, idx: np.ndarray, max_rel_se: float) -> tuple[str, str] | None:
    """The extra term whose standard error is too large for it to mean anything."""
    data = model.data
    values, cov = value_covariance(model, fit)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    rate = float(np.median(data.y[idx] / data.duration[idx]))
    worst, worst_ratio, worst_ref = None, max_rel_se, 0.0
    for j, name in enumerate(fit.names):
        if name == "eta":
            continue
        ref = 0.1 * rate if name in ("aux", "idle", "run") else 0.0
        scale = max(abs(float(values[name])), ref)
        ratio = sd[j] / scale if scale > 0 and math.isfinite(sd[j]) else math.inf
        if ratio > worst_ratio:
            worst, worst_ratio, worst_ref = j, ratio, ref
    if worst is None:
        return None
    name = fit.names[worst]
    value = float(values[name])
    of = (f"its value {value:.3g}" if abs(value) >= worst_ref
          else f"the reference {worst_ref:.3g} (10 % of the median consumption rate)")
    return name, (
        f"not identifiable: {value:.3g} +- {sd[worst]:.3g}, a standard error of {100 * worst_ratio:.0f} % of "
        f"{of} (limit {100 * max_rel_se:.0f} %); {_hint(model, name)}"
    )
