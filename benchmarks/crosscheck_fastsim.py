"""Cross-check cevm's detailed model against NREL's FASTSim 3 on shared drive cycles.

    python benchmarks/crosscheck_fastsim.py [--reps N] [--cycles NAME ...]

Optional: needs ``fastsim`` (``pip install "fastsim>=3.1"``, cevm's ``fastsim`` extra);
cevm itself never imports it. Results and discussion: benchmarks/FASTSIM.md.

FASTSim 3.1 ships no heavy vehicle (its bundled vehicles are passenger cars), so the
cross-check uses two of its own vehicles, and sets cevm's detailed model up to match each
as closely as cevm's parameterisation allows:

- ``2022_Renault_Zoe_ZE50_R135.yaml`` (battery-electric) against cevm's EV model;
- ``2012_Ford_Fusion.yaml`` (conventional, 2.5 l petrol) against cevm's diesel model
  (cevm's only combustion model: a Willans-line engine, generic enough for petrol once
  its coefficients are fitted).

Taken from the FASTSim file at run time (not hard-coded): mass, drag coefficient x frontal
area, rolling coefficient, wheel radius and inertia (x number of wheels), base auxiliary
power, motor/engine maximum power and efficiency curve, transmission efficiency (a
constant in FASTSim), battery usable energy. Physics constants: measured from a short
FASTSim run (:func:`fastsim_physics`), as FASTSim 3.1.0 computes drag with an effective
air density of 1.1728 kg/m^3 although its state reports 1.2, and uses g = 9.8 m/s^2.

Effects FASTSim does not have are switched off in cevm: rotor and engine inertia,
regeneration fade at low speed (FASTSim regenerates down to standstill), a regeneration
torque limit (FASTSim: the motor's maximum power both ways), engine and gear efficiencies
varying by gear (FASTSim: one constant transmission efficiency).

FASTSim's component efficiencies are curves of output power / maximum power, with no speed
or torque; cevm's are maps over speed and torque. cevm's coefficients are therefore fitted
to FASTSim's curve, by least squares at the operating points cevm's model visits on
FASTSim's own two bundled cycles (UDDS, HWFET), which are not among the compared cycles:

- EV (:func:`fit_ev_losses`): motor+inverter loss P = k_c T^2 + k_i w + k_w w^3 + C
  against FASTSim's loss P (1/eff(P/P_max) - 1) when driving and |P| (1 - eff(0)) when
  regenerating (FASTSim 3.1 clamps negative power fractions to 0, so its regeneration
  efficiency is the curve's first value), coefficients >= 0;
- ICE (:func:`fit_willans`): fuel power (P_b + P_fric(w)) / e_ind, constant e_ind, FMEP
  quadratic in speed, against FASTSim's P_b / eff(P_b / P_max), coefficients >= 0
  (friction never negative); linear in (1/e_ind, FMEP_k/e_ind). Gear choice does not
  depend on these coefficients.

Two diagnostics split each difference into road load and powertrain:

- "drag term": cevm integrates drag as the mean of the cubes of the step's end speeds
  (the paper's eq. 14), FASTSim as the cube of the mean speed
  (:func:`drag_discretisation_j`); the net wheel energies must differ by exactly that;
- "FASTSim curve on cevm power": FASTSim's powertrain equations applied to cevm's own
  motor shaft power (EV) or wheel power (ICE) (:func:`fastsim_powertrain_on_cevm`): equal
  to FASTSim but for the road-load difference, so the remaining gap to cevm is the
  efficiency model (and, for the ICE, the fuel cut when braking).

FASTSim's conventional vehicle as shipped has no deceleration fuel cut-off (DFCO): during
braking the engine still burns fuel for the auxiliaries and the brakes take all the
braking energy. cevm's engine cuts fuel when the wheels drive it. FASTSim is therefore
also run with DFCO on (``set_dfco_params(True, v_min, 0.0)``, v_min the speed at which
cevm's first gear turns the engine at its lowest shift speed, below which cevm opens the
clutch and idles).

Cycles: ../shared/cycles/advisor (time_s, speed_kmh; CYC_HHDDT65 at 10 Hz is thinned to
1 Hz with :func:`cevm.core.detailed.decimate_indices` once, so both models see the same
samples). FASTSim runs with ``trace_miss_opts = "Allow"``; where it does not follow the
trace (engine power ramp, solver tolerance) cevm is run on FASTSim's achieved speed, so
both simulate the same speed trace; the tables mark those cycles.

Timing, per cycle, best of ``--reps`` calls (time.perf_counter; shared machine, so the
minimum is the least disturbed figure): cevm ``simulate()`` (all per-step channels built);
FASTSim ``SimDrive.run()`` alone, with history saved every step (as cevm's channels) and
without history, and end to end (``Cycle`` + ``SimDrive`` built, run, totals read from
``to_dataframe``).
"""

from __future__ import annotations

import argparse
import copy
import datetime
import functools
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pandas as pd
from scipy.optimize import nnls

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.core.cycle import Physics  # noqa: E402
from cevm.core.detailed import RPM, DieselParams, EvParams, SimulationResult, decimate_indices, simulate  # noqa: E402
from cevm.core.vehicle import Vehicle  # noqa: E402

try:
    import fastsim as fs
except ImportError:  # pragma: no cover - the benchmark is optional
    fs = None

ADVISOR = ROOT.parent / "shared" / "cycles" / "advisor"

#: FASTSim's bundled vehicles used here.
EV_RESOURCE = "2022_Renault_Zoe_ZE50_R135.yaml"
CONV_RESOURCE = "2012_Ford_Fusion.yaml"
#: FASTSim's own cycles: the training set of the efficiency fits.
TRAINING_CYCLES = ("udds.csv", "hwfet.csv")
#: Petrol density [kg/l], assumed (EN 228: 0.72-0.775 kg/l), only to quote l/100 km;
#: fuel energies are compared in joules, independent of it.
PETROL_DENSITY_KG_PER_L = 0.745

#: Zoe ZE50 R135 drive (public data; FASTSim's file has no speed or torque): 100 kW,
#: 245 N m, single reduction 9.32, 11,300 rpm maximum. Only the split of the motor's
#: operating point into torque and speed depends on them (the loss fit absorbs the rest).
ZOE_GEAR_RATIO = 9.32
ZOE_PEAK_TORQUE_NM = 245.0
ZOE_MAX_SPEED_RPM = 11300.0

