"""The output columns of ``cevm predict`` and ``cevm feasibility``: one
:class:`~cevm.cli.columns.Column` each, with what it means and how its values come from
what the core computed.

**To add a column:** one ``Column(...)`` entry in :data:`PREDICT` (or
:data:`FEASIBILITY`), where it should stand in the CSV, with its meaning (and unit), its
kind, the powertrains whose rows have it, its decimals and its ``value``: a function of
the row context (:class:`BlockRows` for predict: one :class:`~cevm.core.sweep.SweepBlock`
in output units; :class:`VehicleRow` for feasibility: one vehicle of a
:class:`~cevm.core.feasibility.Feasibility`). CSV, JSON, table headers and formats and
the manual's reference (:meth:`~cevm.cli.columns.ColumnSpec.reference`) follow. To show
it in predict's table too, add its name to :data:`PREDICT_TABLE`.

A new per-row quantity of the core flows so: a field of
:class:`~cevm.core.sweep.SweepBlock` (an array of the block's rows, SI units, None when
not computed), filled by the core's evaluation (:mod:`cevm.core.sweep.evaluate`); here a
Column whose ``value`` reads it and converts it to the output unit
(``lambda r: r.optional(r.block.new_field_j, 1 / J_PER_KWH)``).

Predict's row order is source-major (source, then vehicle, then mass). Its JSON keys
start with :data:`PREDICT_JSON_LEAD`, the contract of the first ``cevm predict``; its
CSV starts with the same columns less ``powertrain`` and ``ice_braking``.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Any

import numpy as np

from cevm.cli.columns import Column, ColumnSpec
from cevm.core.intervals import EXTRAPOLATION_TEXTS, INTERVAL_SOURCES, RowRanges, block_ranges, p_reserve_ok, p_tank_ok
from cevm.core.sweep import AMBIENT_ORIGINS, DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT, SweepBlock
from cevm.units import J_PER_KWH, KMH_TO_MPS

MPS_TO_KMH = 1.0 / KMH_TO_MPS

EV, ICE = ("ev",), ("ice",)

#: The meanings of the columns predict and feasibility share (the one verdict of
#: :mod:`cevm.core.limits`, and what a row assumed).
VERDICT_MEANING = ("the verdict: keeps the reserve (EV) or fits the tank (ICE), within max_gross_kg, max_power_kw and "
                   "max_speed_kmh (a limit the vehicle file lacks is not checked: its flag is empty); empty when the "
                   "energy cannot be judged (ICE without tank_l)")
POWER_DEMAND_MEANING = ("the highest mean wheel power the source asks over any 5 s at the row's mass [kW] (one-step "
                        "spikes of a log removed; empty for vehicles without max_power_kw or max_speed_kmh)")
TOP_SPEED_MEANING = "the highest speed the source holds for 3 s [km/h] (empty as power_demand_kw)"
LIMITS_TOLERANCE_MEANING = ("how the source is held to max_power_kw and max_speed_kmh: exact (a cycle file, a "
                            "target) or with a log's measurement tolerance (a logged speed may read up to 10 % + "
                            "4 km/h high, UN ECE R39; its elevation is uncertain by the metres given)")
SOC_FROM_MEANING = ("where the start state of charge comes from: given (--soc-start), logged (a stored trip's own "
                    "logged start) or default (full: 100 %)")
ROAD_MEANING = ("the road's elevation: flat (none: a flat road assumed), elevation (a cycle's elevation or grade "
                "column), a stored trip's source of elevation (dsm, gps, ...), or route legs")


def limits_tolerance(source: Any) -> str:
    """The ``limits_tolerance`` of a source: ``exact`` or the log's tolerance."""
    if not getattr(source, "logged", False):
        return "exact"
    return f"log: speed +10 % +4 km/h, elevation sd {source.elevation_sd_m:g} m"


def road(source: Any) -> str:
    """The ``road`` of a source: ``flat``, ``elevation`` (a cycle's), a stored trip's
    elevation source, or ``route legs``."""
    if source.kind == "cycle":
        legs = source.leg_profiles
        return "flat" if all(leg.elevation_m is None for leg in legs) else "elevation"
    elevation = getattr(source, "elevation_source", None)
    if elevation:
        return str(elevation)
    return "route legs" if source.kind == "route" else "unknown"


# ------------------------------------------------------------------------------ predict


class RangeOptions:
    """What the interval columns need beside a block: the interval's ``level`` and the
    state of charge at the start and the reserve [%] (predict's options)."""

    def __init__(self, level: float = 0.9, soc_start_pct: float = DEFAULT_SOC_START_PCT,
                 reserve_pct: float = DEFAULT_RESERVE_PCT):
        self.level = level
        self.soc_start_pct = soc_start_pct
        self.reserve_pct = reserve_pct


#: What the column from_prior says (:func:`from_prior_text`).
FROM_PRIOR_MEANING = ("the terms the vehicle file leaves out, taken at the middle of their class prior's range (their "
                      "spread in the interval): of aux (auxiliary power), heat, cool (EV), idle, heat, cool (ICE), "
                      "joined by +; none where the file states them all")


