"""The terms a calibration can fit, and the model of a trip's consumption in them (pure).

Every term of :mod:`cevm.core.energy` is, for fixed CdA and Cr, linear in a
*coefficient* that multiplies a per-trip *feature*:

==========  =======================  =========================  =================================
term        vehicle field            coefficient                feature
==========  =======================  =========================  =================================
EV
eta         eta                      1 / eta                    P  [J]
regen       regen_eta                eta_r                      N  [J] (<= 0)
aux         aux_power_w              p0 [W]                     D  [s]
heat        aux_heating_w_per_k      p_heat [W/K]               D h(T)  [K s]
cool        aux_cooling_w_per_k      p_cool [W/K]               D c(T)  [K s]
warm        warmup_j_per_k           e_warm [J/K]               h(T)  [K]
ICE
eta         eta                      1 / eta                    (P + w N) / U  [l]
kin         kinetic_eta              1 / eta_k - 1 / eta        m k_pos / U  [l]
idle        idle_fuel_lps            r_idle [l/s]               I  [s]
run         running_fuel_lps         r_run [l/s]                D_t  [s] (traction)
heat        heating_fuel_lps_per_k   r_heat [l/s/K]             D h(T)  [K s]
cool        cooling_fuel_lps_per_k   r_cool [l/s/K]             D c(T)  [K s]
warm        warmup_fuel_l_per_k      l_warm [l/K]               h(T)  [K]
both
cda         cda_m2                   CdA                        (nonlinear: P and N depend on it)
cr          cr                       Cr                         (nonlinear)
==========  =======================  =========================  =================================

An EV whose ``regen`` is neither fitted nor set regenerates with eta (the paper): its
N term is N / c_eta, not linear in c_eta; the fit linearises it (Gauss-Newton).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from cevm.core import energy
from cevm.core.calibration.data import CalibrationError, TripSet
from cevm.core.model import braking_weight, wheel_energy_j
from cevm.core.terms import ALIASES, EXTRA_TERMS, TERMS_BY_POWERTRAIN, Term
from cevm.core.vehicle import Vehicle

__all__ = ["ALIASES", "EXTRA_TERMS", "TERMS_BY_POWERTRAIN", "Term", "TermModel", "neutral", "normalise", "term",
           "with_values"]


def term(vehicle: Vehicle, name: str) -> Term:
    """The :class:`Term` ``name`` (or an alias) of the vehicle's powertrain."""
    key = ALIASES.get(name, name)
    t = TERMS_BY_POWERTRAIN.get((vehicle.powertrain, key))
    if t is None:
        allowed = ", ".join(n for (pt, n) in TERMS_BY_POWERTRAIN if pt == vehicle.powertrain)
        raise CalibrationError(f"cannot fit {name!r} for an {'EV' if vehicle.is_ev else 'ICE'} vehicle; "
                               f"choose from {allowed}")
    return t


def normalise(vehicle: Vehicle, names: Sequence[str]) -> list[str]:
    """Term names (aliases resolved, duplicates dropped), "eta" first; "eta" must be given."""
    out: list[str] = []
    for n in names:
        t = term(vehicle, n).name
        if t not in out:
            out.append(t)
    if "eta" not in out:
        raise CalibrationError("'eta' must be among the fitted parameters")
    out.remove("eta")
    return ["eta", *out]


def neutral(vehicle: Vehicle, keep: Sequence[str] = ()) -> Vehicle:
    """``vehicle`` without the energy terms not in ``keep`` (zero, or None: the paper's
    model); road-load parameters (CdA, Cr) and eta stay."""
    changes: dict = {}
    for name in EXTRA_TERMS[vehicle.powertrain]:
        if name in keep:
            continue
        t = TERMS_BY_POWERTRAIN[(vehicle.powertrain, name)]
        changes[t.field] = None if t.field in ("regen_eta", "kinetic_eta") else 0.0
    return replace(vehicle, **changes)


def with_values(vehicle: Vehicle, values: Mapping[str, Any]) -> Vehicle:
    """``vehicle`` with fitted field values (keys: vehicle fields)."""
    return replace(vehicle, **values)


# ------------------------------------------------------------------------- the model