#: Fusion 2.5 l (Duratec 25) with a 6-speed automatic: 6F35-class ratios and a 3.39
#: final drive (typical values, assumed), idle 700 rpm, full-load torque peaking at
#: 233 N m (172 lb ft) at 4,500 rpm and giving FASTSim's 130.5 kW at 6,000 rpm.
FUSION_GEAR_RATIOS = (4.584, 2.964, 1.912, 1.446, 1.000, 0.746)
FUSION_AXLE_RATIO = 3.39
FUSION_DISPLACEMENT_M3 = 2.5e-3
FUSION_FULL_LOAD_RPM = (700.0, 1000.0, 2000.0, 3000.0, 4500.0, 6000.0, 6500.0)
FUSION_FULL_LOAD_NM = (140.0, 170.0, 205.0, 220.0, 233.0, 207.7, 185.0)
#: Shift rule of an economy automatic: 1,250 rpm at no load up to 3,000 rpm at rated power.
FUSION_SHIFT_RPM = (1250.0, 3000.0)

#: Key of the third FASTSim vehicle: the project's electric bus written as a FASTSim BEV
#: (:func:`fastsim_bus_dict`), compared on the bus cycles (:data:`BUS_CYCLES`).
BUS_KEY = "cevm-electric-bus"
BUS_TOML = ROOT / "configs" / "vehicles" / "electric-bus.toml"
#: Frontal area given to FASTSim's bus [m^2] (2.55 m wide x 3.0 m high): only the
#: product with the drag coefficient, the project's CdA, matters.
BUS_FRONTAL_AREA_M2 = 7.65
#: Number of wheels of the two-axle bus (twin rear tyres).
BUS_WHEELS = 6
#: Maximum motor power given to FASTSim's bus [W]. FASTSim 3.1.0 stops with "edrv charge
#: power exceeds current max charge power" when the braking power at the motor exceeds
#: the motor's maximum power, instead of passing the excess to the friction brakes; the
#: bus cycles brake at up to about 430 kW. So the motor gets 500 kW, its efficiency
#: curve re-gridded to stay the same in watts up to the bus's 180 kW (flat above).
BUS_FASTSIM_MOTOR_POWER_W = 500e3
#: ADVISOR cycles a city bus drives (as benchmarks/bench_tables.py).
BUS_CYCLES = ("CYC_UKBUS6", "CYC_MANHATTAN", "CYC_NewYorkBus", "CYC_CBDBUS", "CYC_OCC", "CYC_BUSRTE",
              "CYC_NurembergR36", "CYC_ARTERIAL", "CYC_COMMUTER", "CYC_WVUCITY")


def require_fastsim():
    """The ``fastsim`` module, or SystemExit with the install command."""
    if fs is None:
        raise SystemExit('crosscheck_fastsim needs FASTSim 3: pip install "fastsim>=3.1"')
    return fs


# --------------------------------------------------------------------------------------
# FASTSim side
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FsVehicle:
    """The parameters of a FASTSim vehicle file that cevm can use, SI units."""

    resource: str
    name: str
    powertrain: str  # "ev" or "ice"
    mass_kg: float
    cda_m2: float
    cr: float
    wheel_radius_m: float
    wheel_inertia_total_kgm2: float  # inertia of one wheel x number of wheels
    aux_power_w: float
    transmission_efficiency: float
    max_power_w: float  # motor / engine output
    eff_frac: tuple[float, ...]  # output power / max power
    eff_values: tuple[float, ...]
    battery_usable_j: float | None = None
    fuel_specific_energy_j_per_kg: float | None = None

    def efficiency(self, power_w) -> np.ndarray:
        """FASTSim's component efficiency [-] at output power [W]: its curve over
        P / P_max, negative power at the curve's first value (as FASTSim 3.1)."""
        frac = np.clip(np.asarray(power_w, dtype=np.float64) / self.max_power_w, 0.0, None)
        return np.interp(frac, self.eff_frac, self.eff_values)


def _curve(node) -> list[float]:
    """A FASTSim array as a list (plain list, or ``{"data": [...]}`` in msgpack dicts)."""
    return [float(x) for x in (node["data"] if isinstance(node, dict) else node)]


@functools.lru_cache(maxsize=1)
def _bus_dict_cached() -> dict:
    from cevm.io import load_vehicle
    from cevm.io.detailed import ev_params_from_vehicle

    fsm = require_fastsim()
    bus = load_vehicle(BUS_TOML)
    p = ev_params_from_vehicle(bus)
    d = fsm.Vehicle.from_resource(EV_RESOURCE).to_dict()
    d["name"] = f"{bus.name} as a FASTSim BEV"
    d["mass_kilograms"] = bus.mass_kg
    ch = d["chassis"]
    ch.update(drag_coef=bus.cda_m2 / BUS_FRONTAL_AREA_M2, frontal_area_square_meters=BUS_FRONTAL_AREA_M2,
              wheel_rr_coef=bus.cr, wheel_radius_meters=p.wheel_radius_m, num_wheels=BUS_WHEELS,
              wheel_inertia_kilogram_square_meters=p.wheel_inertia_kgm2 / BUS_WHEELS,
              glider_mass_kilograms=None, cargo_mass_kilograms=None)
    d["pwr_aux_base_watts"] = p.aux_base_power_w + p.hvac_power_w
    bev = d["pt_type"]["BEV"]
    em = bev["em"]
    data = em["eff_interp_achieved"]["data"]
    grid, values = _curve(data["grid"][0]), _curve(data["values"])
    grid = [g * p.motor_peak_power_w / BUS_FASTSIM_MOTOR_POWER_W for g in grid] + [1.0]
    values = values + values[-1:]
    data["grid"] = [{"v": 1, "dim": [len(grid)], "data": grid}]
    data["values"] = {"v": 1, "dim": [len(values)], "data": values}
    em["eff_interp_at_max_input"] = None  # derived again by FASTSim's init
    em["pwr_out_max_watts"] = BUS_FASTSIM_MOTOR_POWER_W
    bev["transmission"]["eff_interp"] = p.transmission_efficiency
    res = bev["res"]
    res["energy_capacity_joules"] = bus.battery_j / (float(res["max_soc"]) - float(res["min_soc"]))
    return d


def fastsim_bus_dict() -> dict:
    """The project's electric bus (configs/vehicles/electric-bus.toml) as a FASTSim BEV.

    FASTSim's Zoe file with the bus's mass, CdA, Cr, wheel radius and inertia (its
    [detailed] table), auxiliaries, transmission efficiency and usable battery energy.
    Motor: the Zoe's efficiency curve scaled to the bus's 180 kW peak power (efficiency vs
    P / 180 kW), with the maximum power raised to :data:`BUS_FASTSIM_MOTOR_POWER_W` (see
    there). FASTSim has no motor torque or speed to set.
    """
    return copy.deepcopy(_bus_dict_cached())