def from_prior_text(vehicle: Any) -> str:
    """"none", or the terms a vehicle took from its priors (``vehicle.from_prior``), joined by "+"."""
    return "+".join(vehicle.from_prior) if vehicle.from_prior else "none"


def legend_name(row: dict) -> str:
    """A row's vehicle as the legend under a table names it: its name, and the terms its
    file leaves out that it took from its class's priors (column from_prior)."""
    taken = row.get("from_prior")
    return row["vehicle"] if taken in (None, "none") else f"{row['vehicle']} with {taken} from its class's priors"


class BlockRows:
    """What a predict column reads: one block of rows (:class:`~cevm.core.sweep.SweepBlock`)
    and where its masses come from (``mass_source``), with helpers that give arrays of
    the block's rows in output units: numbers and booleans as floats (NaN: no value),
    text as (codes, categories); ``options`` the level of its intervals and the state of
    charge they are measured against (:class:`RangeOptions`)."""

    def __init__(self, block: SweepBlock, mass_source: str = "vehicle file", options: RangeOptions | None = None,
                 soc_from: str = "default"):
        self.block = block
        self.mass_source = mass_source
        self.soc_from = soc_from
        self.pset = block.pset
        self.source = block.source
        self.n = block.pset.n
        self.options = options or RangeOptions()

    @cached_property
    def ranges(self) -> RowRanges:
        """Each row's predictive distribution (:func:`cevm.core.intervals.block_ranges`)."""
        return block_ranges(self.block)

    @cached_property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The rows' interval [J (EV) or l (ICE)] at the options' level."""
        return self.ranges.bounds(self.options.level)

    def bound(self, high: bool, ev: bool) -> np.ndarray:
        """The interval's low or high end on the rows of one powertrain (NaN on the others)."""
        return np.where(self.pset.is_ev == ev, self.bounds[int(high)], np.nan)

    def soc_at(self, bound: np.ndarray) -> np.ndarray:
        """The state of charge at the end [%] with ``bound`` [J] drawn instead of the
        row's energy: where the row reaches its end, never below 0 (an EV that may run
        empty: p_reserve_ok says how likely)."""
        with np.errstate(invalid="ignore"):
            soc = self.block.soc_end_pct + 100.0 * (self.block.energy_j - bound) / self.pset.battery_j
            return np.where(np.isfinite(self.block.soc_end_pct), np.maximum(soc, 0.0), np.nan)

    def fuel_left(self, bound: np.ndarray) -> np.ndarray:
        """tank_l less ``bound`` [l], never below 0 (NaN without tank_l)."""
        return np.maximum(self.pset.tank_l - bound, 0.0)

    @cached_property
    def km(self) -> float:
        """The source's distance [km]."""
        return self.source.distance_m / 1000.0

    def per_km(self, values: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """``scale * values`` per km of the source (NaN for a source that does not move)."""
        km = self.km
        with np.errstate(invalid="ignore", divide="ignore"):
            return scale * values / km if km > 0 else np.full(self.n, np.nan)

    def same(self, value: float) -> np.ndarray:
        """One number for every row."""
        return np.full(self.n, value)

    def text(self, value: str) -> tuple[np.ndarray, list[str]]:
        """One text for every row."""
        return np.zeros(self.n, dtype=np.int64), [value]

    def by_vehicle(self, values: list[str]) -> tuple[np.ndarray, list[str]]:
        """One text per vehicle of the prediction set."""
        return self.pset.vehicle_index, values

    def ev(self, value: float) -> np.ndarray:
        """One number for every EV row (NaN on ICE rows)."""
        return np.where(self.pset.is_ev, value, np.nan)

    def top_speed_kmh(self) -> np.ndarray:
        """The source's held top speed [km/h] on the rows whose vehicle has a speed or
        power limit (where the source's demand was computed), NaN elsewhere."""
        d = self.block.power_demand_w
        if d is None:
            return np.full(self.n, np.nan)
        return np.where(np.isfinite(d), self.source.demand.top_speed_mps * MPS_TO_KMH, np.nan)

    def optional(self, values: np.ndarray | None, scale: float = 1.0) -> np.ndarray:
        """An optional block array (None: not computed) times ``scale`` (NaN where none)."""
        return np.full(self.n, np.nan) if values is None else values * scale

    @cached_property
    def truth(self) -> dict[str, np.ndarray]:
        """A stored trip's measured consumption (litres for a fuel measurement, kWh for a
        battery one) on every row, and the error e = (modelled - measured) / measured [%]
        of each row of the matching powertrain when the rows are at the trip's own mass
        (not at a --mass-kg or --payload-kg given for every source); NaN elsewhere."""
        n, block = self.n, self.block
        fuel, energy, error = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
        measured = getattr(self.source, "measured", None)  # a stored trip's (cevm.store.sources.StoredTrip)
        if measured is not None and measured.value > 0:
            if measured.kind == "fuel_l":
                fuel[:], modelled = measured.value, block.fuel_l
            else:
                energy[:], modelled = measured.value / J_PER_KWH, block.energy_j
            if self.mass_source not in ("--mass-kg", "--payload-kg"):
                error = 100.0 * (modelled - measured.value) / measured.value  # NaN on rows of the other powertrain
        return {"measured_fuel_l": fuel, "measured_energy_kwh": energy, "error_pct": error}


def _vehicle_names(r: BlockRows) -> tuple[np.ndarray, list[str]]:
    return r.by_vehicle([v.name for v in r.pset.vehicles])


PREDICT = ColumnSpec((
    Column("cycle", "the source's name: a cycle file's stem (with --speed-col, stem[column]), a trip id, a route",
           kind="text", value=lambda r: r.text(r.source.name)),
    Column("vehicle", "the vehicle's name (its file's name key)", kind="text", value=_vehicle_names),
    Column("mass_kg", "gross mass [kg]", header="mass kg", digits=0, decimals=3, value=lambda r: r.pset.mass_kg),
    Column("distance_km", "the source's distance [km]", header="km", digits=2,
           value=lambda r: r.same(r.km)),
    Column("duration_s", "the source's duration [s]", header="s", digits=0, decimals=3,
           value=lambda r: r.same(r.source.duration_s)),
    Column("wheel_energy_kwh", "energy at the wheels over the source [kWh] (eq. 22-30)", header="wheel kWh",
           digits=2, value=lambda r: r.block.wheel_energy_j / J_PER_KWH),
    Column("energy_kwh", "battery energy over the source [kWh]", EV, header="battery kWh", digits=2,
           value=lambda r: r.block.energy_j / J_PER_KWH),
    Column("energy_kwh_per_km", "battery energy per km [kWh/km]", EV, header="kWh/km", digits=3,
           value=lambda r: r.per_km(r.block.energy_j / J_PER_KWH)),
    Column("fuel_l", "fuel over the source [l]", ICE, header="fuel l", digits=2, value=lambda r: r.block.fuel_l),
    Column("fuel_l_per_100km", "fuel per 100 km [l/100km]", ICE, header="l/100km", digits=1,
           value=lambda r: r.per_km(r.block.fuel_l, 100.0)),
    Column("source_kind", "what the source is: cycle, trip or route", kind="text",
           value=lambda r: r.text(r.source.kind)),
    Column("powertrain", "ev or ice", kind="text",
           value=lambda r: r.by_vehicle([v.powertrain for v in r.pset.vehicles])),
    Column("payload_kg", "gross mass less the kerb mass [kg] (empty without kerb_mass_kg)", header="payload kg",
           digits=0, decimals=3, value=lambda r: r.pset.payload_kg),
    Column("over_max_gross", "the gross mass is above the vehicle's max_gross_kg", kind="bool",
           header="over max gross", value=lambda r: r.pset.over_max_gross.astype(float)),
    Column("soc_end_pct", "state of charge at the end [%] (empty when it runs empty on the way)", EV,
           header="SoC end %", digits=1, value=lambda r: r.block.soc_end_pct),
    Column("soc_min_pct", "lowest state of charge along the way [%], never below 0", EV, header="SoC min %",
           digits=1, value=lambda r: r.block.soc_min_pct),
    Column("reserve_ok", "the lowest state of charge keeps --reserve-pct", EV, kind="bool", header="reserve ok",
           value=lambda r: np.where(r.pset.is_ev, r.block.reserve_ok.astype(float), np.nan)),
    Column("tank_ok", "the fuel fits tank_l (empty without tank_l)", ICE, kind="bool", header="tank ok",
           value=lambda r: r.block.tank_ok),
    Column("ice_braking", "the braking mode in force: paper (braking energy credited, eq. 24) or no-credit", ICE,
           kind="text", value=lambda r: r.by_vehicle(list(r.pset.braking))),
    Column("ambient_c", "the ambient temperature the row assumed [degC]", header="ambient degC", digits=1,
           decimals=3, value=lambda r: r.block.ambient_c),
    Column("ambient_from", "where the temperature comes from: given, source, the vehicle's reference_temp_c or "
           "the default", kind="text",
           value=lambda r: (r.block.ambient_from.astype(np.int64), list(AMBIENT_ORIGINS))),
    Column("vehicle_key", "the vehicle's id: its file's id key, else its stem", kind="text", header="vehicle",
           value=lambda r: r.by_vehicle([v.label for v in r.pset.vehicles])),
    Column("reserve_at_km", "where the reserve is first crossed [km from the start] (empty if it is kept)", EV,
           value=lambda r: r.optional(r.block.reserve_at_m, 1e-3)),
    Column("reserve_at_s", "when the reserve is first crossed [s from the start]", EV, decimals=3,
           value=lambda r: r.optional(r.block.reserve_at_s)),
    Column("empty_at_km", "where the battery or the tank runs empty [km from the start] (empty if it does not)",
           value=lambda r: r.optional(r.block.empty_at_m, 1e-3)),
    Column("empty_at_s", "when the battery or the tank runs empty [s from the start]", decimals=3,
           value=lambda r: r.optional(r.block.empty_at_s)),
    Column("range_km", "with --range: the distance to empty, the source driven again and again [km]",
           header="range km", digits=1, value=lambda r: r.optional(r.block.range_m, 1e-3)),
    Column("range_reserve_km", "with --range: the distance to the reserve, the source driven again and again [km]",
           EV, value=lambda r: r.optional(r.block.range_reserve_m, 1e-3)),
    Column("over_power", "the source asks more wheel power than max_power_kw at the row's mass (over any 5 s; "
           "empty without max_power_kw)", kind="bool", value=lambda r: r.optional(r.block.over_power)),
    Column("over_speed", "the source is faster than max_speed_kmh (empty without it)", kind="bool",
           value=lambda r: r.optional(r.block.over_speed)),
    Column("mass_source", "where the row's mass comes from: --mass-kg, --payload-kg, the vehicle file, or a stored "
           "trip's own (manifest, by hand, logged)", kind="text", header="mass from",
           value=lambda r: r.text(r.mass_source)),
    Column("measured_fuel_l", "a stored trip's measured fuel [l]", ICE, header="measured l", digits=2,
           value=lambda r: r.truth["measured_fuel_l"]),
    Column("measured_energy_kwh", "a stored trip's measured battery energy [kWh]", EV, header="measured kWh",
           digits=2, value=lambda r: r.truth["measured_energy_kwh"]),
    Column("error_pct", "(modelled - measured) / measured [%], at a stored trip's own mass", header="error %",
           digits=1, value=lambda r: r.truth["error_pct"]),
    Column("interval", "the level of the row's interval (--interval: 0.9 is the central 90 %)", digits=3,
           value=lambda r: r.same(r.options.level)),
    Column("energy_kwh_low", "the interval's low end of the battery energy [kWh]", EV, header="kWh low", digits=2,
           value=lambda r: r.bound(False, True) / J_PER_KWH),
    Column("energy_kwh_high", "the interval's high end of the battery energy [kWh]", EV, header="kWh high", digits=2,
           value=lambda r: r.bound(True, True) / J_PER_KWH),
    Column("soc_end_pct_low", "state of charge at the end with the interval's high energy [%] (never below 0)", EV,
           header="SoC end % low", digits=1, value=lambda r: r.soc_at(r.bound(True, True))),
    Column("soc_end_pct_high", "state of charge at the end with the interval's low energy [%]", EV,
           header="SoC end % high", digits=1, value=lambda r: r.soc_at(r.bound(False, True))),
    Column("p_reserve_ok", "the probability of completing the source with --reserve-pct kept all along", EV,
           header="P reserve ok", digits=3, decimals=6,
           value=lambda r: p_reserve_ok(r.block, r.ranges, r.block.soc_start_pct, r.block.reserve_pct)),
    Column("fuel_l_low", "the interval's low end of the fuel [l]", ICE, header="fuel l low", digits=2,
           value=lambda r: r.bound(False, False)),
    Column("fuel_l_high", "the interval's high end of the fuel [l]", ICE, header="fuel l high", digits=2,
           value=lambda r: r.bound(True, False)),
    Column("fuel_left_l_low", "fuel left in tank_l with the interval's high fuel [l] (never below 0)", ICE,
           value=lambda r: r.fuel_left(r.bound(True, False))),
    Column("fuel_left_l_high", "fuel left in tank_l with the interval's low fuel [l]", ICE,
           value=lambda r: r.fuel_left(r.bound(False, False))),
    Column("p_tank_ok", "the probability that the fuel fits tank_l (empty without tank_l)", ICE, header="P tank ok",
           digits=3, decimals=6, value=lambda r: p_tank_ok(r.block, r.ranges)),
    Column("interval_from", "what the interval comes from: posterior (the vehicle's calibration), prior (its "
           "class's ranges: a file never calibrated) or none (a vehicle without priors)", kind="text",
           value=lambda r: (r.ranges.source, list(INTERVAL_SOURCES))),
    Column("from_prior", FROM_PRIOR_MEANING, kind="text",
           value=lambda r: (r.pset.vehicle_index, [from_prior_text(v) for v in r.pset.vehicles])),
    Column("extrapolation", "none, or which of temperature, mass, speed (mean), duty (share of time standing) lie "
           "outside what the vehicle's calibration saw (never calibrated: none)", kind="text",
           value=lambda r: (r.ranges.extrapolation, list(EXTRAPOLATION_TEXTS))),
    Column("feasible", VERDICT_MEANING, kind="bool", value=lambda r: r.optional(r.block.feasible)),
    Column("power_demand_kw", POWER_DEMAND_MEANING, header="power kW", digits=0,
           value=lambda r: r.optional(r.block.power_demand_w, 1e-3)),
    Column("top_speed_kmh", TOP_SPEED_MEANING, header="top km/h", digits=1, value=lambda r: r.top_speed_kmh()),
    Column("limits_tolerance", LIMITS_TOLERANCE_MEANING, kind="text",
           value=lambda r: r.text(limits_tolerance(r.source))),
    Column("soc_start_pct", "state of charge at the start [%]", EV, header="SoC start %", digits=1,
           value=lambda r: r.ev(r.block.soc_start_pct)),
    Column("soc_start_from", SOC_FROM_MEANING, EV, kind="text", header="SoC start from",
           value=lambda r: (np.where(r.pset.is_ev, 0, 1).astype(np.int64), [r.soc_from, ""])),
    Column("reserve_pct", "the state of charge to keep all along [%] (--reserve-pct)", EV, header="reserve %",
           digits=1, value=lambda r: r.ev(r.block.reserve_pct)),
    Column("road", ROAD_MEANING, kind="text", value=lambda r: r.text(road(r.source))),
), json_lead=("cycle", "vehicle", "powertrain", "mass_kg", "distance_km", "duration_s", "wheel_energy_kwh",
              "energy_kwh", "energy_kwh_per_km", "fuel_l", "fuel_l_per_100km", "ice_braking"))

#: The keys every predict JSON object starts with (the first contract).
PREDICT_JSON_LEAD = PREDICT.json_lead

#: Predict's table status: the verdict (column feasible) and why not
#: (:func:`verdict_text`); for people only, not in CSV or JSON.
STATUS = Column("status", "the verdict (column feasible), why not, and where the energy's verdict is not sure "
                "(the probability rounds to neither 0 nor 1) its probability", kind="text", header="feasible",
                layout="wrap")


def verdict_reasons(row: dict[str, Any], energy: bool = True) -> list[str]:
    """Why a row's verdict (columns feasible and its flags, of predict or feasibility) is
    not a plain yes, in words: where it runs empty or first crosses the reserve
    (``energy``), an ICE vehicle without tank_l, over max gross, what it cannot follow."""
    ev = row["powertrain"] == "ev"
    out = []
    if energy and row.get("empty_at_km") is not None:
        out.append(f"empty at {row['empty_at_km']:,.1f} km")
    elif energy and ev and row.get("reserve_at_km") is not None:
        out.append(f"reserve at {row['reserve_at_km']:,.1f} km")
    if not ev and row.get("tank_ok") is None:
        out.append("no tank_l")
    if row.get("over_max_gross"):
        out.append("over max gross")
    cannot = [what for what, key in (("power", "over_power"), ("speed", "over_speed")) if row.get(key)]
    if cannot:
        out.append(f"cannot follow: {', '.join(cannot)}")
    return out


def verdict_text(row: dict[str, Any], energy: bool = True) -> str:
    """A row's verdict for people: yes, NO or ? (column feasible), and why
    (:func:`verdict_reasons`)."""
    f = row.get("feasible")
    text = "?" if f is None else "yes" if f else "NO"
    why = verdict_reasons(row, energy)
    p = row.get("p_reserve_ok" if row.get("powertrain") == "ev" else "p_tank_ok")
    if p is not None and row.get("interval_from") in ("posterior", "prior") and 0.005 <= p < 0.995:
        why.append(f"P {p:.2f}")  # where the energy's verdict is not sure (column p_reserve_ok / p_tank_ok)
    return text + (f" ({'; '.join(why)})" if why else "")


def assumptions_line(rows: list[dict[str, Any]], source_key: str = "cycle") -> tuple[str | None, bool]:
    """The line under a predict or feasibility table that says what its rows assumed
    (columns soc_start_pct, soc_start_from, reserve_pct, road, limits_tolerance), and
    whether the start state of charge differs between rows (then the table shows its
    column). ``source_key``: the rows' source column."""
    from collections import Counter

    parts = []
    ev = [r for r in rows if r.get("powertrain") == "ev" and r.get("soc_start_pct") is not None]
    socs = {(r["soc_start_pct"], r.get("soc_start_from")) for r in ev}
    varies = len(socs) > 1
    if len(socs) == 1:
        soc, origin = socs.pop()
        parts.append(f"start SoC {soc:g} % ({origin})")
    elif varies:
        origins = Counter(r.get("soc_start_from") for r in ev)
        parts.append("start SoC per row (" + ", ".join(f"{n} {o}" for o, n in origins.most_common()) + ")")
    reserves = sorted({r["reserve_pct"] for r in ev if r.get("reserve_pct") is not None})
    if reserves:
        parts.append("reserve " + ", ".join(f"{x:g}" for x in reserves) + " %")
    roads = Counter(str(road) for road in {r.get(source_key): r.get("road") for r in rows if r.get("road")}.values())
    if roads:
        parts.append("road " + ", ".join(f"{what} ({n})" if len(roads) > 1 else what for what, n in
                                          sorted(roads.items(), key=lambda kv: (-kv[1], kv[0]))))
    if any(r.get("limits_tolerance", "exact") != "exact" for r in rows):
        parts.append("logs held to their vehicle's limits within their measurement tolerance (column "
                     "limits_tolerance)")
    return ("assumed: " + "; ".join(parts) if parts else None), varies

#: The row's interval as one short text, for people only (:func:`interval_text`: the
#: interval is central, so its half-width says it); its header says the level.
INTERVAL_TEXT = Column("interval_text", "half the width of the row's central interval of the battery energy (EV, "
                       "kWh) or the fuel (ICE, l) at --interval", kind="text", header="+-", layout="right")


def interval_text(row: dict) -> str | None:
    """'+-half-width unit' of a row's energy (EV) or fuel (ICE) interval: half its
    width (a log-normal interval reaches a little further above the mean than below it;
    the CSV and JSON give both ends, ``*_low`` and ``*_high``); None without one."""
    ev = row.get("powertrain") == "ev"
    key, unit = ("energy_kwh", "kWh") if ev else ("fuel_l", "l")
    lo, hi = row.get(f"{key}_low"), row.get(f"{key}_high")
    if lo is None or hi is None:
        return None
    half = 0.5 * (hi - lo)
    d = 2 if half < 100 else 1 if half < 1000 else 0
    return f"+-{half:,.{d}f} {unit}"


#: The columns predict's table may show, in order (those without a value in any row are
#: left out, and ambient_c comes in where a vehicle uses the temperature; see
#: :class:`cevm.cli.predict.PredictWriter`): names of :data:`PREDICT`, and "status".
PREDICT_TABLE = ("cycle", "vehicle_key", "mass_kg", "mass_source", "soc_start_pct", "distance_km", "energy_kwh",
                 "measured_energy_kwh",
                 "energy_kwh_per_km", "soc_min_pct", "fuel_l", "measured_fuel_l", "error_pct", "fuel_l_per_100km",
                 "range_km", "status", "interval_text")
#: What predict's table keeps on a narrow terminal (never left out) and what it leaves
#: out first, in order (:func:`cevm.cli.output.print_table`; the rest go from the right).
PREDICT_TABLE_KEEP = ("cycle", "energy_kwh", "fuel_l", "status")
PREDICT_TABLE_DROP = ("ambient_c", "mass_source", "soc_start_pct", "distance_km", "energy_kwh_per_km",
                      "fuel_l_per_100km", "range_km",
                      "soc_min_pct", "measured_energy_kwh", "measured_fuel_l", "interval_text")


# -------------------------------------------------------------------------- feasibility


class VehicleRow:
    """What a feasibility column reads: vehicle ``i`` of a
    :class:`~cevm.core.feasibility.Feasibility`, the run's ``ice_braking`` override and
    where the masses come from (``mass_source``). Values are Python values: None where a
    row has none."""

    def __init__(self, res: Any, i: int, ice_braking: str | None, mass_source: str, level: float = 0.9,
                 soc_from: str = "default"):
        self.res = res
        self.i = i
        self.level = level
        self.vehicle = res.vehicles[i]
        self.source = res.source
        self.ice_braking = ice_braking
        self.mass_source = mass_source
        self.soc_from = soc_from

    def flag(self, values: np.ndarray | None) -> bool | None:
        """This vehicle's flag (1.0 / 0.0) as a bool; None where unknown."""
        x = None if values is None else self.num(values)
        return None if x is None else x > 0.5

    def top_speed_kmh(self) -> float | None:
        """The source's held top speed [km/h] where the vehicle has a speed or power
        limit."""
        d = self.res.power_demand_w
        if d is None or self.num(d) is None:
            return None
        return self.source.demand.top_speed_mps * MPS_TO_KMH

    def num(self, values: np.ndarray) -> float | None:
        """This vehicle's value of a result array; None for NaN."""
        x = float(values[self.i])
        return None if x != x else x

    def bound(self, high: bool) -> float | None:
        """The interval's end at ``level`` of the energy [J] (EV) or fuel [l] (ICE)."""
        from cevm.core.distribution import interval

        if self.res.sd is None:
            return None
        mean = self.res.energy_j[self.i] if self.vehicle.is_ev else self.res.fuel_l[self.i]
        x = float(interval(mean, self.res.sd[self.i], self.level)[int(high)])
        return None if x != x else x

    def soc_at(self, energy_j: float | None) -> float | None:
        """The state of charge at the end [%] with ``energy_j`` drawn instead (>= 0)."""
        end = self.num(self.res.soc_end_pct)
        if end is None or energy_j is None or not self.vehicle.battery_j:
            return None
        return max(0.0, end + 100.0 * (float(self.res.energy_j[self.i]) - energy_j) / self.vehicle.battery_j)

    def extrapolation(self) -> str:
        from cevm.core.vehicle import extrapolation_mask, extrapolation_text

        vec = self.source.vector
        speed = vec.distance_m / vec.duration_s if vec.duration_s > 0 else None
        idle = vec.idle_s / vec.duration_s if vec.duration_s > 0 else None
        t = None if self.res.ambient_c is None else float(self.res.ambient_c[self.i])
        mask = extrapolation_mask(self.vehicle.calibration, mass_kg=float(self.res.mass_kg[self.i]),
                                  ambient_c=t, mean_speed_mps=speed, idle_share=idle)
        return extrapolation_text(int(mask))

    def range_km(self, range_m: np.ndarray) -> float | None:
        """A range in km; None where unknown, and where unlimited (a source that gives back
        what it takes: JSON has no infinity)."""
        x = float(range_m[self.i])
        return None if not math.isfinite(x) else x / 1e3


def _feasible(r: VehicleRow) -> bool | None:
    f = r.res.feasible[r.i]
    return None if f != f else bool(f > 0.5)


FEASIBILITY = ColumnSpec((
    # named as predict's and simulate's first column (its name: a cycle file's, a stored trip's or route's)
    Column("cycle", "the cycle, trip or route", kind="text", value=lambda r: r.source.name),
    Column("source_kind", "what the source is: cycle, trip or route", kind="text", value=lambda r: r.source.kind),
    Column("vehicle", "the vehicle's name", kind="text", value=lambda r: r.vehicle.name),
    Column("vehicle_key", "the vehicle's id: its file's id key, else its stem", kind="text",
           value=lambda r: r.vehicle.label),
    Column("powertrain", "ev or ice", kind="text", value=lambda r: r.vehicle.powertrain),
    Column("distance_km", "the source's distance [km]", value=lambda r: r.source.distance_m / 1000.0),
    Column("mass_kg", "the gross mass evaluated [kg]", value=lambda r: float(r.res.mass_kg[r.i])),
    Column("payload_kg", "the payload evaluated [kg], from kerb_mass_kg (else mass_kg)",
           value=lambda r: float(r.res.payload_kg[r.i])),
    Column("over_max_gross", "the gross mass is above max_gross_kg", kind="bool",
           value=lambda r: bool(r.res.over_max_gross[r.i])),
    Column("feasible", VERDICT_MEANING + "; the reserve or the tank with probability --confidence", kind="bool",
           value=_feasible),
    Column("energy_kwh", "battery energy over the source [kWh]", EV, value=lambda r: r.num(r.res.energy_j / J_PER_KWH)),
    Column("soc_end_pct", "state of charge at the end [%] (empty when it runs empty on the way)", EV,
           value=lambda r: r.num(r.res.soc_end_pct)),
    Column("soc_min_pct", "lowest state of charge along the way [%]", EV, value=lambda r: r.num(r.res.soc_min_pct)),
    Column("reserve_margin_pct", "lowest state of charge less the reserve [percentage points]", EV,
           value=lambda r: r.num(r.res.reserve_margin_pct)),
    Column("fuel_l", "fuel over the source [l]", ICE, value=lambda r: r.num(r.res.fuel_l)),
    Column("tank_l", "the vehicle's tank [l] (empty without tank_l)", ICE, value=lambda r: r.vehicle.tank_l),
    Column("tank_margin_l", "tank less fuel [l]", ICE, value=lambda r: r.num(r.res.tank_margin_l)),
    Column("ice_braking", "the braking mode in force: paper or no-credit", ICE, kind="text",
           value=lambda r: r.ice_braking or r.vehicle.ice_braking),
    Column("max_payload_kg", "the largest whole-kg payload that keeps the reserve or fits the tank with "
           "probability --confidence, within max_gross_kg or the search cap, at masses the vehicle can follow the "
           "source at (max_power_kw, max_speed_kmh) [kg] (empty: none does)",
           value=lambda r: r.num(r.res.max_payload_kg)),
    Column("min_payload_kg", "the smallest such payload [kg] (above 0 only where the empty vehicle fails)",
           value=lambda r: r.num(r.res.min_payload_kg)),
    Column("limited_by", "what limits the payload: reserve, tank, max_gross_kg, payload_cap, max_power_kw, "
           "max_speed_kmh or infeasible",
           kind="text", value=lambda r: r.res.limited_by[r.i]),
    Column("ambient_c", "the ambient temperature evaluated at [degC]", value=lambda r: r.num(r.res.ambient_c)),
    Column("ambient_from", "where the temperature comes from", kind="text", value=lambda r: r.res.ambient_from[r.i]),
    Column("reserve_at_km", "where the reserve is first crossed [km] (empty if kept)", EV,
           value=lambda r: r.num(r.res.reserve_at_m / 1e3)),
    Column("reserve_at_s", "when the reserve is first crossed [s]", EV, value=lambda r: r.num(r.res.reserve_at_s)),
    Column("empty_at_km", "where the battery or tank runs empty [km] (empty if it does not)",
           value=lambda r: r.num(r.res.empty_at_m / 1e3)),
    Column("empty_at_s", "when the battery or tank runs empty [s]", value=lambda r: r.num(r.res.empty_at_s)),
    Column("range_km", "the distance to empty, the source driven again and again [km] (empty: unlimited)",
           value=lambda r: r.range_km(r.res.range_m)),
    Column("range_reserve_km", "the distance to the reserve, the source driven again and again [km]", EV,
           value=lambda r: r.range_km(r.res.range_reserve_m)),
    Column("mass_source", "where the mass comes from: --mass-kg, --payload-kg, the vehicle file, or a stored "
           "trip's own", kind="text", value=lambda r: r.mass_source),
    Column("confidence", "the probability with which feasible and max_payload_kg keep the reserve or fit the "
           "tank (--confidence)", value=lambda r: r.res.confidence),
    Column("p_reserve_ok", "at the evaluated load, the probability of keeping --reserve-pct all along", EV,
           value=lambda r: r.num(r.res.p_ok) if r.res.p_ok is not None else None),
    Column("p_tank_ok", "at the evaluated load, the probability that the fuel fits tank_l (empty without tank_l)",
           ICE, value=lambda r: r.num(r.res.p_ok) if r.res.p_ok is not None else None),
    Column("interval", "the level of the energy's or fuel's interval (--interval)", value=lambda r: r.level),
    Column("energy_kwh_low", "the interval's low end of the battery energy [kWh]", EV,
           value=lambda r: None if r.bound(False) is None else r.bound(False) / J_PER_KWH),
    Column("energy_kwh_high", "the interval's high end of the battery energy [kWh]", EV,
           value=lambda r: None if r.bound(True) is None else r.bound(True) / J_PER_KWH),
    Column("soc_end_pct_low", "state of charge at the end with the interval's high energy [%] (never below 0)", EV,
           value=lambda r: r.soc_at(r.bound(True))),
    Column("soc_end_pct_high", "state of charge at the end with the interval's low energy [%]", EV,
           value=lambda r: r.soc_at(r.bound(False))),
    Column("fuel_l_low", "the interval's low end of the fuel [l]", ICE, value=lambda r: r.bound(False)),
    Column("fuel_l_high", "the interval's high end of the fuel [l]", ICE, value=lambda r: r.bound(True)),
    Column("interval_from", "what the interval comes from: posterior, prior (a file never calibrated) or none",
           kind="text", value=lambda r: r.res.interval_from[r.i] if r.res.interval_from else "none"),
    Column("from_prior", FROM_PRIOR_MEANING, kind="text", value=lambda r: from_prior_text(r.vehicle)),
    Column("extrapolation", "none, or which of temperature, mass, speed, duty lie outside what the vehicle's "
           "calibration saw", kind="text", value=lambda r: r.extrapolation()),
    Column("over_power", "the source asks more wheel power than max_power_kw at the evaluated mass (over any 5 s; "
           "empty without max_power_kw)", kind="bool", value=lambda r: r.flag(r.res.over_power)),
    Column("over_speed", "the source is faster than max_speed_kmh (empty without it)", kind="bool",
           value=lambda r: r.flag(r.res.over_speed)),
    Column("reserve_ok", "the lowest state of charge keeps the reserve", EV, kind="bool",
           value=lambda r: r.flag(r.res.reserve_ok)),
    Column("tank_ok", "the fuel fits tank_l (empty without tank_l)", ICE, kind="bool",
           value=lambda r: r.flag(r.res.tank_ok)),
    Column("power_demand_kw", POWER_DEMAND_MEANING,
           value=lambda r: None if r.res.power_demand_w is None else r.num(r.res.power_demand_w / 1e3)),
    Column("top_speed_kmh", TOP_SPEED_MEANING, value=lambda r: r.top_speed_kmh()),
    Column("limits_tolerance", LIMITS_TOLERANCE_MEANING, kind="text", value=lambda r: limits_tolerance(r.source)),
    Column("soc_start_pct", "state of charge at the start [%]", EV, value=lambda r: r.res.soc_start_pct),
    Column("soc_start_from", SOC_FROM_MEANING, EV, kind="text", value=lambda r: r.soc_from),
    Column("reserve_pct", "the state of charge to keep all along [%] (--reserve-pct)", EV,
           value=lambda r: r.res.reserve_pct),
    Column("road", ROAD_MEANING, kind="text", value=lambda r: road(r.source)),
))


def feasibility_row(res: Any, i: int, ice_braking: str | None, mass_source: str, level: float = 0.9,
                    soc_from: str = "default") -> dict[str, Any]:
    """The output row of vehicle ``i`` of a feasibility result: the columns its powertrain
    has, in order (``level``: its interval's; ``soc_from``: where its start state of
    charge comes from)."""
    ctx = VehicleRow(res, i, ice_braking, mass_source, level, soc_from)
    return FEASIBILITY.values(ctx, FEASIBILITY.for_powertrain(ctx.vehicle.powertrain))
