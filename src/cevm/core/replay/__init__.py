"""The fleet's logged working days run again with another vehicle, charging included
(pure): ``cevm replay``.

A vehicle's stored trips are grouped into *duties* (:mod:`~cevm.core.replay.duties`),
each run trip by trip in time order with the candidate vehicle: every trip at its own
mass and temperature (:mod:`~cevm.core.replay.trip_energies`, the CE model on the trip's cached
vector), the battery's level (or the tank's) carried from trip to trip and charged in the
stops long enough, at the places allowed (:mod:`~cevm.core.replay.places`,
:mod:`~cevm.core.replay.chain`). Each duty gets its lowest level, where it first crosses
its reserve, what it lacks, the battery and the charger it would need
(:mod:`~cevm.core.replay.sizing`), and its probability of completing with the reserve
kept, by Monte Carlo over the candidate's predictive distribution
(:mod:`~cevm.core.replay.spread`, :mod:`~cevm.core.replay.montecarlo`).

:func:`plan_vehicle` (:mod:`~cevm.core.replay.plan`) does one vehicle, reading the step
tables of the few trips that need one through a callable; :func:`p_complete` is the
Monte Carlo (a task for a worker); :mod:`~cevm.core.replay.fleet` sums the duties up.
Inputs are arrays and frozen dataclasses (:class:`ReplaySettings`, :class:`Charging`,
:class:`LoggedTrips`); SI units inside (J, l, s, m, kg, W).
"""

from cevm.core.replay.chain import ChainRun, DutyLevels, Lanes, Stops, duty_levels, duty_minima, run_chains, stop_gain
from cevm.core.replay.duties import DEFAULT_DUTY_GAP_H, DUTY_RULES, Duties, group_duties, stop_dwell_s
from cevm.core.replay.montecarlo import DEFAULT_DRAWS, DEFAULT_SEED, DrawPlan, p_complete, standard_error
from cevm.core.replay.places import DEFAULT_PLACE_RADIUS_M, Depot, Place, distance_m, find_depot, stops_at
from cevm.core.replay.plan import LoggedTrips, VehiclePlan, candidate_masses, capacity_of, plan_vehicle
from cevm.core.replay.settings import (
    DEFAULT_CHARGE_EFFICIENCY,
    DEFAULT_CONFIDENCE,
    DEFAULT_INTERVAL,
    DEFAULT_MIN_DWELL_MIN,
    DEFAULT_TARGET_SHARE,
    OVERNIGHT_MODES,
    Charging,
    ReplaySettings,
)
from cevm.core.replay.sizing import (
    BATTERY_STEP_KWH,
    CHARGER_STEP_KW,
    battery_needed,
    charger_needed,
    size_for_share,
    smallest_passing,
)
from cevm.core.replay.spread import TripSpread, central_interval, trip_spread
from cevm.core.replay.trip_energies import TripEnergies, trip_crossing, trip_energies, trips_excess

__all__ = [
    "BATTERY_STEP_KWH", "CHARGER_STEP_KW", "DEFAULT_CHARGE_EFFICIENCY", "DEFAULT_CONFIDENCE", "DEFAULT_DRAWS",
    "DEFAULT_DUTY_GAP_H", "DEFAULT_INTERVAL", "DEFAULT_MIN_DWELL_MIN", "DEFAULT_PLACE_RADIUS_M", "DEFAULT_SEED",
    "DEFAULT_TARGET_SHARE", "DUTY_RULES", "OVERNIGHT_MODES", "ChainRun", "Charging", "Depot", "DrawPlan", "Duties",
    "DutyLevels", "Lanes", "LoggedTrips", "Place", "ReplaySettings", "Stops", "TripEnergies", "TripSpread",
    "VehiclePlan", "battery_needed", "candidate_masses", "capacity_of", "central_interval", "charger_needed",
    "distance_m", "duty_levels", "duty_minima", "find_depot", "group_duties", "p_complete", "plan_vehicle",
    "run_chains",
    "size_for_share", "smallest_passing", "standard_error", "stop_dwell_s", "stop_gain", "stops_at",
    "trip_crossing", "trip_energies", "trip_spread", "trips_excess",
]