def _load_fs_vehicle(key: str):
    """A FASTSim ``Vehicle``: a bundled resource, or :data:`BUS_KEY`."""
    fsm = require_fastsim()
    if key == BUS_KEY:
        return fsm.Vehicle.from_dict(fastsim_bus_dict())
    return fsm.Vehicle.from_resource(key)


def fastsim_vehicle(resource: str) -> FsVehicle:
    """Read the parameters of a FASTSim vehicle: a bundled one
    (``fastsim.Vehicle.list_resources()``) or :data:`BUS_KEY`."""
    d = _load_fs_vehicle(resource).to_dict()
    ch = d["chassis"]
    (kind, pt), = d["pt_type"].items()
    trans = pt["transmission"]["eff_interp"]
    if not isinstance(trans, (int, float)):
        raise ValueError(f"{resource}: only a constant transmission efficiency is supported, got {trans!r}")
    common = dict(
        resource=resource,
        name=d["name"],
        mass_kg=float(d["mass_kilograms"]),
        cda_m2=float(ch["drag_coef"]) * float(ch["frontal_area_square_meters"]),
        cr=float(ch["wheel_rr_coef"]),
        wheel_radius_m=float(ch["wheel_radius_meters"]),
        wheel_inertia_total_kgm2=float(ch["wheel_inertia_kilogram_square_meters"]) * int(ch["num_wheels"]),
        aux_power_w=float(d["pwr_aux_base_watts"]),
        transmission_efficiency=float(trans),
    )
    if kind == "BEV":
        em, res = pt["em"], pt["res"]
        data = em["eff_interp_achieved"]["data"]
        usable = float(res["energy_capacity_joules"]) * (float(res["max_soc"]) - float(res["min_soc"]))
        return FsVehicle(powertrain="ev", max_power_w=float(em["pwr_out_max_watts"]),
                         eff_frac=tuple(_curve(data["grid"][0])), eff_values=tuple(_curve(data["values"])),
                         battery_usable_j=usable, **common)
    if kind == "Conv":
        fc = pt["fc"]
        if float(fc.get("pwr_idle_fuel_watts", 0.0)) != 0.0:
            raise ValueError(f"{resource}: a non-zero pwr_idle_fuel_watts is not supported")
        data = fc["eff_interp_from_pwr_out"]["data"]
        return FsVehicle(powertrain="ice", max_power_w=float(fc["pwr_out_max_watts"]),
                         eff_frac=tuple(_curve(data["grid"][0])), eff_values=tuple(_curve(data["values"])),
                         fuel_specific_energy_j_per_kg=float(pt["fs"]["specific_energy_joules_per_kilogram"]),
                         **common)
    raise ValueError(f"{resource}: powertrain {kind} is not compared")


def fastsim_cycle(time_s, speed_mps):
    """A FASTSim ``Cycle`` on the given samples (flat road)."""
    fsm = require_fastsim()
    return fsm.Cycle.from_dict({"time_seconds": np.asarray(time_s, dtype=float).tolist(),
                                "speed_meters_per_second": np.asarray(speed_mps, dtype=float).tolist()})


def _sim_params():
    fsm = require_fastsim()
    sp = fsm.SimParams.default().to_dict()
    sp["trace_miss_opts"] = "Allow"
    return fsm.SimParams.from_dict(sp)


def _fs_vehicle(resource: str, dfco: tuple[float, float] | None = None, save_interval: int | None = 1):
    veh = _load_fs_vehicle(resource)
    if dfco is not None:
        veh.set_dfco_params(True, float(dfco[0]), float(dfco[1]))
    if save_interval != 1:
        veh.set_save_interval(save_interval)
    return veh


def run_fastsim_frame(resource: str, time_s, speed_mps, dfco: tuple[float, float] | None = None) -> pd.DataFrame:
    """FASTSim's per-sample history (``SimDrive.to_dataframe()``) of one run.

    ``dfco``: (minimum speed [m/s], maximum acceleration [m/s^2]) to switch on the
    conventional vehicle's deceleration fuel cut-off; None: the vehicle as shipped.
    """
    fsm = require_fastsim()
    sd = fsm.SimDrive(_fs_vehicle(resource, dfco), fastsim_cycle(time_s, speed_mps), _sim_params())
    sd.run()
    return sd.to_dataframe()


@functools.lru_cache(maxsize=8)
def fastsim_physics(resource: str) -> Physics:
    """Air density and g as FASTSim applies them, measured on a short run of its vehicle:
    drag power / (CdA v^3 / 2) and rolling power / (m Cr v) at constant speed.

    (FASTSim 3.1.0: 1.1728 kg/m^3, while its vehicle state reports 1.2 with
    ``f2_const_air_density``; g = 9.8 m/s^2.)
    """
    fv = fastsim_vehicle(resource)
    t = np.arange(0.0, 41.0)
    v = np.minimum(0.5 * t, 10.0)
    df = run_fastsim_frame(resource, t, v)
    cruise = np.flatnonzero((v[1:] == 10.0) & (v[:-1] == 10.0)) + 1
    drag = df["veh.history.pwr_drag_watts"].to_numpy()[cruise]
    rr = df["veh.history.pwr_rr_watts"].to_numpy()[cruise]
    rho = float(np.median(drag / (0.5 * fv.cda_m2 * 10.0**3)))
    g = float(np.median(rr / (fv.mass_kg * fv.cr * 10.0)))
    return Physics(rho_air_kg_m3=rho, g_mps2=g)


@dataclass(frozen=True)
class FsResult:
    """Totals of one FASTSim run, SI. ``energy_j``: battery terminal (electrical) energy,
    net, auxiliaries included (EV); ``fuel_energy_j``: fuel energy (ICE)."""

    speed_ach_mps: np.ndarray  # achieved speed per sample
    trace_max_miss_mps: float
    wheel_energy_j: float  # net tractive energy (braking negative)
    wheel_positive_j: float
    friction_brake_j: float  # >= 0
    energy_j: float | None = None
    motor_drive_elec_j: float | None = None  # electric energy into the motor, driving
    motor_regen_elec_j: float | None = None  # electric energy from the motor, regenerating (>= 0)
    fuel_energy_j: float | None = None

    @property
    def trace_met(self) -> bool:
        return self.trace_max_miss_mps == 0.0


