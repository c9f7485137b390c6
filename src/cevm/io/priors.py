"""The priors of a vehicle's terms: the shipped class defaults
(``configs/priors/classes.toml``) and a vehicle file's ``class`` key and ``[prior]``
table, as a :class:`cevm.core.uncertainty.Priors`; and the ``[posterior]`` table a
calibration writes, as a :class:`cevm.core.uncertainty.Posterior`.

A vehicle file::

    class = "bus"                  # bus, truck, van, car, quadricycle; else inferred
                                   #   from the mass (and said so)
    [prior]                        # optional: ranges that override the class's
    eta = [0.75, 0.85]             #   [low, high], about 95 %, the keys' own units
    aux_power_kw = [3.0, 6.0]
    scatter_aux_kw = 1.0           #   the trip-to-trip scatter (EV: kW, ICE: l/h)
    scatter_share = 0.05
    [prior.sources]                #   where each range comes from (optional)
    eta = "the maker's data sheet"

    [posterior]                    # written by cevm calibrate (read back here)
    source = "calibrated on 26 trips of EB-01, 2019-01-31..2019-08-27"
    n_trips = 26
    terms = ["eta", "aux", "heat", "cool"]
    std = [0.012, 0.4, 0.05, 0.03]         # each term's key's unit (eta, kW, kW/K ...)
    correlation = [[1.0, ...], ...]         # of the values
    meter_share = 0.02
    [posterior.scatter]
    aux_kw = 0.8                   # or aux_lph (ICE)
    share = 0.04
    day_correlation = 1.0
    day_correlation_note = "..."
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np

from cevm.configs_dir import shipped_configs_dir
from cevm.core.terms import EXTRA_TERMS, PHYSICAL, TERMS_BY_POWERTRAIN
from cevm.core.uncertainty import (
    VEHICLE_CLASSES,
    Posterior,
    Priors,
    Scatter,
    ScatterPrior,
    TermPrior,
    coefficient_covariance,
    value_covariance,
)
from cevm.core.vehicle import coefficients
from cevm.errors import InputError
from cevm.io.toml import read_toml
from cevm.units import J_PER_KWH

#: The shipped class defaults, relative to the configs directory.
CLASSES_FILE = Path("priors") / "classes.toml"


def classes_path() -> Path:
    return shipped_configs_dir() / CLASSES_FILE


def _file_keys(powertrain: str) -> dict[str, tuple[str, float]]:
    """vehicle-file key -> (term, factor from SI) of the powertrain's energy terms."""
    out = {}
    for name in ("eta", *EXTRA_TERMS[powertrain]):
        t = TERMS_BY_POWERTRAIN[(powertrain, name)]
        out[t.file[0]] = (name, t.file[1])
    return out


def _scatter_key(powertrain: str) -> tuple[str, float]:
    """The file key and SI factor of the class scatter's auxiliary part."""
    return ("scatter_aux_kw", 1e-3) if powertrain == "ev" else ("scatter_aux_lph", 3600.0)


def _trip_key(powertrain: str) -> tuple[str, float]:
    """The file key and SI factor of the class scatter's part that does not grow with a
    trip (:class:`cevm.core.uncertainty.Scatter` ``trip``)."""
    return ("scatter_trip_kwh", 1.0 / J_PER_KWH) if powertrain == "ev" else ("scatter_trip_l", 1.0)


def _range(value: Any, where: str, source: str | Path) -> tuple[float, float]:
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)
            or value[0] > value[1]):
        raise InputError(source, f"key '{where}' must be a range [low, high] of two numbers, low <= high; "
                                 f"got {value!r}")
    return float(value[0]), float(value[1])


