"""Loads that follow the weather: a cabin's heating and air conditioning, a diesel's cold
start (pure). These make the sample logs' "measured" consumption depend on temperature
the way real vehicles' does, by physics the CE model does not share.

**Cabin** (:class:`Cabin`, per second of a trip). Heat balance of the cabin air and
interior, held between a heating and a cooling setpoint::

    loss coefficient  L = UA + ventilation (+ doors while stopped, a bus) [W/K]
    gains             G = internal + occupants x sensible heat + aperture x sunshine [W]
    heating demand    q_h = max(0, L (T_heat - T) - G)
    cooling demand    q_c = G + L (T - T_cool)                     when T >= T_cool
                      q_c = max(0, G - (L + economiser) (T_cool - T))  when cooler outside
                      (fresh air cools for free first)

Heating by a heat pump whose capacity and COP fall with the cold (COP a share of the
Carnot value between the evaporator, some kelvin below the air, and the condenser; cut
out below :attr:`Cabin.heat_pump_min_c`), the rest by a resistive heater (COP 1), or, in
a truck, by the engine's coolant (no fuel, but it slows the engine's warm-up). Air
conditioning with an EER that falls as the air (and the condenser) gets hotter. A
ventilation blower runs whenever the ignition is on; the HVAC unit's fans in proportion
to its load. So the electric power is convex in the cold (the COP falls, the resistive
heater takes over), not the CE model's straight hinge.

**Start of a trip**: during the layover the ignition was off; the cabin relaxed towards
its parked equilibrium (the air temperature, plus the sun through the glass) with time
constant capacity / parked UA. At ignition on, the HVAC runs at full capacity until the
deficit capacity x (setpoint - cabin) is made up: the warm-up (or, in summer, pull-down)
energy, which grows with the cold and with the layover's length. At the end of the
previous trip the cabin was at the temperature the HVAC then held (the band's clamp of
its free-floating temperature, taken at this trip's start conditions). The cabin's heat
capacity is otherwise neglected (a quasi-steady cabin inside the band).

**Diesel cold start** (:class:`EngineWarmup`): engine friction rises as the oil and the
liners get colder (about 1.8 x the hot friction at 20 degC, 2.1 x at -5 degC: heavy-duty
motoring measurements span 1.5-2.5 x). The engine cools while parked with a time
constant of hours towards the air temperature; driving, a share of the fuel power heats
it (the thermostat keeps the radiator out of the circuit until it is hot), less what the
cab heater takes from the coolant. The friction scale per second drives the detailed
model's friction (:func:`cevm.core.detailed.simulate`, ``friction_scale``).

Parameter values are plausible for a 10 m electric city bus and a tractor unit's sleeper
cab, with sources or reasoning beside each; they are not measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.units import S_PER_H

#: Kelvin at 0 degC.
K0 = 273.15


@dataclass(frozen=True)
class Cabin:
    """A cabin's heat balance and its heating, ventilation and air conditioning (SI).

    ``heat_source`` is ``"heat_pump"`` (heat pump, then resistive backup, from the
    battery) or ``"engine"`` (the coolant: no energy of its own, up to
    ``resistive_w`` as the heater core's capacity). ``compressor`` is ``"electric"``
    (from the battery) or ``"belt"`` (mechanical, at the engine).
    """

    ua_w_per_k: float
    vent_w_per_k: float
    door_w_per_k: float
    economiser_w_per_k: float
    capacity_j_per_k: float
    parked_ua_w_per_k: float
    solar_aperture_m2: float
    occupant_w: float
    internal_w: float
    heat_set_c: float
    cool_set_c: float
    heat_source: str
    heat_pump_w: float
    heat_pump_per_k: float
    heat_pump_min_c: float
    heat_pump_carnot: float
    condenser_c: float
    evaporator_drop_k: float
    resistive_w: float
    compressor: str
    ac_w: float
    ac_carnot: float
    ac_evaporator_c: float
    ac_condenser_rise_k: float
    blower_w: float
    fans_w: float

    def heating_cop(self, ambient_c) -> np.ndarray:
        """Heat pump COP at air temperature ``ambient_c`` [-]: a share of the Carnot COP
        between the evaporator (``evaporator_drop_k`` below the air) and the condenser."""
        t_evap = np.asarray(ambient_c, dtype=np.float64) - self.evaporator_drop_k
        carnot = (self.condenser_c + K0) / np.maximum(self.condenser_c - t_evap, 5.0)
        return np.clip(self.heat_pump_carnot * carnot, 1.0, 6.0)

    def heat_pump_capacity_w(self, ambient_c) -> np.ndarray:
        """Heat pump heating capacity at ``ambient_c`` [W] (0 below the cut-out)."""
        t = np.asarray(ambient_c, dtype=np.float64)
        cap = self.heat_pump_w * np.maximum(0.0, 1.0 + self.heat_pump_per_k * (t - 7.0))
        return np.where((t >= self.heat_pump_min_c) & (self.heat_source == "heat_pump"), cap, 0.0)

    def cooling_eer(self, ambient_c) -> np.ndarray:
        """Air conditioning EER (cooling over compressor power) at ``ambient_c`` [-]."""
        t_cond = np.asarray(ambient_c, dtype=np.float64) + self.ac_condenser_rise_k
        carnot = (self.ac_evaporator_c + K0) / np.maximum(t_cond - self.ac_evaporator_c, 5.0)
        return np.clip(self.ac_carnot * carnot, 1.0, 8.0)


#: A 10 m single-deck electric city bus (Optare Metrocity EV class).
BUS_CABIN = Cabin(
    ua_w_per_k=350.0,          # about 95 m^2 of body and glazing at 3.7 W/m^2K (single glazing)
    vent_w_per_k=200.0,        # 0.17 m^3/s of fresh air (about 10 air changes an hour)
    door_w_per_k=600.0,        # doors open at stops: air exchange of about 0.5 m^3/s
    economiser_w_per_k=1200.0,  # fresh-air damper fully open for free cooling
    capacity_j_per_k=300e3,    # 85 kJ/K of air plus what warms with it within minutes (seats, panels)
    parked_ua_w_per_k=320.0,   # doors shut, blower off: 16 min time constant
    solar_aperture_m2=4.0,     # about 24 m^2 of glazing x 0.6 transmittance x 0.3 incidence
    occupant_w=80.0,           # sensible heat of a seated or standing adult
    internal_w=600.0,          # saloon lighting, displays, ticketing, fan motors
    heat_set_c=18.0,
    cool_set_c=24.0,
    heat_source="heat_pump",
    heat_pump_w=18e3,          # at 7 degC; R134a/R744 bus heat pumps: 15-25 kW
    heat_pump_per_k=0.03,      # capacity falls 3 %/K with the cold
    heat_pump_min_c=-12.0,     # cut-out: below, the resistive heater alone
    heat_pump_carnot=0.40,     # COP 2.8 at 7 degC, 2.2 at -5 degC
    condenser_c=45.0,
    evaporator_drop_k=8.0,
    resistive_w=20e3,          # PTC / resistive backup heaters
    compressor="electric",
    ac_w=20e3,                 # roof-top unit of a 10 m bus: 18-24 kW cooling
    ac_carnot=0.35,            # EER 2.9 at 24 degC, 2.4 at 30 degC
    ac_evaporator_c=5.0,
    ac_condenser_rise_k=15.0,
    blower_w=400.0,            # ventilation blower, always on with the ignition
    fans_w=900.0,              # evaporator and condenser fans at full load
)

#: The sleeper cab of a tractor unit (Scania P320 class): heated by the engine's coolant,
#: cooled by a belt-driven compressor.
TRUCK_CAB = Cabin(
    ua_w_per_k=55.0,           # about 22 m^2 of cab at 2.5 W/m^2K
    vent_w_per_k=35.0,         # 0.03 m^3/s of fresh air
    door_w_per_k=0.0,          # the door stays shut at stops
    economiser_w_per_k=150.0,
    capacity_j_per_k=60e3,     # 12 m^3 of air, seats, bunk, dashboard
    parked_ua_w_per_k=50.0,    # 20 min time constant
    solar_aperture_m2=1.0,     # a large, steep windscreen and side windows
    occupant_w=80.0,
    internal_w=150.0,
    heat_set_c=20.0,
    cool_set_c=22.0,
    heat_source="engine",
    heat_pump_w=0.0,
    heat_pump_per_k=0.0,
    heat_pump_min_c=0.0,
    heat_pump_carnot=0.0,
    condenser_c=45.0,
    evaporator_drop_k=8.0,
    resistive_w=8e3,           # heater core capacity from a warm engine
    compressor="belt",
    ac_w=5e3,                  # truck cab A/C: 4-6 kW cooling
    ac_carnot=0.30,            # belt-driven, fixed displacement, cycling: EER 2.1 at 25 degC
    ac_evaporator_c=3.0,
    ac_condenser_rise_k=18.0,
    blower_w=150.0,
    fans_w=350.0,              # condenser fan and blower at full load
)


@dataclass(frozen=True, eq=False)
class CabinLoad:
    """What the cabin asks of the vehicle over a trip, per sample.

    ``electric_w``: blower, fans, and (heat pump / resistive heater, electric compressor)
    from the vehicle's electric system; ``compressor_w``: a belt-driven compressor's
    mechanical power at the engine; ``heating_w`` / ``cooling_w``: heat delivered to or
    taken from the cabin [W]; ``warmup_*``: the same quantities' excess during the start
    transient (recovering the layover's deficit); ``start_c``: cabin temperature at
    ignition on [degC].
    """

    electric_w: np.ndarray
    compressor_w: np.ndarray
    heating_w: np.ndarray
    cooling_w: np.ndarray
    warmup_electric_w: np.ndarray
    warmup_compressor_w: np.ndarray
    start_c: float


def _recovery(steady: np.ndarray, capacity: np.ndarray, deficit_j: float, dt: np.ndarray) -> np.ndarray:
    """Extra power [W] per sample that makes up ``deficit_j`` as fast as the capacity above
    the steady demand allows (the rest of the trip if it cannot)."""
    extra = np.zeros(steady.size)
    if deficit_j <= 0.0 or steady.size == 0:
        return extra
    room = np.maximum(capacity - steady, 0.0)
    done = np.concatenate(([0.0], np.cumsum(room[:-1] * dt[:-1])))  # energy made up before sample i
    full = done + room * dt <= deficit_j
    extra[full] = room[full]
    k = int(np.argmin(full)) if not full.all() else steady.size
    if k < steady.size and done[k] < deficit_j:
        extra[k] = (deficit_j - done[k]) / dt[k]
    return extra


def cabin_load(cabin: Cabin, time_s, speed_mps, ambient_c, solar_w_m2, *, occupants: float,
               soak_s: float) -> CabinLoad:
    """The HVAC load of ``cabin`` over one trip (1 Hz or any strictly increasing time).

    ``ambient_c`` and ``solar_w_m2`` per sample; doors are open (``door_w_per_k``)
    while the vehicle stands; ``occupants`` people on board; ``soak_s`` the time parked
    with the ignition off before the trip (see the module docstring).
    """
    c = cabin
    t = np.asarray(time_s, dtype=np.float64)
    ta = np.asarray(ambient_c, dtype=np.float64)
    sun = np.asarray(solar_w_m2, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    dt = np.diff(t, append=t[-1] + 1.0) if t.size > 1 else np.ones(t.size)
    loss = c.ua_w_per_k + c.vent_w_per_k + c.door_w_per_k * (v < 0.1)
    gains = c.internal_w + occupants * c.occupant_w + c.solar_aperture_m2 * sun
    q_h = np.maximum(0.0, loss * (c.heat_set_c - ta) - gains)
    q_c = np.where(ta >= c.cool_set_c, gains + loss * (ta - c.cool_set_c),
                   np.maximum(0.0, gains - (loss + c.economiser_w_per_k) * (c.cool_set_c - ta)))
    hp_cap = c.heat_pump_capacity_w(ta)
    heat_cap = hp_cap + c.resistive_w
    # Start: the cabin relaxed towards its parked equilibrium during the layover.
    parked_eq = ta[0] + c.solar_aperture_m2 * sun[0] / c.parked_ua_w_per_k
    held = float(np.clip(ta[0] + gains[0] / loss[0], c.heat_set_c, c.cool_set_c))
    tau = c.capacity_j_per_k / c.parked_ua_w_per_k
    start = parked_eq + (held - parked_eq) * float(np.exp(-max(soak_s, 0.0) / tau))
    rec_h = _recovery(q_h, heat_cap, c.capacity_j_per_k * (c.heat_set_c - start), dt)
    rec_c = _recovery(q_c, np.full(ta.size, c.ac_w), c.capacity_j_per_k * (start - c.cool_set_c), dt)

    def power(heat, cool):
        heat = np.minimum(heat, heat_cap)
        cool = np.minimum(cool, c.ac_w)
        if c.heat_source == "heat_pump":
            from_hp = np.minimum(heat, hp_cap)
            heating_el = from_hp / c.heating_cop(ta) + (heat - from_hp)
        else:
            heating_el = np.zeros(ta.size)
        comp = cool / c.cooling_eer(ta)
        load = np.maximum(heat / heat_cap, cool / c.ac_w)
        fans = np.where(load > 0.0, c.fans_w * np.minimum(1.0, 0.3 + 0.7 * load), 0.0)
        electric = c.blower_w + fans + heating_el + (comp if c.compressor == "electric" else 0.0)
        mech = comp if c.compressor == "belt" else np.zeros(ta.size)
        return heat, cool, electric, mech

    heat, cool, electric, mech = power(q_h + rec_h, q_c + rec_c)
    _, _, electric0, mech0 = power(q_h, q_c)
    return CabinLoad(electric_w=electric, compressor_w=mech, heating_w=heat, cooling_w=cool,
                     warmup_electric_w=electric - electric0, warmup_compressor_w=mech - mech0, start_c=float(start))


@dataclass(frozen=True)
class EngineWarmup:
    """A diesel engine's warm-up and the friction it costs while cold (SI).

    Defaults for a 9.3 l heavy-duty engine: ``capacity_j_per_k`` = 650 kJ/K, its metal
    (about 900 kg), 35 l of coolant and 30 l of oil, which warm together while the
    thermostat is closed; ``heat_share`` = 0.30 of the fuel power into coolant and oil
    at part load; ``hot_c`` = 88 degC (thermostat); ``soak_tau_s`` = 3 h, cooling parked
    (from 88 to about 50 degC in 2 h at 15 degC; 650 kJ/K over about 60 W/K);
    ``friction_per_k`` = 0.012: friction 1 + 0.012 (hot - T) times the hot engine's.
    With these the engine is hot after about 15 minutes of regional driving from a cold
    start, half an hour in town.
    """

    capacity_j_per_k: float = 650e3
    heat_share: float = 0.30
    hot_c: float = 88.0
    soak_tau_s: float = 3.0 * S_PER_H
    friction_per_k: float = 0.012

    def start_c(self, ambient_c: float, soak_s: float) -> float:
        """Engine temperature at ignition on after ``soak_s`` parked, hot before [degC]."""
        return float(ambient_c + (self.hot_c - ambient_c) * np.exp(-max(soak_s, 0.0) / self.soak_tau_s))

    def temperature_c(self, time_s, fuel_power_w, start_c: float, cab_heat_w=0.0) -> np.ndarray:
        """Engine temperature per sample [degC] from ``start_c``: the heat share of the
        fuel power per step (``fuel_power_w``, N-1 steps), less the cab heater's draw
        (per sample, taken only while it leaves heat to spare), up to ``hot_c``."""
        t = np.asarray(time_s, dtype=np.float64)
        dt = np.diff(t)
        cab = np.broadcast_to(np.asarray(cab_heat_w, dtype=np.float64), t.shape)
        cab_step = 0.5 * (cab[:-1] + cab[1:])
        heat = np.maximum(self.heat_share * np.asarray(fuel_power_w, dtype=np.float64) - cab_step, 0.0) * dt
        temp = start_c + np.concatenate(([0.0], np.cumsum(heat))) / self.capacity_j_per_k
        return np.minimum(temp, max(self.hot_c, start_c))

    def friction_scale(self, engine_c) -> np.ndarray:
        """Engine friction over the hot engine's at temperature ``engine_c`` [-]."""
        return 1.0 + self.friction_per_k * np.maximum(self.hot_c - np.asarray(engine_c, dtype=np.float64), 0.0)


DIESEL_WARMUP = EngineWarmup()
