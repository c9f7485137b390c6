"""The output columns of ``cevm replay``: one row per duty, each a
:class:`~cevm.cli.columns.Column` with its meaning and how its values come from a
vehicle's replay (:class:`DutyRows`: a :class:`~cevm.core.replay.VehiclePlan` and its
duties' probabilities, in output units).

**To add a column:** one ``Column(...)`` entry in :data:`REPLAY`, where it should stand
in the CSV, with its ``value`` a function of :class:`DutyRows`; CSV, JSON and the
manual's reference follow. :data:`REPLAY_TABLE` lists what the table shows.

EV rows (an electric candidate) have the battery's columns (``energy_kwh``,
``soc_*_pct``, ``charged_kwh`` ...), ICE rows the tank's (``fuel_l``, ``tank_*_pct``,
``refuelled_l`` ...). Every row says what it assumed: the candidate, the start level, the
reserve, the charger and where it charges, the rests, how duties were formed, the masses'
and temperatures' sources, what the calibration did not see, and where the probability
comes from.
"""

from __future__ import annotations

from datetime import UTC, datetime, tzinfo
from functools import cached_property

import numpy as np

from cevm.cli.columns import Column, ColumnSpec
from cevm.core.sweep import AMBIENT_ORIGINS
from cevm.units import J_PER_KWH

EV, ICE = ("ev",), ("ice",)


class DutyRows:
    """What a replay column reads: one vehicle's :class:`~cevm.core.replay.VehiclePlan`,
    its duties' ``p_complete`` (NaN: not drawn), the run's ``draws`` and time zone
    ``tz``, and texts for the run's assumptions (``context``: charge_places, overnight,
    duty_rule, tz_name) and each duty's ``extrapolation``."""

    def __init__(self, plan, p_complete: np.ndarray, draws: int, tz: tzinfo, context: dict[str, str],
                 extrapolation: list[str]):
        self.plan = plan
        self.p = np.asarray(p_complete, dtype=np.float64)
        self.draws = draws
        self.tz = tz
        self.context = context
        self.extrapolation = extrapolation
        self.d = plan.duties
        self.n = plan.duties.n
        self.ev = bool(plan.vehicle.is_ev)
        self.unit = J_PER_KWH if self.ev else 1.0  # levels in J (EV) or l (ICE)

    def followed(self, size: np.ndarray) -> np.ndarray:
        """A duty's battery, tank or charger need, empty (NaN) where the candidate cannot
        follow a trip of it: no size completes it."""
        return np.where(self.plan.follows, np.asarray(size, dtype=np.float64), np.nan)

    def same(self, value: float) -> np.ndarray:
        return np.full(self.n, value, dtype=np.float64)

    def text(self, value: str) -> tuple[np.ndarray, list[str]]:
        return np.zeros(self.n, dtype=np.int64), [value]

    def texts(self, values: list[str]) -> tuple[np.ndarray, list[str]]:
        cats = list(dict.fromkeys(values))
        index = {c: i for i, c in enumerate(cats)}
        return np.array([index[v] for v in values], dtype=np.int64), cats

    def per_duty(self, values, op=np.add) -> np.ndarray:
        return op.reduceat(np.asarray(values), self.d.first) if self.n else np.zeros(0)

    def out(self, level: np.ndarray) -> np.ndarray:
        """Levels [J or l] in output units (kWh or l)."""
        return np.asarray(level, dtype=np.float64) / self.unit

    def pct(self, level: np.ndarray) -> np.ndarray:
        return 100.0 * np.asarray(level, dtype=np.float64) / self.plan.capacity

    @cached_property
    def verdict(self) -> dict[str, np.ndarray]:
        """Each duty's flags by the one verdict of :func:`cevm.core.limits.verdict`: the
        reserve kept at the mean energies, and the candidate's gross mass, power and speed
        limits on each of its trips (:mod:`cevm.core.replay.follow`: a flag is 1 if any
        trip fails it; NaN where not checked)."""
        from cevm.core import limits

        follow, first = self.plan.follow, self.d.first
        over = follow.duty_flag("over_max_gross", first)
        if self.plan.vehicle.max_gross_kg is None:
            over = np.full(self.n, np.nan)
        kept = (self.plan.levels.low >= self.plan.reserve).astype(np.float64)
        flags = {k: follow.duty_flag(k, first) for k in ("over_power", "over_speed")}
        return limits.verdict(is_ev=np.full(self.n, self.ev), over_max_gross=np.nan_to_num(over, nan=0.0),
                              energy_ok=kept, **flags) | {"over_max_gross": over}

    @cached_property
    def energy(self) -> np.ndarray:
        return self.per_duty(self.plan.energies.energy)

    def interval(self, end: int) -> np.ndarray:
        from cevm.core.replay import central_interval

        lo, hi = central_interval(self.energy, self.plan.energy_sd, self.plan.settings.interval)
        return self.out(hi if end else lo)

    @cached_property
    def ran_empty(self) -> np.ndarray:
        return self.plan.empty_trip >= 0

    def times(self, which: str) -> tuple[np.ndarray, list[str]]:
        t = self.plan.trips
        s = t.start_s[self.d.first] if which == "start" else t.end_s[self.d.last]
        from cevm.text import iso_time

        return self.texts([iso_time(x, self.tz) for x in s.tolist()])

    def days(self) -> tuple[np.ndarray, list[str]]:
        t = self.plan.trips
        return self.texts([datetime.fromtimestamp(float(x), UTC).astimezone(self.tz).date().isoformat()
                           for x in t.start_s[self.d.first]])

    def trip_id(self, index: np.ndarray) -> tuple[np.ndarray, list[str]]:
        ids = self.plan.trips.trip_ids
        return self.texts([ids[i] if i >= 0 else "" for i in np.asarray(index).tolist()])

    def mass_sources(self) -> tuple[np.ndarray, list[str]]:
        src = self.plan.trips.mass_source
        out = []
        for a, b in zip(self.d.first.tolist(), (self.d.last + 1).tolist(), strict=True):
            counts: dict[str, int] = {}
            for s in src[a:b]:
                counts[s] = counts.get(s, 0) + 1
            out.append(", ".join(f"{n} {s}" for s, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))))
        return self.texts(out)

    def ambient_from(self) -> tuple[np.ndarray, list[str]]:
        codes = self.plan.energies.ambient_from
        out = []
        for a, b in zip(self.d.first.tolist(), (self.d.last + 1).tolist(), strict=True):
            out.append(", ".join(AMBIENT_ORIGINS[c] for c in sorted(set(codes[a:b].tolist()))))
        return self.texts(out)

    def se(self) -> np.ndarray:
        from cevm.core.replay import standard_error

        return standard_error(self.p, self.draws)


