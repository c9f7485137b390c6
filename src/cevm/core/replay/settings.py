"""What a replay assumes, as frozen dataclasses with their defaults and why (pure):
how the candidate charges (:class:`Charging`) and how duties are run
(:class:`ReplaySettings`)."""

from __future__ import annotations

from dataclasses import dataclass

from cevm.core.replay.duties import DEFAULT_DUTY_GAP_H, DUTY_RULES
from cevm.core.replay.montecarlo import DEFAULT_DRAWS, DEFAULT_SEED
from cevm.core.replay.places import DEFAULT_PLACE_RADIUS_M, Place
from cevm.core.replay.sizing import BATTERY_STEP_KWH, CHARGER_STEP_KW
from cevm.core.sweep import DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT

#: Default charging efficiency, grid to battery [-]. A DC charger converts at about
#: 94-96 %, and the battery's own charging losses and its thermal management during the
#: charge take a few percent more; measured grid-to-battery figures of electric vehicles
#: are 85-93 % (EPA certification data of the Tesla Model Y: 88 % on 240 V AC; commercial
#: charging reports 85-93 %). 0.90 is the middle of that range.
DEFAULT_CHARGE_EFFICIENCY = 0.90

#: Default shortest stop that charges [min]: plugging in and out takes minutes, and a
#: driver's statutory break is 45 min (Regulation (EC) 561/2006); 30 min keeps the stops
#: where a driver could plug in and leaves out a quick drop.
DEFAULT_MIN_DWELL_MIN = 30.0

#: How the rests between duties charge (``overnight``): "full" (every duty starts at the
#: start level: a depot charge overnight; the default, since a depot-based fleet charges
#: at night and a battery sized for the day is what is asked), "none" (the level carries
#: from duty to duty), "power" (a charger of ``overnight_w`` for the whole rest, the level
#: carried).
OVERNIGHT_MODES = ("full", "none", "power")

#: Default interval of the duties' energy [-] (predict's default: a 90 % range).
DEFAULT_INTERVAL = 0.9
#: Default confidence at which a duty counts as completed in the fleet's summary: 0.95,
#: the upper end of the default 90 % interval (a duty whose energy at its interval's
#: high end keeps the reserve completes with at least this probability, charging aside).
DEFAULT_CONFIDENCE = 0.95
#: Default share of duties a sized battery or charger must complete.
DEFAULT_TARGET_SHARE = 0.95


@dataclass(frozen=True)
class Charging:
    """How the candidate gains energy (EV) or fuel (ICE) between trips.

    ``power_w`` the charger at the stops inside a duty [W] (0: none; an ICE refuels to
    full instead, where it may); ``min_dwell_s`` the shortest stop that charges or
    refuels [s]; ``efficiency`` grid to battery [-]; ``places`` where it may charge or
    refuel (empty: anywhere for a charger, nowhere for an ICE) and ``depot`` whether the
    vehicle's depot is one (found from its rests, :func:`cevm.core.replay.places.find_depot`,
    within ``depot_radius_m``); ``overnight`` one of :data:`OVERNIGHT_MODES` with
    ``overnight_w`` [W] for "power"."""

    power_w: float = 0.0
    min_dwell_s: float = DEFAULT_MIN_DWELL_MIN * 60.0
    efficiency: float = DEFAULT_CHARGE_EFFICIENCY
    places: tuple[Place, ...] = ()
    depot: bool = False
    depot_radius_m: float = DEFAULT_PLACE_RADIUS_M
    overnight: str = "full"
    overnight_w: float = 0.0

    def __post_init__(self) -> None:
        if not self.power_w >= 0:
            raise ValueError(f"charger power {self.power_w!r} W must be >= 0")
        if not self.min_dwell_s >= 0:
            raise ValueError(f"shortest charging stop {self.min_dwell_s!r} s must be >= 0")
        if not 0 < self.efficiency <= 1:
            raise ValueError(f"charging efficiency {self.efficiency!r} must be in (0, 1]")
        if self.overnight not in OVERNIGHT_MODES:
            raise ValueError(f"overnight must be one of {OVERNIGHT_MODES}, not {self.overnight!r}")
        if self.overnight == "power" and not self.overnight_w > 0:
            raise ValueError("an overnight charger needs a power > 0 W")

    @property
    def anywhere(self) -> bool:
        """Whether every stop long enough may charge (no place named, no depot)."""
        return not self.places and not self.depot

    @property
    def chained(self) -> bool:
        """Whether the level carries from duty to duty."""
        return self.overnight != "full"


@dataclass(frozen=True)
class ReplaySettings:
    """How the duties are formed and run: ``rule`` and ``gap_s`` (:mod:`cevm.core.replay.duties`),
    ``soc_start_pct`` and ``reserve_pct`` (of the battery or tank), ``charging``,
    ``interval`` of the energies, ``draws`` and ``seed`` of the Monte Carlo,
    ``battery_step`` [J or l] and ``charger_step_w`` of the sizing (0: no sizing),
    ``ice_braking`` (None: the file's), and ``logged_kerb_kg``: the logged vehicles' own
    kerb mass (None: each trip's gross mass is the candidate's; else the candidate
    carries the trip's payload, gross less this, on its own kerb mass); ``within_trips``:
    look for the lowest level inside the trips where it could decide something (their step
    tables read), else at the trips' ends only (no step table read: a crossing is placed
    in its trip in proportion to the energy); ``size_confidence``: the battery and charger
    are sized twice, at the mean energies and with each duty's energy at this one-sided
    quantile (:func:`cevm.core.replay.spread.energy_at_confidence`; None: at the mean only)."""

    rule: str = "gap"
    gap_s: float = DEFAULT_DUTY_GAP_H * 3600.0
    soc_start_pct: float = DEFAULT_SOC_START_PCT
    reserve_pct: float = DEFAULT_RESERVE_PCT
    charging: Charging = Charging()
    interval: float = DEFAULT_INTERVAL
    draws: int = DEFAULT_DRAWS
    seed: int = DEFAULT_SEED
    battery_step: float = BATTERY_STEP_KWH * 3.6e6
    charger_step_w: float = CHARGER_STEP_KW * 1e3
    ice_braking: str | None = None
    logged_kerb_kg: float | None = None
    within_trips: bool = True
    size_confidence: float | None = DEFAULT_CONFIDENCE

    def __post_init__(self) -> None:
        if self.rule not in DUTY_RULES:
            raise ValueError(f"duty rule must be one of {DUTY_RULES}, not {self.rule!r}")
        if not 0 < self.interval < 1:
            raise ValueError(f"interval {self.interval!r} must be in (0, 1)")
        if self.size_confidence is not None and not 0 < self.size_confidence < 1:
            raise ValueError(f"size_confidence {self.size_confidence!r} must be in (0, 1)")
        if self.draws < 1:
            raise ValueError(f"draws must be >= 1, got {self.draws!r}")
        if not 0 <= self.reserve_pct < 100 or not 0 < self.soc_start_pct <= 100:
            raise ValueError("--soc-start must be in (0, 100] and --reserve-pct in [0, 100)")