def _positive(value: Any, where: str, source: str | Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise InputError(source, f"key '{where}' must be a number > 0, got {value!r}")
    return float(value)


def _check_plausible(powertrain: str, term: str, key: str, lo_si: float, hi_si: float, where: str,
                     source: str | Path) -> None:
    t = TERMS_BY_POWERTRAIN[(powertrain, term)]
    plo, phi = t.plausible
    if lo_si < plo - 1e-12 * max(1.0, abs(plo)) or hi_si > phi + 1e-12 * max(1.0, abs(phi)):
        f = t.file[1]
        raise InputError(source, f"key '{where}' = [{lo_si * f:g}, {hi_si * f:g}] leaves the physical range "
                                 f"{plo * f:g} to {phi * f:g} of {key} ({t.label})")


#: A stated spec-sheet value's 95 % range as factors of it, by key: the file key and the
#: name a :class:`Priors` ``spec`` entry carries.
SPEC_KEYS = {"cda_m2_factor": "cda", "cr_factor": "cr"}


def _table_priors(table: dict, powertrain: str, where: str, source: str | Path, default_source: str,
                  prefix: str) -> tuple[dict[str, TermPrior], dict[str, float]]:
    """The term ranges and scatter numbers of a class or [prior] table (the spec-sheet
    factors: :func:`_spec`)."""
    keys = _file_keys(powertrain)
    sc_key, sc_f = _scatter_key(powertrain)
    tr_key, tr_f = _trip_key(powertrain)
    sources = table.get("sources", {})
    if not isinstance(sources, dict):
        raise InputError(source, f"key '{where}.sources' must be a table of texts")
    terms: dict[str, TermPrior] = {}
    scatter: dict[str, float] = {}
    for key, value in table.items():
        if key in ("sources", "class_from") or key in SPEC_KEYS:
            continue
        if key == sc_key:
            scatter["aux"] = _positive(value, f"{where}.{key}", source) / sc_f
            continue
        if key == "scatter_share":
            scatter["share"] = _positive(value, f"{where}.{key}", source)
            continue
        if key == tr_key:
            scatter["trip"] = _positive(value, f"{where}.{key}", source) / tr_f
            continue
        if key not in keys:
            other = _scatter_key("ice" if powertrain == "ev" else "ev")[0]
            hint = (f" (an {'EV' if powertrain == 'ev' else 'ICE'} vehicle's is '{sc_key}')" if key == other else "")
            allowed = ", ".join([*keys, sc_key, "scatter_share", tr_key, *SPEC_KEYS])
            raise InputError(source, f"unknown key '{where}.{key}'{hint}; a prior may set {allowed}")
        term, factor = keys[key]
        lo, hi = _range(value, f"{where}.{key}", source)
        lo_si, hi_si = lo / factor, hi / factor
        _check_plausible(powertrain, term, key, lo_si, hi_si, f"{where}.{key}", source)
        text = sources.get(key)
        terms[term] = TermPrior(term, lo_si, hi_si, f"{prefix}{text}" if text else default_source)
    return terms, scatter


def _spec(table: dict, where: str, source: str | Path) -> dict[str, tuple[float, float]]:
    """The spec-sheet factors of a class or [prior] table: name -> (low, high), 0 < low
    <= 1 <= high (a range around the stated value)."""
    out = {}
    for key, name in SPEC_KEYS.items():
        if key in table:
            lo, hi = _range(table[key], f"{where}.{key}", source)
            if not 0 < lo <= 1.0 <= hi:
                raise InputError(source, f"key '{where}.{key}' = [{lo:g}, {hi:g}] must hold 1 (the stated value) "
                                         "between factors > 0")
            out[name] = (lo, hi)
    return out


@functools.lru_cache(maxsize=4)
def _load_classes(path_text: str) -> dict:
    path = Path(path_text)
    data = read_toml(path, "prior class defaults")
    by_mass = data.get("classes_by_mass")
    if not isinstance(by_mass, dict):
        raise InputError(path, "missing table [classes_by_mass]")
    out: dict = {"by_mass": by_mass, "classes": {}}
    for cls in VEHICLE_CLASSES:
        for pt in ("ev", "ice"):
            table = (data.get(cls) or {}).get(pt)
            if not isinstance(table, dict):
                raise InputError(path, f"missing table [{cls}.{pt}]")
            terms, scatter = _table_priors(table, pt, f"{cls}.{pt}", path, f"class default ({cls})",
                                           f"class {cls}: ")
            missing = [k for k in _file_keys(pt) if _file_keys(pt)[k][0] not in terms]
            if missing or set(scatter) != {"aux", "share", "trip"}:
                raise InputError(path, f"table [{cls}.{pt}] lacks {', '.join(missing) or 'its scatter'}")
            sources = table.get("sources", {})
            sc_key = _scatter_key(pt)[0]
            out["classes"][(cls, pt)] = (terms, ScatterPrior(scatter["aux"], scatter["share"],
                                                             f"class {cls}: {sources.get(sc_key, 'class default')}",
                                                             scatter["trip"]), _spec(table, f"{cls}.{pt}", path))
    return out


def class_defaults(path: str | Path | None = None) -> dict:
    """The parsed class defaults: {"by_mass": ..., "classes": {(class, powertrain):
    (term -> TermPrior, ScatterPrior, spec-sheet factors)}} (cached)."""
    return _load_classes(str(classes_path() if path is None else Path(path)))


def infer_class(mass_kg: float, powertrain: str, defaults: dict) -> tuple[str, str]:
    """(class, how it was decided) from the gross mass and the powertrain."""
    bm = defaults["by_mass"]
    if mass_kg < float(bm["quadricycle_below_kg"]):
        cls = "quadricycle"
    elif mass_kg < float(bm["car_below_kg"]):
        cls = "car"
    elif mass_kg < float(bm["van_below_kg"]):
        cls = "van"
    else:
        cls = str(bm["heavy_ev" if powertrain == "ev" else "heavy_ice"])
    heavy = "; a heavy EV is taken as a bus" if cls == "bus" else ""
    return cls, f"inferred from its mass {mass_kg:,.0f} kg (no 'class' key{heavy})"


def priors_from_mapping(data: dict, powertrain: str, mass_kg: float, source: str | Path,
                        defaults: dict | None = None) -> Priors:
    """The :class:`Priors` of a parsed vehicle file: its class's defaults (the ``class``
    key, else inferred from the mass), overridden by its ``[prior]`` table."""
    defaults = class_defaults() if defaults is None else defaults
    cls = data.get("class")
    if cls is None:
        cls, how = infer_class(mass_kg, powertrain, defaults)
    else:
        if cls not in VEHICLE_CLASSES:
            raise InputError(source, f"key 'class' must be one of {', '.join(VEHICLE_CLASSES)}; got {cls!r}")
        how = "vehicle file"
    terms, scatter, spec = defaults["classes"][(cls, powertrain)]
    terms, spec = dict(terms), dict(spec)
    table = data.get("prior")
    sc = scatter
    if table is not None:
        if not isinstance(table, dict):
            raise InputError(source, "key 'prior' must be a table")
        own, own_sc = _table_priors(table, powertrain, "prior", source, "vehicle file [prior]",
                                    "vehicle file [prior]: ")
        terms.update(own)
        if own_sc:
            sc = ScatterPrior(own_sc.get("aux", scatter.aux), own_sc.get("share", scatter.share),
                              "vehicle file [prior]", own_sc.get("trip", scatter.trip))
        if isinstance(table.get("class_from"), str) and data.get("class") is not None:
            how = table["class_from"]
        spec.update(_spec(table, "prior", source))
    order = ("eta", *EXTRA_TERMS[powertrain])
    return Priors(vehicle_class=str(cls), class_from=how, terms=tuple(terms[n] for n in order if n in terms),
                  scatter=sc, sources=str(CLASSES_FILE),
                  spec=tuple((n, lo, hi) for n, (lo, hi) in sorted(spec.items())))


def with_prior_values(vehicle, data: dict):
    """``vehicle`` with each term every vehicle has (:data:`cevm.core.terms.PHYSICAL`)
    that the parsed file ``data`` leaves out at its prior's central value (the middle of
    its range, :attr:`TermPrior.mean`) and listed in ``from_prior``. What a file does not
    state is unknown, not zero: a car without a heating key still heats in the cold,
    within its class's range (the predictive distribution spans that range,
    :mod:`cevm.core.predictive`). A stated value is kept, zero too (a quadricycle without
    a heater). Without priors (none apply) the vehicle is returned as it is."""
    from dataclasses import replace

    pr = vehicle.priors
    if pr is None:
        return vehicle
    pt = vehicle.powertrain
    values: dict = {}
    names: list[str] = []
    for name in PHYSICAL[pt]:
        t = TERMS_BY_POWERTRAIN[(pt, name)]
        p = pr.get(name)
        if t.file[0] in data or p is None:
            continue
        values[t.field] = p.mean
        names.append(name)
    return replace(vehicle, **values, from_prior=tuple(names)) if names else vehicle


def prior_values_note(vehicle) -> str | None:
    """What a vehicle took from its priors, for a note beside its rows: the terms its
    file leaves out at their central values in file units, with its class and how the
    class was decided; for a file that states every term but no ``class``, the class
    inferred from its mass whose priors its intervals use; None otherwise."""
    pr = vehicle.priors
    if pr is None:
        return None
    parts = []
    for name in vehicle.from_prior:
        t = TERMS_BY_POWERTRAIN[(vehicle.powertrain, name)]
        key, f = t.file
        parts.append(f"{key} {getattr(vehicle, t.field) * f:.3g}")
    if parts:
        return (f"{vehicle.label}: {', '.join(parts)} (not in its file) at the middle of the priors of "
                f"{pr.describe()}; their spread is in the intervals (column from_prior)")
    if pr.class_from.startswith("inferred"):
        return f"{vehicle.label}: its intervals use the priors of {pr.describe()}"
    return None


def prior_table(priors: Priors, powertrain: str) -> dict:
    """The ``[prior]`` table (file units) of ``priors``, with its sources: what a
    calibrated file records of the priors it was fitted with."""
    keys = {term: (key, f) for key, (term, f) in _file_keys(powertrain).items()}
    out: dict = {"class_from": priors.class_from}
    sources: dict = {}
    for p in priors.terms:
        key, f = keys[p.term]
        out[key] = [_round(p.low * f), _round(p.high * f)]
        sources[key] = p.source
    sc_key, sc_f = _scatter_key(powertrain)
    out[sc_key] = _round(priors.scatter.aux * sc_f)
    out["scatter_share"] = _round(priors.scatter.share)
    for key, name in SPEC_KEYS.items():
        for n, lo, hi in priors.spec:
            if n == name:
                out[key] = [_round(lo), _round(hi)]
    tr_key, tr_f = _trip_key(powertrain)
    out[tr_key] = _round(priors.scatter.trip * tr_f)
    sources[sc_key] = priors.scatter.source
    out["sources"] = sources
    return out


def _round(x: float) -> float:
    return float(f"{x:.6g}")


# ------------------------------------------------------------------ the posterior table


def posterior_table(posterior: Posterior, vehicle) -> dict:
    """The ``[posterior]`` table (file units) of a calibrated vehicle."""
    pt = vehicle.powertrain
    terms = posterior.terms
    coef = coefficients(vehicle, terms)
    vcov = value_covariance(terms, coef, posterior.cov)
    sd = np.sqrt(np.maximum(np.diag(vcov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = vcov / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    factors = [TERMS_BY_POWERTRAIN[(pt, t)].file[1] for t in terms]
    sc = posterior.scatter
    sc_key = "aux_kw" if pt == "ev" else "aux_lph"
    sc_f = 1e-3 if pt == "ev" else 3600.0
    scatter = {sc_key: _round(sc.aux * sc_f), "share": _round(sc.share), "day_correlation": _round(sc.day_corr),
               "day_correlation_note": sc.day_corr_note}
    if sc.standstill is not None:
        scatter["standstill_" + sc_key] = _round(sc.standstill * sc_f)
    tr_key, tr_f = ("trip_kwh", 1.0 / J_PER_KWH) if pt == "ev" else ("trip_l", 1.0)
    scatter[tr_key] = _round(sc.trip * tr_f)
    return {
        "source": posterior.source, "n_trips": int(posterior.n_trips), "terms": list(terms),
        "std": [_round(s * f) for s, f in zip(sd, factors, strict=True)],
        "correlation": [[round(float(x), 6) for x in row] for row in corr],
        "meter_share": _round(posterior.meter_share),
        "scatter": scatter,
    }


def posterior_from_mapping(table: Any, vehicle, priors: Priors | None, source: str | Path) -> Posterior | None:
    """A :class:`Posterior` from a vehicle file's ``[posterior]`` table (None if absent),
    at the vehicle's values (its coefficients' means)."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise InputError(source, "key 'posterior' must be a table")
    pt = vehicle.powertrain
    terms = table.get("terms")
    if not isinstance(terms, list) or not terms or not all(
            isinstance(t, str) and (pt, t) in TERMS_BY_POWERTRAIN for t in terms) or len(set(terms)) != len(terms):
        raise InputError(source, f"key 'posterior.terms' must list the model's terms, got {terms!r}")
    k = len(terms)
    std = table.get("std")
    if (not isinstance(std, list) or len(std) != k
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x >= 0
                       for x in std)):
        raise InputError(source, f"key 'posterior.std' must hold {k} numbers >= 0, got {std!r}")
    corr = table.get("correlation")
    try:
        C = np.array(corr, dtype=np.float64)
    except (TypeError, ValueError):
        C = np.zeros(0)
    if C.shape != (k, k) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T, atol=1e-6) \
            or np.any(np.abs(C) > 1 + 1e-9):
        raise InputError(source, f"key 'posterior.correlation' must be a symmetric {k} x {k} matrix of "
                                 "correlations")
    factors = np.array([TERMS_BY_POWERTRAIN[(pt, t)].file[1] for t in terms])
    sd = np.array(std, dtype=np.float64) / factors
    vcov = C * np.outer(sd, sd)
    if np.min(np.linalg.eigvalsh(vcov)) < -1e-9 * max(1.0, float(np.max(np.abs(vcov)))):
        raise InputError(source, "key 'posterior.correlation' is not a valid correlation matrix "
                                 "(not positive semi-definite)")
    coef = coefficients(vehicle, terms)
    if not np.all(np.isfinite(coef)):
        bad = [t for t, c in zip(terms, coef, strict=True) if not math.isfinite(c)]
        raise InputError(source, f"key 'posterior.terms' names {', '.join(bad)}, which the file's values leave out")
    cov = coefficient_covariance(terms, coef, vcov)
    sc_t = table.get("scatter")
    if not isinstance(sc_t, dict):
        raise InputError(source, "missing table [posterior.scatter]")
    sc_key, sc_f = ("aux_kw", 1e-3) if pt == "ev" else ("aux_lph", 3600.0)
    if sc_key not in sc_t:
        raise InputError(source, f"missing key 'posterior.scatter.{sc_key}'")
    aux = _nonneg(sc_t[sc_key], f"posterior.scatter.{sc_key}", source) / sc_f
    share = _nonneg(sc_t.get("share"), "posterior.scatter.share", source)
    rho = _nonneg(sc_t.get("day_correlation", 1.0), "posterior.scatter.day_correlation", source)
    if rho > 1:
        raise InputError(source, f"key 'posterior.scatter.day_correlation' = {rho:g} must be <= 1")
    ss = sc_t.get("standstill_" + sc_key)
    # the part that does not grow with a trip: a file calibrated before cevm fitted it
    # has the class's typical value (its intervals were too narrow on short trips)
    tr_key, tr_f = ("trip_kwh", 1.0 / J_PER_KWH) if pt == "ev" else ("trip_l", 1.0)
    trip = (_nonneg(sc_t[tr_key], f"posterior.scatter.{tr_key}", source) / tr_f if tr_key in sc_t
            else priors.scatter.trip if priors is not None else 0.0)
    scatter = Scatter(aux=aux, share=share, day_corr=rho, trip=trip,
                      day_corr_note=str(sc_t.get("day_correlation_note", "as the vehicle file states")),
                      standstill=None if ss is None else _nonneg(ss, f"posterior.scatter.standstill_{sc_key}",
                                                                  source) / sc_f)
    n = table.get("n_trips", 0)
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise InputError(source, f"key 'posterior.n_trips' must be an integer >= 0, got {n!r}")
    meter = _nonneg(table.get("meter_share", 0.0), "posterior.meter_share", source)
    text = table.get("source", f"calibrated on {n} trips")
    return Posterior(terms=tuple(terms), cov=cov, scatter=scatter, source=str(text), n_trips=n, priors=priors,
                     meter_share=meter)


def _nonneg(value: Any, where: str, source: str | Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise InputError(source, f"key '{where}' must be a number >= 0, got {value!r}")
    return float(value)