def _level_pct(r: DutyRows, which: str) -> np.ndarray:
    lv = r.plan.levels
    if which == "start":
        return r.pct(lv.start)
    if which == "min":
        return np.maximum(r.pct(lv.low), 0.0)
    return np.where(r.ran_empty, np.nan, r.pct(lv.end))


def _extra(r: DutyRows) -> np.ndarray:
    return r.out(np.maximum(r.plan.reserve - r.plan.levels.low, 0.0))


def _capacity(r: DutyRows) -> np.ndarray:
    return r.same(r.plan.capacity / r.unit)


REPLAY = ColumnSpec((
    Column("vehicle_id", "the logged vehicle whose duties are replayed", kind="text",
           value=lambda r: r.text(r.plan.trips.vehicle_id)),
    Column("day", "the date the duty starts, in --tz", kind="text", value=lambda r: r.days()),
    Column("duty", "the duty's number among the vehicle's replayed duties (1, 2, ...)", decimals=0, digits=0,
           value=lambda r: np.arange(1, r.n + 1, dtype=np.float64)),
    Column("start_time", "when the duty's first trip starts (ISO 8601 to the second, in --tz: Z for UTC, else the "
           "zone's offset)", kind="text",
           value=lambda r: r.times("start")),
    Column("end_time", "when the duty's last trip ends (ISO 8601, in --tz)", kind="text",
           value=lambda r: r.times("end")),
    Column("trips", "the duty's trips", decimals=0, digits=0, value=lambda r: r.d.sizes.astype(np.float64)),
    Column("distance_km", "the duty's distance [km]", header="km", digits=1,
           value=lambda r: r.per_duty(r.plan.trips.distance_m) / 1e3),
    Column("driving_h", "time on the move, the trips' durations summed [h]", digits=2,
           value=lambda r: r.per_duty(r.plan.trips.end_s - r.plan.trips.start_s) / 3600.0),
    Column("energy_kwh", "battery energy of the duty's trips [kWh], the sum of its trips'", EV, header="kWh",
           digits=1, value=lambda r: r.out(r.energy)),
    Column("energy_kwh_low", "low end of the duty's energy at --interval [kWh]", EV, header="kWh low", digits=1,
           value=lambda r: r.interval(0)),
    Column("energy_kwh_high", "high end of the duty's energy at --interval [kWh]", EV, header="kWh high", digits=1,
           value=lambda r: r.interval(1)),
    Column("fuel_l", "fuel of the duty's trips [l], the sum of its trips'", ICE, header="fuel l", digits=1,
           value=lambda r: r.out(r.energy)),
    Column("fuel_l_low", "low end of the duty's fuel at --interval [l]", ICE, digits=1, value=lambda r: r.interval(0)),
    Column("fuel_l_high", "high end of the duty's fuel at --interval [l]", ICE, digits=1,
           value=lambda r: r.interval(1)),
    Column("soc_start_pct", "state of charge at the duty's start [%]", EV, header="SoC start %", digits=1,
           value=lambda r: _level_pct(r, "start")),
    Column("soc_min_pct", "lowest state of charge in the duty, inside its trips [%], never below 0", EV,
           header="SoC min %", digits=1, value=lambda r: _level_pct(r, "min")),
    Column("soc_end_pct", "state of charge after the duty's last trip [%] (empty when it runs empty)", EV,
           header="SoC end %", digits=1, value=lambda r: _level_pct(r, "end")),
    Column("tank_start_pct", "fuel in the tank at the duty's start [% of tank_l]", ICE, digits=1,
           value=lambda r: _level_pct(r, "start")),
    Column("tank_min_pct", "least fuel in the tank in the duty [% of tank_l], never below 0", ICE, header="tank min %",
           digits=1, value=lambda r: _level_pct(r, "min")),
    Column("tank_end_pct", "fuel in the tank after the duty's last trip [%] (empty when it runs dry)", ICE,
           header="tank end %", digits=1, value=lambda r: _level_pct(r, "end")),
    Column("charged_kwh", "energy charged into the battery in the duty's stops [kWh] (not the rest after it)", EV,
           header="charged kWh", digits=1, value=lambda r: r.out(r.plan.levels.gained)),
    Column("refuelled_l", "fuel taken in the duty's stops [l]", ICE, digits=1,
           value=lambda r: r.out(r.plan.levels.gained)),
    Column("charges", "stops of the duty that charged (EV) or refuelled (ICE)", decimals=0, digits=0,
           value=lambda r: r.plan.levels.charges.astype(np.float64)),
    Column("completes", "the duty keeps the reserve all along, at the mean energies, and the candidate can follow "
           "every trip of it (column cannot_follow)", kind="bool", header="completes",
           value=lambda r: r.plan.completes.astype(np.float64)),
    Column("cannot_follow", "the duty's first trip the candidate cannot follow and the limit, with the figures (e.g. "
           "'speed on trip T (124 km/h > 80)'; empty where it follows them all): its max_power_kw, max_speed_kmh "
           "and max_gross_kg judged on each trip's stored samples as cevm predict judges them", kind="text",
           value=lambda r: r.texts(list(r.plan.cannot_follow))),
    Column("over_max_gross", "a trip of the duty is heavier than the candidate's max_gross_kg (empty without it)",
           kind="bool", value=lambda r: r.verdict["over_max_gross"]),
    Column("over_power", "a trip of the duty asks more wheel power than the candidate's max_power_kw (over any 5 s, "
           "at the trip's mass, with the logged trace's tolerance, as cevm predict; empty without it)", kind="bool",
           value=lambda r: r.verdict["over_power"]),
    Column("over_speed", "a trip of the duty holds a speed above the candidate's max_speed_kmh (as cevm predict; "
           "empty without it)", kind="bool", value=lambda r: r.verdict["over_speed"]),
    Column("feasible", "the verdict every command gives (cevm.core.limits): the duty completes (the reserve kept at "
           "the mean energies) and the candidate can follow every trip (max_power_kw, max_speed_kmh, max_gross_kg)",
           kind="bool", value=lambda r: r.verdict["feasible"]),
    Column("p_complete", "probability that the duty keeps the reserve all along (Monte Carlo over the candidate's "
           "predictive distribution; 0 or 1 without one), 0 where the candidate cannot follow a trip of it",
           header="p", digits=3, value=lambda r: r.p),
    Column("p_complete_se", "Monte Carlo standard error of p_complete", decimals=6, value=lambda r: r.se()),
    Column("reserve_trip", "the trip in which the level first falls below the reserve (empty if kept)", kind="text",
           value=lambda r: r.trip_id(r.plan.reserve_trip)),
    Column("reserve_at_km", "where the level first falls below the reserve [km into the duty]", digits=1,
           value=lambda r: r.plan.reserve_at_m / 1e3),
    Column("empty_at_km", "where the battery or tank runs empty [km into the duty] (empty if it does not)", digits=1,
           value=lambda r: r.plan.empty_at_m / 1e3),
    Column("extra_kwh", "energy the duty lacks to keep the reserve at its lowest point [kWh] (0 if kept)", EV,
           header="lacks kWh", digits=1, value=_extra),
    Column("extra_l", "fuel the duty lacks to keep the reserve at its lowest point [l] (0 if kept)", ICE,
           header="lacks l", digits=1, value=_extra),
    Column("battery_needed_kwh", "smallest usable battery that runs the duty with the reserve kept, to "
           "1 kWh [kWh] (empty: levels carried across duties, or a trip the candidate cannot follow)", EV,
           header="needs kWh", digits=0, value=lambda r: r.out(r.followed(r.plan.battery_needed))),
    Column("tank_needed_l", "smallest tank that runs the duty with the reserve kept, to 1 l [l] (empty: a trip the "
           "candidate cannot follow)", ICE, digits=0, value=lambda r: r.followed(r.plan.battery_needed)),
    Column("battery_needed_kwh_conf", "as battery_needed_kwh with the duty's energy at its --confidence quantile "
           "(its mean plus z times its standard deviation, shared over its trips as they draw) [kWh]", EV,
           digits=0, value=lambda r: r.out(r.followed(r.plan.battery_needed_conf))),
    Column("tank_needed_l_conf", "as tank_needed_l with the duty's fuel at its --confidence quantile [l]", ICE,
           digits=0, value=lambda r: r.followed(r.plan.battery_needed_conf)),
    Column("charger_needed_kw", "smallest charger at the duty's charging stops that completes it at the candidate's "
           "battery, to 1 kW [kW] (empty: no stop may charge; inf is written empty: no charger suffices, as for a "
           "trip the candidate cannot follow)", EV,
           digits=0, value=lambda r: r.followed(np.where(np.isfinite(r.plan.charger_needed_w),
                                                         r.plan.charger_needed_w / 1e3, np.nan))),
    Column("charger_needed_kw_conf", "as charger_needed_kw with the duty's energy at its --confidence quantile [kW]",
           EV, digits=0, value=lambda r: r.followed(np.where(np.isfinite(r.plan.charger_needed_w_conf),
                                                             r.plan.charger_needed_w_conf / 1e3, np.nan))),
    Column("vehicle_key", "the candidate vehicle: its file's id key, else its stem", kind="text", header="candidate",
           value=lambda r: r.text(r.plan.vehicle.label)),
    Column("powertrain", "the candidate's powertrain: ev or ice", kind="text",
           value=lambda r: r.text(r.plan.vehicle.powertrain)),
    Column("battery_kwh", "the candidate's usable battery [kWh]", EV, value=_capacity),
    Column("tank_l", "the candidate's tank [l]", ICE, value=_capacity),
    Column("reserve_pct", "the reserve kept [% of the battery or tank]",
           value=lambda r: r.same(r.plan.settings.reserve_pct)),
    Column("charger_kw", "the charger at the duty's stops [kW] (0: none)", EV,
           value=lambda r: r.same(r.plan.settings.charging.power_w / 1e3)),
    Column("min_dwell_min", "the shortest stop that charges or refuels [min]",
           value=lambda r: r.same(r.plan.settings.charging.min_dwell_s / 60.0)),
    Column("charge_efficiency", "grid to battery [-]", EV, value=lambda r: r.same(r.plan.settings.charging.efficiency)),
    Column("charge_places", "where stops may charge or refuel: anywhere, the named places, the vehicle's depot (or "
           "none found)", kind="text", value=lambda r: r.text(r.context["charge_places"])),
    Column("overnight", "the rests between duties: full (each duty starts at --soc-start), none (levels carried) or "
           "a charger's power", kind="text", value=lambda r: r.text(r.context["overnight"])),
    Column("duty_rule", "how trips were grouped into duties", kind="text",
           value=lambda r: r.text(r.context["duty_rule"])),
    Column("lowest_at", "where the lowest level is looked for: inside the trips (--within-trips exact) or at their "
           "ends", kind="text", value=lambda r: r.text(r.context["lowest_at"])),
    Column("mass_min_kg", "the lightest trip's gross mass with the candidate [kg]", decimals=3,
           value=lambda r: r.per_duty(r.plan.energies.mass_kg, np.minimum)),
    Column("mass_max_kg", "the heaviest trip's gross mass with the candidate [kg]", decimals=3,
           value=lambda r: r.per_duty(r.plan.energies.mass_kg, np.maximum)),
    Column("mass_sources", "where the trips' masses come from, counted: manifest, by hand, logged, the candidate's "
           "file", kind="text", value=lambda r: r.mass_sources()),
    Column("ambient_min_c", "the coldest trip's ambient temperature [degC]", decimals=3,
           value=lambda r: r.per_duty(r.plan.energies.ambient_c, np.minimum)),
    Column("ambient_max_c", "the warmest trip's ambient temperature [degC]", decimals=3,
           value=lambda r: r.per_duty(r.plan.energies.ambient_c, np.maximum)),
    Column("ambient_from", "where the trips' temperatures come from", kind="text", value=lambda r: r.ambient_from()),
    Column("extrapolation", "what the duty's trips ask beyond the candidate's calibration: none, or which of "
           "temperature, mass, speed, duty (as predict)", kind="text", value=lambda r: r.texts(r.extrapolation)),
    Column("interval_from", "where the interval and the probability come from: posterior (a calibration), "
           "prior (the class's, a file never calibrated) or none", kind="text",
           value=lambda r: r.text(r.plan.spread.source)),
    Column("draws", "Monte Carlo draws of p_complete", decimals=0, value=lambda r: r.same(float(r.draws))),
    Column("missing_trips", "the vehicle's damaged stored trips left out of the replay (its duties may lack them)",
           decimals=0, value=lambda r: r.same(float(r.plan.trips.missing))),
), json_lead=("vehicle_id", "day", "duty", "trips", "distance_km", "energy_kwh", "energy_kwh_low", "energy_kwh_high",
              "fuel_l", "fuel_l_low", "fuel_l_high"))

