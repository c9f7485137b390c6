"""The output columns of ``cevm gtfs``: a row per block and date (:data:`BLOCKS`) and,
with ``--trips``, a row per trip and date (:data:`TRIPS`), each a
:class:`~cevm.cli.columns.Column` reading the command's row context (a dict of arrays in
output units, text columns as lists of strings).

EV rows have the battery's columns (``energy_kwh``, ``soc_*_pct``, ``charged_kwh``), ICE
rows the tank's (``fuel_l``, ``tank_*_pct``, ``refuelled_l``), as replay's. Every row says
what it assumed: how the block was formed, the driving, the elevation, the mass, the
temperature and where the interval comes from.
"""

from __future__ import annotations

import numpy as np

from cevm.cli.columns import Column, ColumnSpec

EV, ICE = ("ev",), ("ice",)


def v(name: str):
    return lambda r: r[name]


def num(name: str, meaning: str, pts=("ev", "ice"), **kw) -> Column:
    return Column(name, meaning, tuple(pts), value=v(name), **kw)


def text(name: str, meaning: str, **kw) -> Column:
    return Column(name, meaning, kind="text", value=v(name), **kw)


_ENERGY = (
    num("energy_kwh", "battery energy [kWh], the mean of the synthesised cycles' predictions", EV, header="kWh",
        digits=1),
    num("energy_kwh_low", "low end of the energy at --interval [kWh]: the model's spread and the synthesis's", EV,
        header="kWh low", digits=1),
    num("energy_kwh_high", "high end of the energy at --interval [kWh]", EV, header="kWh high", digits=1),
    num("fuel_l", "fuel [l], the mean of the synthesised cycles' predictions", ICE, header="fuel l", digits=1),
    num("fuel_l_low", "low end of the fuel at --interval [l]", ICE, digits=1),
    num("fuel_l_high", "high end of the fuel at --interval [l]", ICE, digits=1),
)

BLOCKS = ColumnSpec((
    text("block_id", "the block: the feed's block_id, or inferred:FIRST_TRIP where chained from the trips"),
    text("date", "the service date"),
    text("block_from", "feed (block_id) or inferred (chained: a trip ends where the next begins after "
         "--min-layover-min)"),
    text("start_time", "the block's first departure (pull-out included; ISO 8601 in the feed's time zone)"),
    text("end_time", "the block's last arrival (pull-in included)"),
    num("trips", "revenue trips of the block", decimals=0, digits=0),
    num("deadheads", "empty runs: between trips that end and begin apart, and pull-out / pull-in with --depot",
        decimals=0, digits=0),
    num("distance_km", "the block's distance, empty running included [km]", header="km", digits=1),
    num("deadhead_km", "empty running's distance: straight line x --deadhead-detour [km]", digits=1),
    *_ENERGY,
    num("soc_start_pct", "state of charge at the block's start [%]", EV, digits=1),
    num("soc_min_pct", "lowest state of charge at the legs' ends [%], never below 0", EV, header="SoC min %",
        digits=1),
    num("soc_end_pct", "state of charge after the block [%] (empty when it runs empty)", EV, header="SoC end %",
        digits=1),
    num("tank_min_pct", "least fuel in the tank [% of tank_l]", ICE, header="tank min %", digits=1),
    num("tank_end_pct", "fuel in the tank after the block [%]", ICE, digits=1),
    num("charged_kwh", "energy charged in the block's layovers [kWh]", EV, header="charged kWh", digits=1),
    num("refuelled_l", "fuel taken in the block's layovers [l]", ICE, digits=1),
    num("charges", "layovers that charged (EV) or refuelled (ICE)", decimals=0, digits=0),
    Column("completes", "the block keeps the reserve all along at the mean energies", kind="bool",
           value=v("completes")),
    Column("feasible", "the verdict every command gives (cevm.core.limits): the block completes within "
           "max_gross_kg; max_power_kw and max_speed_kmh are not checked here (a synthesised cycle's vector)",
           kind="bool", value=v("feasible")),
    num("p_complete", "probability that the block keeps the reserve (Monte Carlo over the model's predictive "
        "distribution and the synthesis's spread)", header="p", digits=3),
    num("p_complete_se", "Monte Carlo standard error of p_complete"),
    num("reserve_at_km", "where the level first falls below the reserve [km into the block]", digits=1),
    num("battery_needed_kwh", "smallest usable battery that runs the block with the reserve kept, to 1 kWh", EV,
        header="needs kWh", digits=0),
    num("battery_needed_kwh_conf", "as battery_needed_kwh with the block's energy at its --confidence quantile", EV,
        digits=0),
    num("tank_needed_l", "smallest tank that runs the block with the reserve kept [l]", ICE, digits=0),
    num("charger_needed_kw", "smallest charger at the layovers that completes the block at the candidate's battery "
        "[kW] (empty: no layover may charge, or none suffices)", EV, digits=0),
    num("charger_needed_kw_conf", "as charger_needed_kw with the block's energy at its --confidence quantile", EV,
        digits=0),
    text("vehicle_key", "the candidate vehicle", header="candidate"),
    text("powertrain", "ev or ice"),
    num("reserve_pct", "the reserve kept [%]"),
    num("charger_kw", "the charger at the layovers [kW] (0: none)", EV),
    num("min_dwell_min", "the shortest layover that charges or refuels [min]"),
    text("charge_places", "where layovers may charge: anywhere, the places named"),
    text("overnight", "the rests between the block's dates: full (each date starts at --soc-start) or not"),
    num("mass_kg", "the candidate's gross mass on every trip [kg]", decimals=3),
    text("mass_from", "where the mass comes from: the vehicle file's mass_kg, --mass-kg or --payload-kg"),
    num("ambient_min_c", "the coldest trip's ambient temperature [degC]", decimals=3),
    num("ambient_max_c", "the warmest trip's ambient temperature [degC]", decimals=3),
    text("ambient_from", "where the temperatures come from: --weather, --ambient-c, the vehicle's reference"),
    text("driving_from", "how the buses drive between stops: learnt from the stored trips of --vehicle-id, or the "
         "class prior"),
    text("elevation_from", "the road's elevation: the DSM along the shapes, or flat (no --dsm)"),
    text("interval_from", "where the model's spread comes from: posterior, prior or none"),
    num("deadhead_late_min", "how much later than the next departure empty running would arrive [min] (0: in "
        "time)", digits=1),
), json_lead=("block_id", "date", "trips", "distance_km", "energy_kwh", "energy_kwh_low", "energy_kwh_high",
              "fuel_l", "fuel_l_low", "fuel_l_high"))