def read_fastsim(df: pd.DataFrame, speed_mps) -> FsResult:
    """:class:`FsResult` from FASTSim's history of a run over the trace ``speed_mps``."""
    cols = df.columns
    dt = np.diff(df["cyc.time_seconds"].to_numpy())
    p_trac = df["veh.history.pwr_tractive_watts"].to_numpy()[1:]
    v_ach = df["veh.history.speed_ach_meters_per_second"].to_numpy()
    out = dict(
        speed_ach_mps=v_ach,
        trace_max_miss_mps=float(np.max(np.abs(v_ach - np.asarray(speed_mps)))),
        wheel_energy_j=float(df["veh.history.energy_tractive_joules"].iloc[-1]),
        wheel_positive_j=float(np.dot(np.maximum(p_trac, 0.0), dt)),
        # pwr_brake <= 0: friction brakes only (regeneration is in the motor's channels)
        friction_brake_j=-float(np.dot(df["veh.history.pwr_brake_watts"].to_numpy()[1:], dt)),
    )
    if "veh.pt_type.BEV.res.history.energy_out_electrical_joules" in cols:
        p_el = df["veh.pt_type.BEV.em.history.pwr_elec_prop_in_watts"].to_numpy()[1:]
        out.update(
            energy_j=float(df["veh.pt_type.BEV.res.history.energy_out_electrical_joules"].iloc[-1]),
            motor_drive_elec_j=float(np.dot(np.maximum(p_el, 0.0), dt)),
            motor_regen_elec_j=float(-np.dot(np.minimum(p_el, 0.0), dt)),
        )
    else:
        out.update(fuel_energy_j=float(df["veh.pt_type.Conv.fc.history.energy_fuel_joules"].iloc[-1]))
    return FsResult(**out)


def run_fastsim(resource: str, time_s, speed_mps, dfco: tuple[float, float] | None = None) -> FsResult:
    """Run FASTSim's vehicle ``resource`` over the trace and read its totals."""
    return read_fastsim(run_fastsim_frame(resource, time_s, speed_mps, dfco), speed_mps)


def time_fastsim(resource: str, time_s, speed_mps, reps: int) -> dict:
    """Best times [s] over ``reps`` calls: ``run_s`` (``SimDrive.run()``, history saved),
    ``run_nohist_s`` (history off) and ``total_s`` (build, run, read totals)."""
    fsm = require_fastsim()
    params = _sim_params()
    veh, veh_nohist = _fs_vehicle(resource), _fs_vehicle(resource, save_interval=None)
    best = {"run_s": np.inf, "run_nohist_s": np.inf, "total_s": np.inf}
    for _ in range(reps):
        t0 = time.perf_counter()
        sd = fsm.SimDrive(veh, fastsim_cycle(time_s, speed_mps), params)
        t1 = time.perf_counter()
        sd.run()
        t2 = time.perf_counter()
        read_fastsim(sd.to_dataframe(), speed_mps)
        t3 = time.perf_counter()
        sd = fsm.SimDrive(veh_nohist, fastsim_cycle(time_s, speed_mps), params)
        t4 = time.perf_counter()
        sd.run()
        t5 = time.perf_counter()
        for key, value in (("run_s", t2 - t1), ("total_s", t3 - t0), ("run_nohist_s", t5 - t4)):
            best[key] = min(best[key], value)
    return best


# --------------------------------------------------------------------------------------
# cevm side: the matched vehicles
# --------------------------------------------------------------------------------------


def training_traces() -> list[tuple[np.ndarray, np.ndarray]]:
    """(time [s], speed [m/s]) of FASTSim's bundled cycles (:data:`TRAINING_CYCLES`)."""
    fsm = require_fastsim()
    out = []
    for name in TRAINING_CYCLES:
        d = fsm.Cycle.from_resource(name).to_dict()
        out.append((np.asarray(_curve(d["time_seconds"])), np.asarray(_curve(d["speed_meters_per_second"]))))
    return out


def cevm_vehicle(fv: FsVehicle) -> Vehicle:
    """cevm's :class:`~cevm.core.vehicle.Vehicle` with FASTSim's road load. ``eta`` belongs to
    the CE model and is not used by the detailed model (set to the transmission's)."""
    common = dict(name=f"{fv.name} (matched to FASTSim)", mass_kg=fv.mass_kg, cda_m2=fv.cda_m2, cr=fv.cr,
                  eta=fv.transmission_efficiency)
    if fv.powertrain == "ev":
        return Vehicle(powertrain="ev", battery_j=fv.battery_usable_j, **common)
    lhv = fv.fuel_specific_energy_j_per_kg * PETROL_DENSITY_KG_PER_L
    return Vehicle(powertrain="ice", fuel_lhv_j_per_l=lhv, **common)


def base_ev_params(fv: FsVehicle) -> EvParams:
    """:class:`EvParams` matching the FASTSim BEV, loss map not yet fitted.

    Regeneration limited by the motor's maximum power only, down to standstill (fade
    low = high = 0), as FASTSim. No rotor inertia (FASTSim has none). Battery resistance
    0: in cevm it changes only the SoC, not the terminal energy compared here. Gearing,
    peak torque and maximum speed (absent from FASTSim): the Zoe's (:data:`ZOE_GEAR_RATIO`
    ...) or, for :data:`BUS_KEY`, the bus's [detailed] table.
    """
    if fv.resource == BUS_KEY:
        from cevm.io import load_vehicle
        from cevm.io.detailed import ev_params_from_vehicle

        own = ev_params_from_vehicle(load_vehicle(BUS_TOML))
        # peak torque scaled with the power: the bus's base speed (1,560 rpm) is kept
        torque = own.motor_peak_torque_nm * fv.max_power_w / own.motor_peak_power_w
        ratio, w_max = own.total_ratio, own.motor_max_speed_rad_s
    else:
        ratio, torque, w_max = ZOE_GEAR_RATIO, ZOE_PEAK_TORQUE_NM, ZOE_MAX_SPEED_RPM * RPM
    return EvParams(
        wheel_radius_m=fv.wheel_radius_m,
        gear_ratio=ratio,
        final_drive_ratio=1.0,
        transmission_efficiency=fv.transmission_efficiency,
        motor_peak_power_w=fv.max_power_w,
        motor_peak_torque_nm=torque,
        motor_max_speed_rad_s=w_max,
        regen_max_power_w=fv.max_power_w,
        regen_max_torque_nm=None,
        regen_fade_low_mps=0.0,
        regen_fade_high_mps=0.0,
        cells_in_series=96.0,
        internal_resistance_ohm=0.0,
        aux_base_power_w=fv.aux_power_w,
        hvac_power_w=0.0,
        wheel_inertia_kgm2=fv.wheel_inertia_total_kgm2,
        motor_inertia_kgm2=0.0,
    )


