"""Sensors and files: the truth trips as the srf and portal loggers record them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np

from cevm.units import J_PER_KWH, M_PER_MILE, MPH_TO_MPS, MPS_TO_KMH, RAD_S_PER_RPM, S_PER_H
from cevm_samplegen.common import BNG, GEOID_UNDULATION_M, WGS84, seeded_rng
from cevm_samplegen.consumption import STANDIN, wheel_power_w
from cevm_samplegen.csvfmt import assemble, iso_utc_ms, num_field, text_field, uk_local
from cevm_samplegen.fleet import FleetSpec, TruthTrip, VehicleSpec
from cevm_samplegen.world import World

SRF_BUS_COLUMNS = (
    "timestamp_utc", "gps_lat_deg", "gps_lon_deg", "gps_alt_m", "gps_speed_kmh", "gps_hdop",
    "fms_wheel_speed_kmh", "fms_accel_pedal_pct", "fms_brake_switch", "fms_engine_speed_rpm",
    "fms_engine_torque_pct", "fms_battery_soc_pct", "fms_battery_voltage_v", "fms_battery_current_a",
    "fms_total_energy_used_kwh", "fms_ambient_air_temp_c",
)
SRF_TRUCK_COLUMNS = (
    "timestamp_utc", "gps_lat_deg", "gps_lon_deg", "gps_alt_m", "gps_speed_kmh", "gps_hdop",
    "fms_wheel_speed_kmh", "fms_accel_pedal_pct", "fms_brake_switch", "fms_engine_speed_rpm",
    "fms_engine_torque_pct", "fms_total_fuel_used_l", "fms_fuel_rate_lph", "flowmeter_fuel_lph",
    "fms_gross_weight_kg", "fms_ambient_air_temp_c",
)
#: (decimals, strip trailing zeros) per srf column.
SRF_FORMAT = {
    "gps_lat_deg": (6, False), "gps_lon_deg": (6, False), "gps_alt_m": (1, False), "gps_speed_kmh": (1, False),
    "gps_hdop": (1, False), "fms_wheel_speed_kmh": (8, True), "fms_accel_pedal_pct": (1, False),
    "fms_brake_switch": (0, False), "fms_engine_speed_rpm": (3, True), "fms_engine_torque_pct": (0, False),
    "fms_battery_soc_pct": (1, False), "fms_battery_voltage_v": (1, False), "fms_battery_current_a": (1, False),
    "fms_total_energy_used_kwh": (1, False), "fms_total_fuel_used_l": (1, False), "fms_fuel_rate_lph": (2, False),
    "flowmeter_fuel_lph": (2, False), "fms_gross_weight_kg": (0, False), "fms_ambient_air_temp_c": (5, True),
}
#: FMS ambient air temperature (J1939 PGN 65269, SPN 171): 0.03125 degC per bit.
AMBIENT_RESOLUTION_C = 0.03125
#: The ambient sensor's warm reading at standstill in full sun [K at 800 W/m^2]: it sits
#: behind the bumper or under a mirror, heated by the sun and the road when no air flows
#: past; the excess decays with speed (scale :data:`SENSOR_SUN_SPEED_MPS`).
SENSOR_SUN_HEATING_K = 2.0
SENSOR_SUN_SPEED_MPS = 3.0
#: The sensor's thermal time constant [s] (its housing lags the air).
SENSOR_TAU_S = 60.0
#: Truck gearbox (12-speed AMT) and axle ratio of the plausible engine-speed model.
_GEARS = np.array([14.9, 11.7, 9.0, 7.1, 5.6, 4.4, 3.5, 2.7, 2.1, 1.7, 1.3, 1.0])
_AXLE = 2.8
_EV_USABLE_J = 124.0 * J_PER_KWH  # configs/vehicles/electric-bus.toml battery_kwh


def _arrivals(tk: np.ndarray, period_s: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """Mask of ticks that received a new value of a field broadcast at random intervals
    in ``period_s``: a tick shows a value if an arrival fell after the previous tick."""
    if tk.size == 0:
        return np.zeros(0, bool)
    span = tk[-1] - tk[0] + 2.0
    n = int(span / period_s[0]) + 2
    arr = tk[0] - rng.uniform(0.0, period_s[1]) + np.cumsum(rng.uniform(*period_s, n))
    idx = np.searchsorted(tk, arr, side="left")
    idx = idx[(idx < tk.size) & (arr >= tk[0] - 1.0)]
    m = np.zeros(tk.size, bool)
    m[idx] = True
    return m


def ambient_sensor_c(tr: TruthTrip) -> np.ndarray:
    """What the vehicle's ambient air temperature sensor reads on the trip's 1 s truth
    grid [degC], before quantisation: the air plus the vehicle's sensor bias, plus
    :data:`SENSOR_SUN_HEATING_K` x (sunshine / 800 W/m^2) x exp(-v / 3 m/s), through a
    first-order lag of :data:`SENSOR_TAU_S` starting from its reading at ignition on."""
    from scipy.signal import lfilter

    c = tr.conditions
    raw = (c.ambient_c + tr.vehicle.ambient_bias_k
           + SENSOR_SUN_HEATING_K * (c.solar_w_m2 / 800.0) * np.exp(-tr.speed_mps / SENSOR_SUN_SPEED_MPS))
    a = math.exp(-1.0 / SENSOR_TAU_S)
    return lfilter([1.0 - a], [1.0, -a], raw, zi=[a * raw[0]])[0]


def _ar1(n: int, tau_ticks: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary AR(1) noise with correlation time ``tau_ticks`` and std ``sigma``."""
    from scipy.signal import lfilter

    if n == 0:
        return np.zeros(0)
    a = math.exp(-1.0 / tau_ticks)
    w = rng.normal(0.0, sigma * math.sqrt(1 - a * a), n)
    w[0] = rng.normal(0.0, sigma)
    return lfilter([1.0], [1.0, -a], w)