BLOCKS_TABLE = ("block_id", "date", "block_from", "trips", "distance_km", "energy_kwh", "energy_kwh_low",
                "energy_kwh_high", "fuel_l", "fuel_l_low", "fuel_l_high", "soc_min_pct", "tank_min_pct",
                "charged_kwh", "p_complete", "completes")

TRIPS = ColumnSpec((
    text("trip_id", "the trip (TRIPID@HH:MM:SS: a departure of a frequency-based trip)"),
    text("route_id", "its route"),
    text("block_id", "its block (as in the block rows)"),
    text("date", "the service date"),
    text("start_time", "its first departure (ISO 8601 in the feed's time zone)"),
    num("distance_km", "from its first stop to its last along the shape [km]", header="km", digits=2),
    num("duration_s", "from its first departure to its last arrival [s]", decimals=0, digits=0),
    num("stops", "its stops (timed and untimed)", decimals=0, digits=0),
    num("ascent_m", "the sum of the rises of its road [m] (0: flat)", digits=0),
    *_ENERGY,
    num("mass_kg", "the candidate's gross mass [kg]", decimals=3),
    num("ambient_c", "the ambient temperature at the trip's midpoint [degC]", decimals=3),
    text("ambient_from", "where the temperature comes from"),
    text("cycle_from", "how its drive cycle was made: synthesised from its stop times, the driving's source, the "
         "draws"),
    text("stops_from", "how its stops were placed: shape_dist_traveled (its unit), projected onto the shape, or "
         "straight lines between stops (no shape)"),
    text("elevation_from", "the road's elevation: the DSM along the shape, or flat"),
), json_lead=("trip_id", "route_id", "block_id", "date", "distance_km", "duration_s", "stops", "ascent_m",
              "energy_kwh", "energy_kwh_low", "energy_kwh_high", "fuel_l", "fuel_l_low", "fuel_l_high", "cycle_from"))

TRIPS_TABLE = ("trip_id", "route_id", "block_id", "date", "distance_km", "duration_s", "stops", "ascent_m",
               "energy_kwh", "energy_kwh_low", "energy_kwh_high", "fuel_l", "fuel_l_low", "fuel_l_high")


def columns_of(spec: ColumnSpec, rows: dict, n: int, ev: bool) -> dict:
    """The spec's columns from ``rows`` (arrays, or lists of str for text), the other
    powertrain's empty, text as (codes, categories)."""
    pt = "ev" if ev else "ice"
    out: dict = {}
    for c in spec.columns:
        if pt not in c.powertrains or c.name not in rows:
            out[c.name] = (np.zeros(n, np.int64), [""]) if c.kind == "text" else np.full(n, np.nan)
            continue
        x = rows[c.name]
        if c.kind == "text":
            vals = [str(s) for s in (x if isinstance(x, list | tuple | np.ndarray) else [x] * n)]
            cats = list(dict.fromkeys(vals))
            index = {s: i for i, s in enumerate(cats)}
            out[c.name] = (np.array([index[s] for s in vals], dtype=np.int64), cats)
        else:
            out[c.name] = np.broadcast_to(np.asarray(x, dtype=np.float64), (n,)).copy()
    return out