def replay_values(ctx: DutyRows) -> dict:
    """Every column's values for one vehicle's duties, with nothing in the columns of the
    other powertrain (NaN, or an empty text)."""
    cols = REPLAY.values(ctx)
    pt = "ev" if ctx.ev else "ice"
    for c in REPLAY.columns:
        if pt not in c.powertrains:
            cols[c.name] = ctx.text("") if c.kind == "text" else np.full(ctx.n, np.nan)
    return cols


#: The replay table's status: keeps the reserve, and where not, where it fails; for
#: people only.
STATUS = Column("status", "reserve kept, and where not, where it is crossed", kind="text", header="completes",
                layout="wrap")

#: What the table never leaves out on a narrow terminal (its verdict, "status", above
#: all: the other columns are folded or left out first, :func:`cevm.cli.output.fit_columns`),
#: and what it leaves out first.
REPLAY_TABLE_KEEP = ("vehicle_id", "day", "status")
REPLAY_TABLE_DROP = ("charged_kwh", "refuelled_l", "tank_needed_l", "battery_needed_kwh", "extra_kwh", "extra_l",
                     "distance_km", "trips", "soc_min_pct", "tank_min_pct")

#: What the table shows (those without a value in any row left out), and "status".
REPLAY_TABLE = ("vehicle_id", "day", "trips", "distance_km", "energy_kwh", "fuel_l", "soc_min_pct", "tank_min_pct",
                "charged_kwh", "refuelled_l", "p_complete", "extra_kwh", "extra_l", "battery_needed_kwh",
                "tank_needed_l", "status")