def base_conv_params(fv: FsVehicle) -> DieselParams:
    """:class:`DieselParams` matching the FASTSim conventional vehicle, Willans line not
    yet fitted: FASTSim's constant transmission efficiency as the axle's (gears 1.0), no
    engine inertia (FASTSim has none), constant indicated efficiency (FASTSim's curve has
    no speed or load dependence), FASTSim's auxiliary power on the crankshaft."""
    return DieselParams(
        wheel_radius_m=fv.wheel_radius_m,
        gear_ratios=FUSION_GEAR_RATIOS,
        axle_ratio=FUSION_AXLE_RATIO,
        gear_efficiencies=(1.0,) * len(FUSION_GEAR_RATIOS),
        axle_efficiency=fv.transmission_efficiency,
        displacement_m3=FUSION_DISPLACEMENT_M3,
        idle_speed_rad_s=FUSION_FULL_LOAD_RPM[0] * RPM,
        max_speed_rad_s=FUSION_FULL_LOAD_RPM[-1] * RPM,
        full_load_speed_rad_s=tuple(n * RPM for n in FUSION_FULL_LOAD_RPM),
        full_load_torque_nm=FUSION_FULL_LOAD_NM,
        indicated_efficiency_speed_drop=0.0,
        indicated_efficiency_load_drop=0.0,
        aux_power_w=fv.aux_power_w,
        shift_low_speed_rad_s=FUSION_SHIFT_RPM[0] * RPM,
        shift_high_speed_rad_s=FUSION_SHIFT_RPM[1] * RPM,
        wheel_inertia_kgm2=fv.wheel_inertia_total_kgm2,
        engine_inertia_kgm2=0.0,
    )


@dataclass(frozen=True)
class FitInfo:
    """Quality of an efficiency fit on the training operating points."""

    n_points: int
    target_energy_j: float  # FASTSim's loss (EV) / fuel (ICE) energy at those points
    fitted_energy_j: float  # cevm's fitted map at the same points
    rms_w: float  # RMS residual of the power [W]


def _nnls_fit(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, FitInfo]:
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    coef = nnls(a / scale, b)[0] / scale
    fitted = a @ coef
    return coef, FitInfo(n_points=b.size, target_energy_j=float(b.sum()), fitted_energy_j=float(fitted.sum()),
                         rms_w=float(np.sqrt(np.mean((fitted - b) ** 2))))


def _fields(obj) -> dict:
    return {f: getattr(obj, f) for f in obj.__dataclass_fields__}


def fit_ev_losses(fv: FsVehicle, base: EvParams, traces, physics: Physics) -> tuple[EvParams, FitInfo]:
    """Fit cevm's motor loss map to FASTSim's efficiency curve (non-negative least squares).

    Operating points: every step with motor torque of cevm's model on ``traces`` (torque
    and speed do not depend on the loss map, but for the rare regenerating steps whose
    losses would exceed the recovered power, which the model leaves to the brakes).
    """
    veh = cevm_vehicle(fv)
    rows, target = [], []
    for t, v in traces:
        s = simulate(veh, t, v, params=base, time_step_s=None, physics=physics).steps
        on = s["motor_torque_nm"] != 0.0
        tq, w, p = s["motor_torque_nm"][on], s["motor_speed_rad_s"][on], s["motor_power_w"][on]
        eff = fv.efficiency(p)
        rows.append(np.column_stack([tq * tq, w, w**3, np.ones_like(w)]))
        target.append(np.where(p > 0, p * (1.0 / eff - 1.0), -p * (1.0 - eff)))
    (kc, ki, kw, c), info = _nnls_fit(np.vstack(rows), np.concatenate(target))
    pk, wmax, tpk = base.motor_peak_power_w, base.motor_max_speed_rad_s, base.motor_peak_torque_nm
    params = EvParams(**{**_fields(base), "copper_loss_frac": kc * tpk**2 / pk, "iron_loss_frac": ki * wmax / pk,
                         "windage_loss_frac": kw * wmax**3 / pk, "constant_loss_frac": c / pk})
    return params, info


def fit_willans(fv: FsVehicle, base: DieselParams, traces, physics: Physics,
                passes: int = 3) -> tuple[DieselParams, FitInfo]:
    """Fit cevm's Willans line (constant e_ind, FMEP = f0 + f1 n + f2 n^2, n in 1000 rpm)
    to FASTSim's fuel power P_b / eff(P_b / P_max) at cevm's fuelled operating points.

    P_fuel = x P_b + x V/(4 pi) (f0 w + f1 w^2 / c + f2 w^3 / c^2), c = 1,000 rpm, is
    linear in (x, x f0, x f1, x f2), all >= 0: non-negative least squares. The fuelled
    set depends on the friction (fuel cut), so the fit is repeated ``passes`` times.
    """
    veh = cevm_vehicle(fv)
    params, c = base, 1000.0 * RPM
    for _ in range(passes):
        rows, target = [], []
        for t, v in traces:
            s = simulate(veh, t, v, params=params, time_step_s=None, physics=physics).steps
            on = s["fuel_power_w"] > 0
            pb, w = s["engine_power_w"][on], s["engine_speed_rad_s"][on]
            rows.append(np.column_stack([pb, w, w * w, w**3]))
            target.append(pb / fv.efficiency(pb))
        coef, info = _nnls_fit(np.vstack(rows), np.concatenate(target))
        k = 4.0 * np.pi / (base.displacement_m3 * coef[0])
        params = DieselParams(**{**_fields(base), "indicated_efficiency_max": 1.0 / coef[0],
                                 "fmep0_pa": coef[1] * k, "fmep1_pa": coef[2] * k * c,
                                 "fmep2_pa": coef[3] * k * c * c})
    return params, info


@dataclass(frozen=True)
class Matched:
    """A FASTSim vehicle and cevm's matched model of it."""

    fv: FsVehicle
    vehicle: Vehicle
    params: EvParams | DieselParams
    fit: FitInfo
    physics: Physics

    def simulate(self, time_s, speed_mps) -> SimulationResult:
        """cevm's detailed model over the trace (every sample simulated, flat road)."""
        return simulate(self.vehicle, time_s, speed_mps, params=self.params, time_step_s=None,
                        physics=self.physics)

    def dfco(self) -> tuple[float, float] | None:
        """FASTSim DFCO settings equivalent to cevm's fuel cut (ICE), else None:
        (speed at which first gear turns the engine at the lowest shift speed [m/s],
        maximum acceleration 0 m/s^2)."""
        if self.fv.powertrain != "ice":
            return None
        p = self.params
        return (p.shift_low_speed_rad_s / (p.gear_ratios[0] * p.axle_ratio) * p.wheel_radius_m, 0.0)