def _floor_q(x, q):
    """Counter reading: ``x`` floored to the resolution ``q`` (with a 1e-9 guard)."""
    return np.floor(np.asarray(x) / q + 1e-9) * q


def _round_q(x, q):
    return np.round(np.asarray(x) / q) * q


def bng_to_wgs84():
    import pyproj

    return pyproj.Transformer.from_crs(BNG, WGS84, always_xy=True)


def _fms_common(veh: VehicleSpec, tr: TruthTrip, at: dict, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Wheel speed, pedal, brake switch, engine/motor speed and torque at the ticks."""
    p = STANDIN[veh.vehicle_type]
    k = at["k"]
    v0, v1 = tr.speed_mps[k], tr.speed_mps[k + 1]
    acc = v1 - v0  # the grid step is 1 s
    dh = tr.elevation_m[k + 1] - tr.elevation_m[k]
    pw = wheel_power_w(p, 1.0, v0, v1, dh, tr.mass_kg)
    v = at["speed"]
    n = v.size
    out = {}
    out["fms_wheel_speed_kmh"] = np.round(v * veh.wheel_speed_scale * MPS_TO_KMH * 256.0) / 256.0
    out["fms_accel_pedal_pct"] = _round_q(np.clip(100.0 * pw / p.max_power_w, 0.0, 100.0) * (pw > 0), 0.4)
    out["fms_brake_switch"] = ((acc < -0.3) | (v < 0.05)).astype(float)
    omega_w = v / p.wheel_radius_m  # wheel rad/s
    if veh.vehicle_type == "electric-bus":
        omega = omega_w * p.motor_ratio
        pm = np.where(pw > 0, pw / 0.95, np.maximum(pw, -p.regen_max_w) * 0.95)
        torque = pm / np.maximum(omega, 5.0)
        rpm = omega * 60.0 / (2 * np.pi)
    else:
        rpm_all = omega_w[:, None] * _AXLE * _GEARS[None, :] * 60.0 / (2 * np.pi)
        gear = np.maximum((rpm_all >= 1000.0).sum(axis=1) - 1, 0)
        rpm = np.clip(rpm_all[np.arange(n), gear], 600.0, 1900.0) + rng.normal(0.0, 4.0, n)
        pe = pw + p.aux_w
        torque = np.where(pe > 0, pe / (rpm * RAD_S_PER_RPM), -0.08 * p.ref_torque_nm)
        torque = np.where(v < 0.1, 0.05 * p.ref_torque_nm, torque)
    out["fms_engine_speed_rpm"] = _round_q(np.maximum(rpm, 0.0), 0.125)
    out["fms_engine_torque_pct"] = np.clip(np.round(100.0 * torque / p.ref_torque_nm), -125, 125)
    return out


def _round_part(key: str, x: float) -> float:
    return round(x, 1 if key.endswith("_j") else 5 if key.endswith("_l") else 3)


def conditions_record(tr: TruthTrip, t_first: float, t_last: float) -> dict:
    """The truth record's duty, route, weather and consumption parts of a trip logged from
    ``t_first`` to ``t_last`` [s from its start]: the air temperature's time-weighted mean,
    minimum and maximum and the mean sunshine over that span; the ignition-off time
    before the trip; the consumption function's parts (over the whole truth trip)."""
    t = tr.time_s
    inside = (t >= t_first - 1.0) & (t <= t_last + 1.0)
    tt = np.concatenate(([t_first], t[(t > t_first) & (t < t_last)], [t_last]))
    amb = np.interp(tt, t, tr.conditions.ambient_c)
    sun = np.interp(tt, t, tr.conditions.solar_w_m2)
    span = max(t_last - t_first, 1e-9)
    return {
        "duty": tr.duty, "route": tr.route,
        "ambient_c": round(float(np.sum(0.5 * (amb[1:] + amb[:-1]) * np.diff(tt)) / span), 3),
        "ambient_min_c": round(float(tr.conditions.ambient_c[inside].min()), 3),
        "ambient_max_c": round(float(tr.conditions.ambient_c[inside].max()), 3),
        "solar_w_m2": round(float(np.sum(0.5 * (sun[1:] + sun[:-1]) * np.diff(tt)) / span), 1),
        "soak_s": round(tr.conditions.soak_s, 1), "occupants": tr.conditions.occupants,
        **{k: _round_part(k, v) for k, v in sorted(tr.parts.items())},
    }


@dataclass
class Counters:
    """Running state of one vehicle across its days: cumulative true consumption."""

    consumption: float = 0.0
    odometer_m: float = 0.0
    reset_offset: float | None = None  # ECU counter after a reset = offset + bias x consumption


def _srf_gps(tr: TruthTrip, at: dict, n: int, T: float, alt_bias: float, transformer,
             rng: np.random.Generator) -> dict[str, np.ndarray]:
    """An srf trip's GPS columns: fixes lost at a cold start and in outages (the HDOP
    rising around them), position and altitude noise growing with the HDOP."""
    cols_v: dict[str, np.ndarray] = {}
    fix = rng.random(n) > 0.02
    cold = int(rng.integers(8, 26)) if tr.trip_index == 0 else int(rng.integers(2, 7))
    fix[:cold] = False
    hdop = 0.9 + np.abs(_ar1(n, 60.0, 0.25, rng))
    for _ in range(int(rng.poisson(T / 1800.0))):
        i0 = int(rng.integers(0, n))
        L = int(rng.integers(10, 46))
        fix[i0 : i0 + L] = False
        hdop[max(0, i0 - 5) : i0] += np.linspace(0.5, 2.5, len(hdop[max(0, i0 - 5) : i0]))
        hdop[i0 + L : i0 + L + 8] += np.linspace(2.5, 0.3, len(hdop[i0 + L : i0 + L + 8]))
    scale = hdop / 0.9
    ex = _ar1(n, 40.0, 2.5, rng) * scale + rng.normal(0.0, 0.7, n)
    ny = _ar1(n, 40.0, 2.5, rng) * scale + rng.normal(0.0, 0.7, n)
    lon, lat = transformer.transform(at["x"] + ex, at["y"] + ny)
    alt = at["elev"] + GEOID_UNDULATION_M + alt_bias + _ar1(n, 200.0, 12.0, rng) + rng.normal(0.0, 2.0, n)
    gspeed = np.abs(at["speed"] + rng.normal(0.0, 0.15, n)) * MPS_TO_KMH
    nan = np.where(fix, 1.0, np.nan)
    cols_v["gps_lat_deg"], cols_v["gps_lon_deg"] = lat * nan, lon * nan
    cols_v["gps_alt_m"], cols_v["gps_speed_kmh"] = alt * nan, gspeed * nan
    cols_v["gps_hdop"] = _round_q(hdop, 0.1) * nan
    return cols_v


def _srf_battery(veh: VehicleSpec, tk: np.ndarray, e_day: np.ndarray, cons: np.ndarray, rate: np.ndarray,
                 soc0: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """An electric bus's battery columns in an srf trip: voltage and current of a battery
    with an internal resistance, the state of charge, the FMS energy counter."""
    n = tk.size
    cols_v: dict[str, np.ndarray] = {}
    soc_true = soc0 - 100.0 * e_day / _EV_USABLE_J
    voc = 560.0 + 1.3 * soc_true
    r_ohm = 0.1
    cur = (voc - np.sqrt(voc * voc - 4.0 * r_ohm * rate)) / (2.0 * r_ohm)
    volt = voc - r_ohm * cur
    m = np.where(rng.random(n) > 0.01, 1.0, np.nan)
    cols_v["fms_battery_voltage_v"] = _round_q(volt, 0.1) * m
    cols_v["fms_battery_current_a"] = _round_q(cur, 0.1) * m
    cols_v["fms_battery_soc_pct"] = np.where(_arrivals(tk, (9.0, 11.0), rng), _round_q(soc_true, 0.4), np.nan)
    kwh = veh.energy_counter_start_kwh + cons / J_PER_KWH
    cols_v["fms_total_energy_used_kwh"] = np.where(_arrivals(tk, (4.0, 6.0), rng), _floor_q(kwh, 0.1), np.nan)
    return cols_v


def _srf_assemble(veh: VehicleSpec, cols: tuple[str, ...], blocks: list[dict], records: list[dict],
                  faults: list[dict], rng: np.random.Generator) -> tuple[bytes, dict]:
    """The srf file's bytes from its trips' blocks of columns, with repeated ticks
    (identical duplicate lines), and its file record; each trip record and fault gets
    its lines."""
    allc = {c: np.concatenate([b["cols"][c] for b in blocks]) for c in blocks[0]["cols"]}
    ntot = allc["timestamp_ms"].size
    rep = rng.random(ntot) < 0.003
    order = np.repeat(np.arange(ntot), 1 + rep.astype(int))
    first_row = np.concatenate(([0], np.cumsum([b["n"] for b in blocks])))
    # line of row i of the original = header lines + position in `order`
    started = datetime.fromtimestamp(int(allc["timestamp_ms"][0] // 1000) - int(rng.integers(2, 9)), UTC)
    header = (
        f"# vehicle_id={veh.vehicle_id}\n# logger=SRF Logger 2.4.1\n"
        f"# started={started.strftime('%Y-%m-%dT%H:%M:%SZ')}\n"
        f"# fms_dongle=FMS-BT 1.7\n{','.join(cols)}\n"
    ).encode()
    n_head = header.count(b"\n")
    pos_first = np.searchsorted(order, np.arange(ntot), side="left")  # first output row of each tick
    pos_last = np.searchsorted(order, np.arange(ntot), side="right") - 1
    for j, rec in enumerate(records):
        rec["first_line"] = int(n_head + 1 + pos_first[first_row[j]])
        rec["last_line"] = int(n_head + 1 + pos_last[first_row[j + 1] - 1])
        del rec["_rows"]
    for f in faults:
        f["line"] = int(n_head + 1 + pos_first[f.pop("tick")])
    fields = [iso_utc_ms(allc["timestamp_ms"][order])]
    for c in cols[1:]:
        dec, strip = SRF_FORMAT[c]
        fields.append(num_field(allc[c][order], dec, strip=strip))
    data = header + assemble(fields, b",", b"\n")
    info = {"vehicle_id": veh.vehicle_id, "dialect": "srf", "rows": int(order.size), "repeated_ticks": int(rep.sum()),
            "faults": faults}
    return data, info


def srf_file(world: World, veh: VehicleSpec, trips: list[TruthTrip], date: str, state: Counters, fleet: FleetSpec,
              seed: int, transformer) -> tuple[bytes, list[dict], dict]:
    """One srf session file: (bytes, truth records of its trips, file record)."""
    rng = seeded_rng(seed, "srf", veh.vehicle_id, date)
    is_bus = veh.vehicle_type == "electric-bus"
    cols: tuple[str, ...] = SRF_BUS_COLUMNS if is_bus else SRF_TRUCK_COLUMNS
    if not is_bus and not veh.flowmeter:
        cols = tuple(c for c in cols if c != "flowmeter_fuel_lph")
    day_index = trips[0].day_index
    faults: list[dict] = []
    blocks: list[dict] = []
    records: list[dict] = []
    soc0 = float(rng.uniform(92.0, 100.0))
    day_energy0 = state.consumption
    alt_bias = float(rng.uniform(-10.0, 10.0))
    for tr in trips:
        T = float(tr.time_s[-1])
        n0 = int(T) + 1
        tk = np.arange(n0) + rng.uniform(0.0, 1.0) + rng.normal(0.0, 0.012, n0)
        tk = tk[(tk >= 0.0) & (tk <= T)]
        keep = rng.random(tk.size) > 0.01
        for _ in range(int(rng.integers(0, 3))):  # short bursts of missed ticks
            i0 = int(rng.integers(1, max(2, tk.size - 5)))
            keep[i0 : i0 + int(rng.integers(2, 5))] = False
        keep[0] = keep[-1] = True
        tk = tk[keep]
        n = tk.size
        at = tr.at(tk, world)
        cols_v: dict[str, np.ndarray] = {}
        cols_v.update(_srf_gps(tr, at, n, T, alt_bias, transformer, rng))
        # ---- FMS common (three broadcast groups, each missing in 0.5 % of ticks)
        fms = _fms_common(veh, tr, at, rng)
        groups = (("fms_wheel_speed_kmh", "fms_brake_switch"), ("fms_accel_pedal_pct",),
                  ("fms_engine_speed_rpm", "fms_engine_torque_pct"))
        for g in groups:
            m = np.where(rng.random(n) > 0.005, 1.0, np.nan)
            for c in g:
                cols_v[c] = fms[c] * m
        sensed = np.interp(tk, tr.time_s, ambient_sensor_c(tr))
        cols_v["fms_ambient_air_temp_c"] = np.where(_arrivals(tk, (4.0, 6.0), rng),
                                                    _round_q(sensed, AMBIENT_RESOLUTION_C), np.nan)
        cons = state.consumption + at["cons"]
        rate = np.diff(tr.consumption)[at["k"]]  # per 1 s step: l/s or W
        if is_bus:
            cols_v.update(_srf_battery(veh, tk, cons - day_energy0, cons, rate, soc0, rng))
        else:
            ecu = veh.fuel_counter_start_l + veh.ecu_fuel_bias * cons
            if fleet.fuel_reset and fleet.fuel_reset[:3] == (veh.vehicle_id, day_index, tr.trip_index):
                i_reset = n // 2
                state.reset_offset = fleet.fuel_reset[3] - veh.ecu_fuel_bias * cons[i_reset]
                faults.append({"kind": "fuel_counter_reset", "trip_index": tr.trip_index,
                               "tick": sum(b["n"] for b in blocks) + i_reset,
                               "from_l": float(_floor_q(ecu[i_reset - 1], 0.5)), "to_l": fleet.fuel_reset[3]})
                ecu = np.where(np.arange(n) >= i_reset, state.reset_offset + veh.ecu_fuel_bias * cons, ecu)
            elif state.reset_offset is not None:
                ecu = state.reset_offset + veh.ecu_fuel_bias * cons
            cols_v["fms_total_fuel_used_l"] = np.where(_arrivals(tk, (5.0, 10.0), rng), _floor_q(ecu, 0.5), np.nan)
            lph = np.maximum(0.0, veh.ecu_fuel_bias * rate * S_PER_H * (1.0 + rng.normal(0.0, 0.02, n)))
            cols_v["fms_fuel_rate_lph"] = np.where(rng.random(n) > 0.03, _round_q(lph, 0.05), np.nan)
            if veh.flowmeter:
                m = _arrivals(tk, (1.8, 2.2), rng)
                idx = np.flatnonzero(m)
                c_at = at["cons"][idx]
                prev_t = np.concatenate(([tk[idx[0]] - 2.0], tk[idx[:-1]])) if idx.size else idx
                prev_c = np.interp(prev_t, tr.time_s, tr.consumption) if idx.size else idx
                mean_lph = (c_at - prev_c) / np.maximum(tk[idx] - prev_t, 1e-3) * S_PER_H
                flow = np.full(n, np.nan)
                flow[idx] = _round_q(np.maximum(0.0, mean_lph * (1.0 + rng.normal(0.0, 0.015, idx.size))), 0.01)
                cols_v["flowmeter_fuel_lph"] = flow
            moved = np.cumsum(np.concatenate(([0.0], np.diff(tk))) * (at["speed"] > 0.5)) > 30.0
            cols_v["fms_gross_weight_kg"] = np.where(_arrivals(tk, (9.0, 11.0), rng) & moved,
                                                     _round_q(tr.mass_kg, 10.0), np.nan)
        # ---- clock: the phone clock ran ahead until a mid-trip correction
        clock = np.zeros(n)
        cs = fleet.clock_step
        if cs and cs[0] == veh.vehicle_id and cs[1] == day_index:
            if tr.trip_index < cs[2]:
                clock[:] = cs[3]
            elif tr.trip_index == cs[2]:
                i_step = n // 2
                clock[:i_step] = cs[3]
                faults.append({"kind": "clock_step_backwards", "trip_index": tr.trip_index,
                               "tick": sum(b["n"] for b in blocks) + i_step, "seconds": cs[3]})
        true_ms = np.round((tr.start_utc_s + tk) * 1000.0).astype(np.int64)
        cols_v["timestamp_ms"] = true_ms + np.round(clock * 1000.0).astype(np.int64)
        blocks.append({"n": n, "cols": cols_v})
        t_first, t_last = tk[0], tk[-1]
        c_first, c_last = at["cons"][0], at["cons"][-1]
        records.append({
            "vehicle_id": veh.vehicle_id, "vehicle_type": veh.vehicle_type, "dialect": "srf", "day_index": day_index,
            "trip_index": tr.trip_index, "start_utc_s": round(tr.start_utc_s + t_first, 3),
            "end_utc_s": round(tr.start_utc_s + t_last, 3), "duration_s": round(t_last - t_first, 3),
            "distance_m": round(float(at["distance"][-1] - at["distance"][0]), 2),
            "mass_kg": tr.mass_kg, "consumption": float(c_last - c_first),
            "route_from_m": round(tr.route_from_m + float(at["distance"][0]), 2),
            "load": tr.load, "dsm_covered_share": round(float(world.in_tiles(tr.x_m, tr.y_m).mean()), 4),
            **conditions_record(tr, t_first, t_last), "_rows": n,
        })
        state.consumption += float(tr.consumption[-1])
    data, info = _srf_assemble(veh, cols, blocks, records, faults, rng)
    return data, records, info


# ======================================================================================
# Sensors: portal
# ======================================================================================

PORTAL_COLUMNS = ("Registration", "Date/Time", "Latitude", "Longitude", "Speed (mph)", "Odometer (mi)", "Fuel Used (l)",
                  "Ignition", "Event")


def _portal_vehicle(world: World, veh: VehicleSpec, days: list[list[TruthTrip]], state: Counters, seed: int,
                    transformer) -> tuple[dict[str, np.ndarray], list[dict]]:
    """Rows of one vehicle (time order) and truth records of its trips."""
    rng = seeded_rng(seed, "portal", veh.vehicle_id)
    rows: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "x", "y", "speed_mph", "odo", "fuel", "ign", "event")}
    records = []
    trips = [tr for day in days for tr in day]
    events_pool = np.array(["", "Harsh braking", "Speeding", "Harsh acceleration"], dtype=object)
    for j, tr in enumerate(trips):
        T = int(tr.time_s[-1])
        v = tr.speed_mps
        moving = v > 0.3
        rate = np.where(moving, 1.0 / 5.0, 1.0 / 75.0) * rng.uniform(0.5, 1.5, v.size)
        cum = np.cumsum(rate)
        sel = np.flatnonzero(np.diff(np.floor(cum), prepend=0.0) > 0)
        # journey events: a row when the vehicle comes to rest and when it moves off
        change = np.flatnonzero(moving[1:] != moving[:-1])
        sel = np.unique(np.concatenate(([0], sel, change, change + 1, [T])))
        ts = sel.astype(float)
        at = tr.at(ts, world)
        n = ts.size
        ex = _ar1(n, 8.0, 3.0, rng)
        ny = _ar1(n, 8.0, 3.0, rng)
        rows["t"].append(tr.start_utc_s + ts)
        rows["x"].append(at["x"] + ex)
        rows["y"].append(at["y"] + ny)
        rows["speed_mph"].append(np.abs(at["speed"] + rng.normal(0.0, 0.2, n) * (at["speed"] > 0.3)) / MPH_TO_MPS)
        rows["odo"].append(state.odometer_m + at["distance"])
        rows["fuel"].append(veh.fuel_counter_start_l + state.consumption + at["cons"])
        ign = np.ones(n)
        ign[-1] = 0.0
        rows["ign"].append(ign)
        ev = np.full(n, "", dtype=object)
        # Harsh events on a few rows with the strongest deceleration / while fast.
        acc = np.diff(v, append=0.0)[sel]
        if n > 10:
            ev[int(np.argmin(acc))] = "Harsh braking"
            if rng.random() < 0.5:
                ev[int(rng.integers(1, n - 1))] = str(events_pool[int(rng.integers(1, 4))])
        if j == 0 or trips[j - 1].day_index != tr.day_index:
            ev[0] = "Départ dépôt – Café Rouge Distribution, Wolverton"
        if j + 1 == len(trips) or trips[j + 1].day_index != tr.day_index:
            ev[-1] = "Fuel card: £152,40 at Shell Newport Pagnell"
        rows["event"].append(ev)
        records.append({
            "vehicle_id": veh.vehicle_id, "vehicle_type": veh.vehicle_type, "dialect": "portal",
            "day_index": tr.day_index, "trip_index": j, "start_utc_s": float(tr.start_utc_s),
            "end_utc_s": float(tr.start_utc_s + T), "duration_s": float(T),
            "distance_m": round(float(tr.distance_m[-1]), 2), "mass_kg": tr.mass_kg,
            "consumption": float(tr.consumption[-1]),
            "route_from_m": round(tr.route_from_m, 2), "load": tr.load, **conditions_record(tr, 0.0, float(T)),
            "dsm_covered_share": round(float(world.in_tiles(tr.x_m, tr.y_m).mean()), 4),
        })
        state.odometer_m += float(tr.distance_m[-1])
        state.consumption += float(tr.consumption[-1])
        # Heartbeats while parked with the ignition off, until the next trip.
        if j + 1 < len(trips):
            nxt = trips[j + 1].start_utc_s
            hb = tr.start_utc_s + T + np.cumsum(rng.uniform(900.0, 1800.0, 40))
            hb = np.round(hb[hb < nxt - 30.0])
            m = hb.size
            if m:
                rows["t"].append(hb)
                rows["x"].append(np.full(m, at["x"][-1]) + rng.normal(0, 2.0, m))
                rows["y"].append(np.full(m, at["y"][-1]) + rng.normal(0, 2.0, m))
                rows["speed_mph"].append(np.zeros(m))
                rows["odo"].append(np.full(m, state.odometer_m))
                rows["fuel"].append(np.full(m, veh.fuel_counter_start_l + state.consumption))
                rows["ign"].append(np.zeros(m))
                rows["event"].append(np.full(m, "", dtype=object))
    out = {k: np.concatenate(vv) for k, vv in rows.items()}
    o = np.argsort(out["t"], kind="stable")
    out = {k: vv[o] for k, vv in out.items()}
    lon, lat = transformer.transform(out["x"], out["y"])
    nofix = rng.random(lon.size) < 0.002
    out["lat"], out["lon"] = np.where(nofix, 0.0, lat), np.where(nofix, 0.0, lon)
    return out, records


def portal_file(world: World, fleet: FleetSpec, truth: dict[str, list[list[TruthTrip]]], seed: int,
                 transformer) -> tuple[bytes, list[dict], dict]:
    """The portal export of all portal vehicles: (cp1252 bytes, truth records, file record)."""
    per = []
    records = []
    for veh in sorted(fleet.portal_vehicles, key=lambda v: v.vehicle_id):
        rows, recs = _portal_vehicle(world, veh, truth[veh.vehicle_id], Counters(odometer_m=veh.odometer_start_m),
                                     seed, transformer)
        per.append((veh, rows))
        records.extend(recs)
    reg = np.concatenate([np.full(r["t"].size, v.vehicle_id.encode("cp1252")) for v, r in per])
    allr = {k: np.concatenate([r[k] for _, r in per]) for k in per[0][1]}
    t = np.round(allr["t"]).astype(np.int64)
    texts, inverse = np.unique(allr["event"].astype(str), return_inverse=True)
    events = np.array([x.encode("cp1252") for x in texts], dtype=object)[inverse]
    fields = [
        text_field(reg), uk_local(t),
        num_field(allr["lat"], 5, dec=b","), num_field(allr["lon"], 5, dec=b","),
        num_field(allr["speed_mph"], 1, dec=b","), num_field(_floor_q(allr["odo"] / M_PER_MILE, 0.1), 1, dec=b","),
        num_field(_floor_q(allr["fuel"], 0.5), 1, dec=b","),
        text_field(np.where(allr["ign"] > 0, b"On", b"Off")),
        text_field(events),
    ]
    header = (";".join(PORTAL_COLUMNS) + "\r\n").encode("cp1252")
    data = header + assemble(fields, b";", b"\r\n")
    # lines: header is line 1; rows in (vehicle, time) order; trips start/end at exact rows
    lines = {}
    offset = 0
    for v, r in per:
        lines[v.vehicle_id] = (offset, np.round(r["t"]).astype(np.int64))
        offset += r["t"].size
    for rec in records:
        off, tt = lines[rec["vehicle_id"]]
        rec["first_line"] = int(2 + off + np.searchsorted(tt, round(rec["start_utc_s"]), side="left"))
        rec["last_line"] = int(2 + off + np.searchsorted(tt, round(rec["end_utc_s"]), side="left"))
    info = {"dialect": "portal", "rows": int(t.size), "vehicles": [v.vehicle_id for v, _ in per], "faults": []}
    return data, records, info