class TermModel:
    """Predictions and Jacobians of the trips' consumption as a function of the fitted
    terms' coefficients (see the module docstring); the other terms at the vehicle's
    values."""

    def __init__(self, vehicle: Vehicle, data: TripSet, components: dict | None = None):
        self.vehicle = vehicle
        self.data = data
        self.ev = vehicle.is_ev
        if not self.ev:
            if vehicle.fuel_lhv_j_per_l is None:
                raise CalibrationError(f"ICE vehicle {vehicle.name!r} has no fuel lower heating value")
            self.w_ice = braking_weight(vehicle.ice_braking)
            self.lhv = float(vehicle.fuel_lhv_j_per_l)
        self._cache: dict = {}
        self._components: dict = {} if components is None else components  # shared by with_balance
        self._balanced: dict = {}
        t = data.ambient_c
        with np.errstate(invalid="ignore"):
            self.h = np.where(np.isfinite(t), energy.heating_k(np.nan_to_num(t), vehicle.heating_below_c), np.nan)
            self.c = np.where(np.isfinite(t), energy.cooling_k(np.nan_to_num(t), vehicle.cooling_above_c), np.nan)

    def components(self, cda: float, cr: float) -> tuple[np.ndarray, np.ndarray]:
        """P_i (E_DC1 + positive non-simplified) and N_i (negative non-simplified) [J]."""
        key = (float(cda), float(cr))
        hit = self._components.get(key)
        if hit is None:
            w01 = np.array([0.0, 1.0])
            e = np.array([wheel_energy_j(v, np.float64(m), key[0], key[1], w01)
                          for v, m in zip(self.data.vectors, self.data.mass, strict=True)])
            e = e.reshape(self.data.n, 2)
            hit = (e[:, 0], e[:, 1] - e[:, 0])
            if len(self._components) > 256:
                self._components.clear()
            self._components[key] = hit
        return hit

    def with_balance(self, heating_below_c: float, cooling_above_c: float) -> TermModel:
        """The same model with other balance temperatures [degC] (cached; the wheel
        energies are shared)."""
        key = (float(heating_below_c), float(cooling_above_c))
        if key == (self.vehicle.heating_below_c, self.vehicle.cooling_above_c):
            return self
        hit = self._balanced.get(key)
        if hit is None:
            hit = TermModel(replace(self.vehicle, heating_below_c=key[0], cooling_above_c=key[1]), self.data,
                            self._components)
            hit._balanced = self._balanced
            self._balanced[key] = hit
        return hit

    def feature(self, name: str, cda: float, cr: float) -> np.ndarray:
        """The feature multiplying term ``name``'s coefficient, per trip."""
        d = self.data
        if name == "eta":
            P, N = self.components(cda, cr)
            return P if self.ev else (P + self.w_ice * N) / self.lhv
        if name == "regen":
            return self.components(cda, cr)[1]
        if name == "kin":
            return d.mass * d.k_pos / self.lhv
        if name == "aux":
            return d.duration
        if name == "idle":
            return d.idle
        if name == "run":
            return d.traction
        # a trip without a logged temperature counts no heating or cooling demand: the
        # temperature terms then learn nothing from it (a selection leaves such trips out
        # when most trips have one, :func:`.selection.select`)
        if name == "heat":
            return d.duration * np.nan_to_num(self.h)
        if name == "cool":
            return d.duration * np.nan_to_num(self.c)
        if name == "warm":
            return np.nan_to_num(self.h)
        raise KeyError(name)

    # values <-> coefficients ---------------------------------------------------------

    def vehicle_values(self) -> dict[str, float]:
        """The current value of every term's field (SI), None-valued fields as NaN."""
        v = self.vehicle
        out = {}
        for (pt, name), t in TERMS_BY_POWERTRAIN.items():
            if pt == v.powertrain:
                x = getattr(v, t.field)
                out[name] = math.nan if x is None else float(x)
        return out

    def coefficients(self, values: dict[str, float]) -> dict[str, float]:
        """Term coefficients from term values (``values`` keyed by term name)."""
        c = {}
        for name, x in values.items():
            if name == "eta":
                c[name] = 1.0 / x
            elif name == "kin":
                c[name] = 0.0 if not math.isfinite(x) else 1.0 / x - 1.0 / values["eta"]
            elif name in ("cda", "cr"):
                c[name] = x
            elif name == "regen":
                c[name] = x  # NaN: tied to eta
            else:
                c[name] = x
        return c

    def values_of(self, names: Sequence[str], theta: np.ndarray) -> dict[str, float]:
        """Term values (SI, vehicle-field meaning) with ``names`` set from coefficients
        ``theta`` and the others at the vehicle's values."""
        vals = self.vehicle_values()
        coef = dict(zip(names, (float(x) for x in theta), strict=True))
        if "eta" in coef:
            vals["eta"] = 1.0 / coef["eta"]
        for name, x in coef.items():
            if name == "eta":
                continue
            if name == "kin":
                vals["kin"] = 1.0 / (x + 1.0 / vals["eta"])
            else:
                vals[name] = x
        return vals

    def fields_of(self, names: Sequence[str], theta: np.ndarray) -> dict[str, float]:
        """Vehicle field -> value for the fitted ``names``."""
        vals = self.values_of(names, theta)
        return {TERMS_BY_POWERTRAIN[(self.vehicle.powertrain, n)].field: vals[n] for n in names}

    # prediction ----------------------------------------------------------------------

    def _linear_parts(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                              tuple[float, np.ndarray] | None]:
        """For linear ``names`` at the vehicle's CdA and Cr (cached): the features F (n, k)
        of the fitted terms, the fixed terms' consumption (all but those that move with
        eta), and the features that move with eta: the tied regeneration N (EV, divided
        by c_eta) and a fixed kinetic_eta's K (ICE, times 1/eta_k - c_eta), or None."""
        key = ("lin", names)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        vals = self.vehicle_values()
        cda, cr = vals["cda"], vals["cr"]
        F = np.column_stack([self.feature(n, cda, cr) for n in names]) if names else np.zeros((self.data.n, 0))
        fixed = np.zeros(self.data.n)
        tied_n = fixed_k = None
        for name in EXTRA_TERMS[self.vehicle.powertrain]:
            if name in names:
                continue
            x = vals.get(name, math.nan)
            if name == "regen":
                if not math.isfinite(x):
                    tied_n = self.feature("regen", cda, cr)
                    continue
            elif name == "kin":
                if math.isfinite(x):
                    fixed_k = (1.0 / x, self.feature("kin", cda, cr))
                continue
            if math.isfinite(x) and x != 0.0:
                fixed = fixed + x * self.feature(name, cda, cr)
        hit = (F, fixed, tied_n, fixed_k)
        self._cache[key] = hit
        return hit

    def predict(self, names: Sequence[str], theta: np.ndarray, idx=slice(None)) -> np.ndarray:
        """Consumption of the trips ``idx`` [J or l] with the coefficients ``theta`` of
        ``names`` (the other terms at the vehicle's values)."""
        names = tuple(names)
        if "cda" not in names and "cr" not in names and "eta" in names:
            F, fixed, tied_n, fixed_k = self._linear_parts(names)
            out = F[idx] @ np.asarray(theta, dtype=np.float64) + fixed[idx]
            c_eta = float(theta[names.index("eta")])
            if tied_n is not None:
                out = out + tied_n[idx] / c_eta
            if fixed_k is not None:
                out = out + (fixed_k[0] - c_eta) * fixed_k[1][idx]
            return out
        vals = self.values_of(names, theta)
        cda, cr = vals["cda"], vals["cr"]
        coef = self.coefficients({k: v for k, v in vals.items() if k not in ("cda", "cr")})
        out = np.zeros(self.data.n)[idx]
        for name, c in coef.items():
            if name == "regen" and not math.isfinite(c):
                out = out + self.feature("regen", cda, cr)[idx] / coef["eta"]  # tied: eta N
                continue
            if c == 0.0 or not math.isfinite(c):
                continue
            out = out + c * self.feature(name, cda, cr)[idx]
        return out

    def jacobian(self, names: Sequence[str], theta: np.ndarray, idx=slice(None)) -> np.ndarray:
        """d predict / d theta (coefficients; CdA and Cr by a forward difference, exact
        within a linear piece of the wheel energy)."""
        names = tuple(names)
        if "cda" not in names and "cr" not in names and "eta" in names:
            F, _fixed, tied_n, fixed_k = self._linear_parts(names)
            J = F[idx].copy()
            j = names.index("eta")
            c_eta = float(theta[j])
            if tied_n is not None:
                J[:, j] -= tied_n[idx] / (c_eta * c_eta)
            if fixed_k is not None:
                J[:, j] -= fixed_k[1][idx]
            return J
        vals = self.values_of(names, theta)
        cda, cr = vals["cda"], vals["cr"]
        n = self.data.n if isinstance(idx, slice) else len(np.atleast_1d(np.arange(self.data.n)[idx]))
        J = np.empty((n, len(names)))
        tied = self.ev and not math.isfinite(vals.get("regen", math.nan)) and "regen" not in names
        base = None
        for j, name in enumerate(names):
            if name in ("cda", "cr"):
                if base is None:
                    base = self.predict(names, theta, idx)
                h = 1e-7 * max(abs(vals[name]), 1e-3)
                th = np.array(theta, dtype=np.float64)
                th[j] += h
                J[:, j] = (self.predict(names, th, idx) - base) / h
                continue
            col = self.feature(name, cda, cr)[idx]
            if name == "eta" and tied:
                col = col - self.feature("regen", cda, cr)[idx] / (1.0 / vals["eta"]) ** 2
            if name == "eta" and not self.ev and "kin" not in names and math.isfinite(vals.get("kin", math.nan)):
                # a fixed kinetic_eta: its coefficient 1/eta_k - 1/eta moves with eta
                col = col - self.feature("kin", cda, cr)[idx]
            J[:, j] = col
        return J

    def nontraction(self, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
        """Per trip, the consumption of the terms that do not scale with wheel energy
        (aux, heating, cooling, warm-up, idle, running) [J or l]."""
        vals = self.values_of(names, theta)
        out = np.zeros(self.data.n)
        for name in ("aux", "heat", "cool", "warm", "idle", "run"):
            x = vals.get(name, 0.0)
            if math.isfinite(x) and x:
                out = out + x * self.feature(name, vals["cda"], vals["cr"])
        return out

    def standstill_rate(self, names: Sequence[str], theta: np.ndarray) -> np.ndarray:
        """Per trip, the modelled rate while standing still [W or l/s]: EV P_aux(T); ICE
        r_idle + r_heat h(T) + r_cool c(T)."""
        vals = self.values_of(names, theta)
        g = {k: (0.0 if not math.isfinite(vals.get(k, 0.0)) else vals.get(k, 0.0))
             for k in ("aux", "heat", "cool", "idle")}
        h = np.nan_to_num(self.h)
        c = np.nan_to_num(self.c)
        base = g["aux"] if self.ev else g["idle"]
        return base + g["heat"] * h + g["cool"] * c
