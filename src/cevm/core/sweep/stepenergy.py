"""The energy of each step along a source, per prediction (battery energy [J] for an
EV, fuel [l] for an ICE), with every term of :mod:`cevm.core.energy`.

Energy along the way, per step i, from :mod:`cevm.core.energy`::

  EV:  g_i = W_i / eta + P_aux(T) dt_i,  W_i = Delta_i, or w Delta_i for a negative
       non-simplified step, w = eta eta_r (:func:`~cevm.core.energy.ev_negative_weight`),
       P_aux from :func:`~cevm.core.energy.ev_aux_power_w`; the warm-up energy of the
       start (:func:`~cevm.core.energy.ev_start_energy_j`) before the first step.
  ICE: g_i = W_i / (U eta) + c_kin m max(k_i, 0) / U + r_run dt_i (simplified steps)
       + r_idle dt_i (standstill) + r_T(T) dt_i, W_i with the braking mode's weight
       (1 for the paper's eq. 24, 0 for no-credit); the cold-start fuel first.

:func:`step_coefficients` gives these per row as a few coefficients
(:class:`StepCoefficients`), :func:`step_energies` the (rows, steps) energies on a
:class:`~cevm.core.sweep.steptable.StepTable`; :func:`energy_trajectory` the same sum,
sample by sample, for one vehicle and mass (plain per-step arithmetic: for plots and
tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.core import energy
from cevm.core.cycle import step_terms
from cevm.core.model import braking_weight
from cevm.core.sweep.predictions import PredictionSet
from cevm.core.sweep.sources import Source
from cevm.core.sweep.steptable import StepTable
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True, eq=False)
class StepCoefficients:
    """Per row, the energy of step i as kx x_i + kr r_i + ka a_i (its negative part,
    on non-simplified steps, weighted by w) + ck max(k_i, 0) + (aux + run [simplified]
    + idle [standstill]) dt_i, and ``lump`` before the first step (units of the row:
    J for an EV, l for an ICE)."""

    kx: np.ndarray
    kr: np.ndarray
    ka: np.ndarray
    w: np.ndarray
    ck: np.ndarray
    aux: np.ndarray
    run: np.ndarray
    idle: np.ndarray
    lump: np.ndarray

    def take(self, rows: np.ndarray) -> StepCoefficients:
        return StepCoefficients(*(getattr(self, f)[rows] for f in self.__dataclass_fields__))


def step_coefficients(pset: PredictionSet, ambient_c) -> StepCoefficients:
    """The per-step energy coefficients of every row of ``pset`` (see :class:`StepTable`
    and the notes above), with every term of :mod:`cevm.core.energy` at each row's
    ambient temperature ``ambient_c`` [degC] (P,) (a block's ``ambient_c``)."""
    n = pset.n
    t = np.broadcast_to(np.asarray(ambient_c, dtype=np.float64), (n,))
    m, cda, cr, eta = pset.mass_kg, pset.cda_m2, pset.cr, pset.eta
    scale = np.where(pset.is_ev, 1.0 / eta, 1.0 / (eta * np.where(pset.is_ev, 1.0, pset.lhv_j_per_l)))
    out = {f: np.zeros(n) for f in ("w", "ck", "aux", "run", "idle", "lump")}
    for j, v in enumerate(pset.vehicles):
        rows = np.flatnonzero(pset.vehicle_index == j)
        if not rows.size:
            continue
        if v.is_ev:
            out["w"][rows] = energy.ev_negative_weight(v)
            out["aux"][rows] = energy.ev_aux_power_w(v, t[rows])
            out["lump"][rows] = energy.ev_start_energy_j(v, t[rows])
        else:
            out["w"][rows] = braking_weight(pset.braking[j] or v.ice_braking)
            assert v.fuel_lhv_j_per_l is not None  # an ICE's (vehicle files require it)
            out["ck"][rows] = energy.ice_kinetic_coefficient(v) * m[rows] / v.fuel_lhv_j_per_l
            out["aux"][rows] = energy.ice_time_fuel_lps(v, t[rows])
            out["run"][rows] = v.running_fuel_lps
            out["idle"][rows] = v.idle_fuel_lps
            out["lump"][rows] = energy.ice_start_fuel_l(v, t[rows])
    return StepCoefficients(kx=m * scale, kr=m * cr * scale, ka=cda * scale, **out)


def step_energies(st: StepTable, c: StepCoefficients, lo: int = 0, hi: int | None = None) -> np.ndarray:
    """(R, hi - lo) energy of each step lo..hi-1 (default all) for R rows of coefficients
    ``c`` (J or l)."""
    sl = slice(lo, hi)
    x, r, a, simplified = st.x[sl], st.r[sl], st.a[sl], st.simplified[sl]
    g = c.kx[:, None] * x[None, :]
    g += c.kr[:, None] * r[None, :]
    g += c.ka[:, None] * a[None, :]
    ns = ~simplified
    if ns.any():
        neg = np.minimum(g[:, ns], 0.0)
        neg *= (c.w - 1.0)[:, None]
        g[:, ns] += neg
    if np.any(c.ck != 0):
        g += c.ck[:, None] * np.maximum(st.k[sl], 0.0)[None, :]
    dt = st.dt[sl]
    if np.any(c.aux != 0):
        g += c.aux[:, None] * dt[None, :]
    if np.any(c.run != 0):
        g += c.run[:, None] * np.where(simplified, dt, 0.0)[None, :]
    if np.any(c.idle != 0):
        g += c.idle[:, None] * np.where(st.moving[sl], 0.0, dt)[None, :]
    return g


def energy_trajectory(
    source: Source, vehicle: Vehicle, mass_kg: float, *, ice_braking: str | None = None,
    ambient_c: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cumulative energy along a source for one vehicle and mass, sample by sample.

    Returns ``(time_s, distance_m, energy)``: time [s] and distance [m] from the start of
    the first leg (legs follow each other), and the battery energy drawn [J] for an EV,
    the fuel burnt [l] for an ICE, with every term of :mod:`cevm.core.energy` (the
    start's warm-up at the first sample; an ICE's running fuel on simplified steps, idle
    fuel on standstill steps, its kinetic term on the steps that gain speed).
    ``ambient_c`` [degC]: default the source's own, else the vehicle's default. Plain
    per-step arithmetic (no compression): for plots and tests.
    """
    if ambient_c is None:
        ambient_c = source.ambient_c if source.ambient_c is not None else (
            vehicle.reference_temp_c if vehicle.reference_temp_c is not None else energy.AMBIENT_DEFAULT_C)
    t_c = float(ambient_c)
    phys = source.vector.physics
    if vehicle.is_ev:
        w = energy.ev_negative_weight(vehicle)
        e0 = float(energy.ev_start_energy_j(vehicle, t_c))
        aux = float(energy.ev_aux_power_w(vehicle, t_c))
    else:
        w = braking_weight(ice_braking or vehicle.ice_braking)
        e0 = float(energy.ice_start_fuel_l(vehicle, t_c))
        rate_t = float(energy.ice_time_fuel_lps(vehicle, t_c))
        c_kin = energy.ice_kinetic_coefficient(vehicle)
        assert vehicle.fuel_lhv_j_per_l is not None  # an ICE's (vehicle files require it)
        lhv: float = vehicle.fuel_lhv_j_per_l
    ts, ds, es = [np.zeros(1)], [np.zeros(1)], [np.full(1, e0)]
    t0 = d0 = 0.0
    for leg in source.leg_profiles:
        st = step_terms(leg.time_s, leg.speed_mps, leg.elevation_m, phys)
        d = mass_kg * (st.k + st.e + vehicle.cr * st.r) + vehicle.cda_m2 * st.a
        simplified = (st.k + st.e + source.vector.cr0 * st.r) > 0
        d = np.where(~simplified & (d <= 0), w * d, d)
        if vehicle.is_ev:
            g = d / vehicle.eta + aux * st.dt
        else:
            g = (d / (lhv * vehicle.eta) + c_kin * mass_kg * np.maximum(st.k, 0.0) / lhv
                 + vehicle.running_fuel_lps * st.dt * simplified + vehicle.idle_fuel_lps * st.dt * (st.a <= 0)
                 + rate_t * st.dt)
        ts.append(t0 + np.cumsum(st.dt))
        ds.append(d0 + np.cumsum(st.r) / phys.g_mps2)
        es.append(es[-1][-1] + np.cumsum(g))
        t0, d0 = float(ts[-1][-1]), float(ds[-1][-1])
    return np.concatenate(ts), np.concatenate(ds), np.concatenate(es)