def matched_model(kind: str, traces=None) -> Matched:
    """cevm's model of FASTSim's EV (``kind`` "ev"), conventional vehicle ("ice") or of
    the project's bus written as a FASTSim BEV ("bus")."""
    traces = training_traces() if traces is None else traces
    fv = fastsim_vehicle({"ev": EV_RESOURCE, "ice": CONV_RESOURCE, "bus": BUS_KEY}[kind])
    physics = fastsim_physics(fv.resource)
    if fv.powertrain == "ev":
        params, info = fit_ev_losses(fv, base_ev_params(fv), traces, physics)
    else:
        params, info = fit_willans(fv, base_conv_params(fv), traces, physics)
    return Matched(fv, cevm_vehicle(fv), params, info, physics)


# --------------------------------------------------------------------------------------
# Comparison
# --------------------------------------------------------------------------------------


def drag_discretisation_j(time_s, speed_mps, cda_m2: float, rho_kg_m3: float) -> float:
    """cevm's aerodynamic energy minus FASTSim's over a trace [J], >= 0.

    cevm (paper eq. 14): rho CdA (v0^3 + v1^3) dt / 4 per step, the mean of the cubes;
    FASTSim: rho CdA ((v0 + v1)/2)^3 dt / 2, the cube of the mean.
    """
    v = np.asarray(speed_mps, dtype=np.float64)
    dt = np.diff(np.asarray(time_s, dtype=np.float64))
    v0, v1 = v[:-1], v[1:]
    vm = 0.5 * (v0 + v1)
    return float(0.5 * rho_kg_m3 * cda_m2 * np.sum((0.5 * (v0**3 + v1**3) - vm**3) * dt))


def fastsim_powertrain_on_cevm(fv: FsVehicle, res: SimulationResult) -> float:
    """FASTSim's powertrain equations applied to cevm's power, per step [J].

    EV: battery terminal energy of cevm's motor shaft power P through FASTSim's curve,
    P / eff(P / P_max) driving, P eff(0) regenerating, plus FASTSim's auxiliaries.
    ICE: fuel energy of FASTSim's engine output max(P_wheel, 0) / eta_tr + P_aux (no
    fuel cut: FASTSim's vehicle as shipped) through FASTSim's curve, P_b / eff(P_b / P_max).
    """
    s = res.steps
    dt = s["dt_s"]
    if fv.powertrain == "ev":
        p = s["motor_power_w"]
        eff = fv.efficiency(p)
        p_el = np.where(p > 0, p / eff, p * eff)
        return float(np.dot(p_el + fv.aux_power_w, dt))
    pb = np.maximum(s["wheel_power_w"], 0.0) / fv.transmission_efficiency + fv.aux_power_w
    return float(np.dot(pb / fv.efficiency(pb), dt))


def compare(m: Matched, time_s, speed_mps) -> dict:
    """One cycle, one vehicle: FASTSim and cevm's matched model on the same trace.

    Returns SI totals of both and relative differences (cevm - FASTSim) / FASTSim.
    Where FASTSim misses the trace, cevm runs on FASTSim's achieved speed.
    """
    fv = m.fv
    t = np.asarray(time_s, dtype=np.float64)
    fsr = run_fastsim(fv.resource, t, speed_mps)
    v = np.asarray(speed_mps, dtype=np.float64) if fsr.trace_met else fsr.speed_ach_mps
    res = m.simulate(t, v)
    s = res.steps
    positive = float(np.dot(np.maximum(s["wheel_power_w"], 0.0), s["dt_s"]))
    drag = drag_discretisation_j(t, v, fv.cda_m2, m.physics.rho_air_kg_m3)
    via = fastsim_powertrain_on_cevm(fv, res)
    row = dict(
        trace_met=fsr.trace_met, trace_max_miss_mps=fsr.trace_max_miss_mps, speed_used_mps=v,
        distance_m=float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t))),
        fs_wheel_j=fsr.wheel_energy_j, ce_wheel_j=res.wheel_energy_j,
        fs_wheel_pos_j=fsr.wheel_positive_j, ce_wheel_pos_j=positive,
        drag_discretisation_j=drag,
        fs_brake_j=fsr.friction_brake_j, ce_brake_j=res.friction_brake_energy_j,
        ce_deficit_j=res.traction_deficit_j,
    )
    row["wheel_diff"] = (res.wheel_energy_j - fsr.wheel_energy_j) / fsr.wheel_energy_j
    row["wheel_diff_after_drag"] = (res.wheel_energy_j - drag - fsr.wheel_energy_j) / fsr.wheel_energy_j
    row["wheel_pos_diff"] = (positive - fsr.wheel_positive_j) / fsr.wheel_positive_j
    if fv.powertrain == "ev":
        p_el = s["motor_electric_power_w"]
        fs_e, ce_e = fsr.energy_j, res.energy_j
        row.update(ce_drive_j=float(np.dot(np.maximum(p_el, 0), s["dt_s"])), fs_drive_j=fsr.motor_drive_elec_j,
                   ce_regen_j=float(-np.dot(np.minimum(p_el, 0), s["dt_s"])), fs_regen_j=fsr.motor_regen_elec_j)
    else:
        fs_e, ce_e = fsr.fuel_energy_j, res.fuel_l * m.vehicle.fuel_lhv_j_per_l
        dfco = run_fastsim(fv.resource, t, v, dfco=m.dfco())
        row.update(fs_dfco_j=dfco.fuel_energy_j, dfco_diff=(ce_e - dfco.fuel_energy_j) / dfco.fuel_energy_j)
    row.update(fs_energy_j=fs_e, ce_energy_j=ce_e, via_energy_j=via, energy_diff=(ce_e - fs_e) / fs_e,
               via_diff=(via - fs_e) / fs_e)
    return row


def time_cevm(m: Matched, time_s, speed_mps, reps: int) -> float:
    """Best time of cevm's ``simulate()`` over ``reps`` calls [s]."""
    best = np.inf
    for _ in range(reps):
        t0 = time.perf_counter()
        m.simulate(time_s, speed_mps)
        best = min(best, time.perf_counter() - t0)
    return best


def load_advisor(name: str) -> tuple[np.ndarray, np.ndarray]:
    """(time [s], speed [m/s]) of an ADVISOR cycle, thinned to 1 Hz if faster."""
    d = pd.read_csv(ADVISOR / f"{name}.csv")
    t = d["time_s"].to_numpy(dtype=np.float64)
    v = d["speed_kmh"].to_numpy(dtype=np.float64) / 3.6
    idx = decimate_indices(t, 1.0)
    return t[idx], v[idx]


# --------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------


def _pct(x: float) -> str:
    return f"{100 * x:+.2f}"


def _describe(m: Matched) -> None:
    fv, p, info, ph = m.fv, m.params, m.fit, m.physics
    print(f"## {fv.name} (`{fv.resource}`)\n")
    print(f"- road load: m = {fv.mass_kg:.1f} kg, CdA = {fv.cda_m2:.4f} m^2, Cr = {fv.cr}, "
          f"r = {fv.wheel_radius_m} m, wheel inertia {fv.wheel_inertia_total_kgm2:.2f} kg m^2 in all; "
          f"aux {fv.aux_power_w:.0f} W; transmission {fv.transmission_efficiency}; FASTSim's air density "
          f"(measured) {ph.rho_air_kg_m3:.4f} kg/m^3, g {ph.g_mps2:.4f} m/s^2")
    curve = ", ".join(f"{a:g}: {b:.2f}" for a, b in zip(fv.eff_frac, fv.eff_values, strict=True))
    what = "motor" if fv.powertrain == "ev" else "engine"
    print(f"- FASTSim {what} efficiency vs P/P_max: {curve}; P_max = {fv.max_power_w / 1e3:.1f} kW")
    if fv.powertrain == "ev":
        kc, ki, kw, c = p.loss_coefficients
        print(f"- fitted cevm loss map: k_c = {kc:.4f} W/(N m)^2, k_i = {ki:.4f} W s, k_w = {kw:.3g} W s^3, "
              f"C = {c:.1f} W (fractions of P_peak: copper {p.copper_loss_frac:.4f}, iron {p.iron_loss_frac:.4f}, "
              f"windage {p.windage_loss_frac:.4f}, constant {p.constant_loss_frac:.4f})")
    else:
        print(f"- fitted cevm Willans line: e_ind = {p.indicated_efficiency_max:.4f}, FMEP = "
              f"{p.fmep0_pa / 1e5:.3f} + {p.fmep1_pa / 1e5:.3f} n + {p.fmep2_pa / 1e5:.4f} n^2 bar "
              f"(n in 1000 rpm); idle fuel {p.fuel_power_w(p.idle_speed_rad_s, p.aux_power_w) / 1e3:.2f} kW "
              f"(FASTSim {fv.aux_power_w / fv.efficiency(fv.aux_power_w) / 1e3:.2f} kW); FASTSim DFCO variant: "
              f"v_min = {m.dfco()[0]:.2f} m/s, max acceleration 0")
    print(f"- fit on {info.n_points} operating points of {', '.join(TRAINING_CYCLES)}: "
          f"{'loss' if fv.powertrain == 'ev' else 'fuel'} energy {info.fitted_energy_j / 1e6:.3f} MJ fitted vs "
          f"{info.target_energy_j / 1e6:.3f} MJ FASTSim ({_pct(info.fitted_energy_j / info.target_energy_j - 1)} %), "
          f"RMS residual {info.rms_w:.0f} W\n")


def _trace(r) -> str:
    return "met" if r.trace_met else f"missed, {r.trace_max_miss_mps * 3.6:.2g} km/h max"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=5, help="timing repetitions per cycle (best of), default 5")
    ap.add_argument("--cycles", nargs="*", default=None, help="ADVISOR cycle names (default: all)")
    args = ap.parse_args(argv)
    fsm = require_fastsim()
    if not ADVISOR.is_dir():
        raise SystemExit(f"shared cycles not found: {ADVISOR}")
    names = args.cycles or sorted(p.stem for p in ADVISOR.glob("CYC_*.csv"))
    t_start = time.perf_counter()
    traces = training_traces()
    models = {kind: matched_model(kind, traces) for kind in ("ev", "ice", "bus")}
    from cevm.io import load_vehicle
    from cevm.io.detailed import detailed_params

    own_bus = load_vehicle(BUS_TOML)
    own_bus_params = detailed_params(own_bus)

    print(f"# cevm detailed model vs FASTSim {fsm.__version__}: output of crosscheck_fastsim.py")
    cmd = "python benchmarks/crosscheck_fastsim.py" + (f" --reps {args.reps}" if args.reps != 5 else "")
    print(f"\n{datetime.date.today().isoformat()}, Python {platform.python_version()}, numpy {np.__version__}, "
          f"{platform.machine()}: `{cmd}`\n")
    for m in models.values():
        _describe(m)

    rows = []
    for name in names:
        t, v = load_advisor(name)
        for kind, m in models.items():
            if kind == "bus" and name not in BUS_CYCLES:
                continue
            r = compare(m, t, v)
            used = r.pop("speed_used_mps")
            if kind == "bus":  # the project's bus as configured, same trace and physics
                own = simulate(own_bus, t, used, params=own_bus_params, time_step_s=None, physics=m.physics)
                r.update(own_energy_j=own.energy_j, own_deficit_j=own.traction_deficit_j,
                         own_diff=(own.energy_j - r["fs_energy_j"]) / r["fs_energy_j"])
            r.update(time_fastsim(m.fv.resource, t, v, args.reps))
            r["ce_s"] = time_cevm(m, t, used, args.reps)
            r.update(cycle=name, kind=kind, n=t.size)
            rows.append(r)
    df = pd.DataFrame(rows)

    print("Differences are (cevm - FASTSim) / FASTSim. *after drag term*: cevm's net wheel energy less "
          "the drag discretisation term. *FASTSim curve on cevm power*: FASTSim's powertrain equations "
          "applied to cevm's shaft (EV) or wheel (ICE) power, against FASTSim.\n")
    d = df[df.kind == "ev"]
    print("## Battery-electric: Renault Zoe ZE50 R135\n")
    print("| cycle | km | FASTSim trace | wheel net FASTSim kWh | cevm % | after drag term % | wheel + % "
          "| battery FASTSim kWh | cevm kWh | cevm % | FASTSim curve on cevm power % | Wh/km FASTSim | cevm |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in d.itertuples():
        km = r.distance_m / 1e3
        fs_e, ce_e = r.fs_energy_j / 3.6e6, r.ce_energy_j / 3.6e6
        print(f"| {r.cycle} | {km:.2f} | {_trace(r)} | {r.fs_wheel_j / 3.6e6:.3f} | {_pct(r.wheel_diff)} | "
              f"{_pct(r.wheel_diff_after_drag)} | {_pct(r.wheel_pos_diff)} | {fs_e:.3f} | {ce_e:.3f} | "
              f"{_pct(r.energy_diff)} | {_pct(r.via_diff)} | {1e3 * fs_e / km:.0f} | {1e3 * ce_e / km:.0f} |")
    _summary(d, "Battery energy")
    tot = d[["fs_drive_j", "ce_drive_j", "fs_regen_j", "ce_regen_j", "fs_brake_j", "ce_brake_j"]].sum() / 3.6e6
    print(f"All cycles together [kWh]: motor electric input when driving FASTSim {tot.fs_drive_j:.3f}, cevm "
          f"{tot.ce_drive_j:.3f}; electric output when regenerating FASTSim {tot.fs_regen_j:.3f}, cevm "
          f"{tot.ce_regen_j:.3f}; friction brakes FASTSim {tot.fs_brake_j:.3f}, cevm {tot.ce_brake_j:.3f}.\n")

    d = df[df.kind == "ice"]
    lhv = models["ice"].vehicle.fuel_lhv_j_per_l
    print("## Conventional: Ford Fusion 2012\n")
    print("| cycle | km | FASTSim trace | wheel net FASTSim kWh | cevm % | after drag term % | wheel + % "
          "| fuel FASTSim MJ | cevm MJ | cevm % | FASTSim curve on cevm power % | FASTSim + DFCO MJ | cevm % "
          "| l/100 km FASTSim | cevm |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in d.itertuples():
        km = r.distance_m / 1e3
        print(f"| {r.cycle} | {km:.2f} | {_trace(r)} | {r.fs_wheel_j / 3.6e6:.3f} | {_pct(r.wheel_diff)} | "
              f"{_pct(r.wheel_diff_after_drag)} | {_pct(r.wheel_pos_diff)} | {r.fs_energy_j / 1e6:.2f} | "
              f"{r.ce_energy_j / 1e6:.2f} | {_pct(r.energy_diff)} | {_pct(r.via_diff)} | {r.fs_dfco_j / 1e6:.2f} | "
              f"{_pct(r.dfco_diff)} | {100 * r.fs_energy_j / lhv / km:.2f} | {100 * r.ce_energy_j / lhv / km:.2f} |")
    _summary(d, "Fuel energy")
    e = d.dfco_diff
    tot = d[["fs_brake_j", "ce_brake_j"]].sum() / 3.6e6
    print(f"Against FASTSim with DFCO: mean {_pct(e.mean())} %, std {100 * e.std():.2f} %, range {_pct(e.min())} "
          f"to {_pct(e.max())} %. All cycles together: friction brakes FASTSim {tot.fs_brake_j:.2f} kWh, "
          f"cevm {tot.ce_brake_j:.2f} kWh.\n")

    d = df[df.kind == "bus"]
    if len(d):
        print("## The project's electric bus as a FASTSim BEV\n")
        print("| cycle | km | FASTSim trace | wheel net FASTSim kWh | cevm % | after drag term % "
              "| battery FASTSim kWh | cevm matched kWh | cevm % | FASTSim curve on cevm power % "
              "| cevm as configured kWh | cevm % | kWh/km FASTSim | matched | configured |")
        print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        for r in d.itertuples():
            km = r.distance_m / 1e3
            fs_e, ce_e, own_e = r.fs_energy_j / 3.6e6, r.ce_energy_j / 3.6e6, r.own_energy_j / 3.6e6
            print(f"| {r.cycle} | {km:.2f} | {_trace(r)} | {r.fs_wheel_j / 3.6e6:.3f} | {_pct(r.wheel_diff)} | "
                  f"{_pct(r.wheel_diff_after_drag)} | {fs_e:.3f} | {ce_e:.3f} | {_pct(r.energy_diff)} | "
                  f"{_pct(r.via_diff)} | {own_e:.3f} | {_pct(r.own_diff)} | {fs_e / km:.3f} | {ce_e / km:.3f} | "
                  f"{own_e / km:.3f} |")
        _summary(d, "Battery energy")
        e = d.own_diff
        print(f"cevm's bus as configured vs FASTSim: mean {_pct(e.mean())} %, std {100 * e.std():.2f} %, range "
              f"{_pct(e.min())} to {_pct(e.max())} %; its traction deficit: max "
              f"{d.own_deficit_j.max() / 3.6e3:.2f} Wh.\n")

    print(f"## Compute time per cycle (best of {args.reps}, ms)\n")
    print("| cycle | samples | EV: cevm simulate | FASTSim run | run, no history | end to end "
          "| ICE: cevm simulate | FASTSim run | run, no history | end to end |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name in names:
        ev = df[(df.cycle == name) & (df.kind == "ev")].iloc[0]
        ice = df[(df.cycle == name) & (df.kind == "ice")].iloc[0]
        cells = [f"{1e3 * x.ce_s:.2f} | {1e3 * x.run_s:.1f} | {1e3 * x.run_nohist_s:.1f} | {1e3 * x.total_s:.1f}"
                 for x in (ev, ice)]
        print(f"| {name} | {ev.n} | {cells[0]} | {cells[1]} |")
    print()
    for kind in ("ev", "ice", "bus"):
        d = df[df.kind == kind]
        if not len(d):
            continue
        us = lambda col: 1e6 * (d[col] / d.n).median()  # noqa: E731
        print(f"- {kind.upper()}, median per sample: cevm {us('ce_s'):.2f} us; FASTSim run {us('run_s'):.1f} us, "
              f"without history {us('run_nohist_s'):.1f} us, end to end {us('total_s'):.1f} us. FASTSim run / "
              f"cevm: {(d.run_s / d.ce_s).median():.0f}x (median over cycles).")
    print(f"\nTotal benchmark time {time.perf_counter() - t_start:.1f} s.")
    return 0


def _summary(d: pd.DataFrame, what: str) -> None:
    e, via = d.energy_diff, d.via_diff
    print(f"\n{what} over {len(d)} cycles, cevm vs FASTSim: mean {_pct(e.mean())} %, std {100 * e.std():.2f} %, "
          f"range {_pct(e.min())} to {_pct(e.max())} %. FASTSim curve on cevm power vs FASTSim: mean "
          f"{_pct(via.mean())} %, range {_pct(via.min())} to {_pct(via.max())} %. Net wheel energy: max |diff| "
          f"{100 * d.wheel_diff.abs().max():.3f} %, after the drag term "
          f"{100 * d.wheel_diff_after_drag.abs().max():.1e} %. "
          f"cevm traction deficit: max {d.ce_deficit_j.max() / 3.6e3:.2f} Wh.")


if __name__ == "__main__":
    raise SystemExit(main())
