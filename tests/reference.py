"""An independent, deliberately plain per-step implementation of the paper's model.

One Python loop over steps, the equations as printed (with PAPER-NOTES' discretisation),
no numpy tricks: the yardstick the fast code is tested against.
"""

RHO = 1.225
G = 9.81


def step_terms(t, v, h, i):
    """Step i's terms as the paper prints them: (dt [s], k [J/kg], a [J/m^2], r [J/kg
    per unit Cr], e [J/kg]); ``h`` None is a flat road."""
    dt = t[i + 1] - t[i]
    k = 0.5 * (v[i + 1] ** 2 - v[i] ** 2)
    a = 0.25 * RHO * (v[i] ** 3 + v[i + 1] ** 3) * dt
    r = 0.5 * G * (v[i] + v[i + 1]) * dt
    e = G * (h[i + 1] - h[i]) if h is not None else 0.0
    return dt, k, a, r, e


def reference_wheel_energy_j(t, v, h, m, cda, cr, mode, eta=1.0, cr0=0.004):
    """E_DC [J] summed step by step. mode: 'paper' (eq. 24), 'no-credit', or 'ev' (eq. 27-29)."""
    total = 0.0
    for i in range(len(t) - 1):
        dt, k, a, r, e = step_terms(t, v, h, i)
        delta = m * (k + e) + cda * a + cr * m * r
        if k + e + cr0 * r > 0 or mode == "paper":  # simplified step (criterion 8)
            total += delta
        elif mode == "no-credit":
            if delta > 0:
                total += delta
        elif mode == "ev":
            if delta > 0:
                total += delta
            else:
                total += eta * eta * delta
        else:
            raise ValueError(mode)
    return total


def reference_consumption(t, v, h, m, veh, ambient_c, cr0=0.004):
    """Battery energy [J] (EV) or fuel [l] (ICE) of one trip, step by step, with every
    term of cevm.core.energy written out from its equation (not from cevm's code).

    ``veh`` is a mapping with the vehicle's fields (SI): eta, cda_m2, cr, powertrain, and
    for an EV regen_eta (None: eta), aux_power_w, aux_heating_w_per_k,
    aux_cooling_w_per_k, warmup_j_per_k; for an ICE fuel_lhv_j_per_l, ice_braking,
    kinetic_eta (None: eta), running_fuel_lps, idle_fuel_lps, heating_fuel_lps_per_k,
    cooling_fuel_lps_per_k, warmup_fuel_l_per_k; both heating_below_c, cooling_above_c.

    EV per step: Delta / eta if Delta > 0 or the step is simplified, else regen_eta Delta;
    plus P_aux(T) dt; once at the start warmup h(T). ICE per step: Delta / (U eta)
    counted as eq. (24) ("paper") or only when positive ("no-credit"), plus
    max(k, 0) m (1/eta_k - 1/eta) / U, running fuel x dt on simplified steps, idle fuel x
    dt at standstill (v = 0 at both ends), the temperature rate x dt; once the cold start.
    """
    heat = max(0.0, veh["heating_below_c"] - ambient_c)
    cool = max(0.0, ambient_c - veh["cooling_above_c"])
    eta = veh["eta"]
    ev = veh["powertrain"] == "ev"
    if ev:
        regen = eta if veh["regen_eta"] is None else veh["regen_eta"]
        p_aux = veh["aux_power_w"] + veh["aux_heating_w_per_k"] * heat + veh["aux_cooling_w_per_k"] * cool
        total = veh["warmup_j_per_k"] * heat
    else:
        lhv = veh["fuel_lhv_j_per_l"]
        eta_k = eta if veh["kinetic_eta"] is None else veh["kinetic_eta"]
        rate_t = veh["heating_fuel_lps_per_k"] * heat + veh["cooling_fuel_lps_per_k"] * cool
        total = veh["warmup_fuel_l_per_k"] * heat
    for i in range(len(t) - 1):
        dt, k, a, r, e = step_terms(t, v, h, i)
        delta = m * (k + e) + veh["cda_m2"] * a + veh["cr"] * m * r
        simplified = k + e + cr0 * r > 0
        if ev:
            if simplified or delta > 0:
                total += delta / eta
            else:
                total += regen * delta
            total += p_aux * dt
        else:
            if simplified or delta > 0 or veh["ice_braking"] == "paper":
                total += delta / (lhv * eta)
            total += max(k, 0.0) * m * (1.0 / eta_k - 1.0 / eta) / lhv
            if simplified:
                total += veh["running_fuel_lps"] * dt
            if v[i] == 0 and v[i + 1] == 0:
                total += veh["idle_fuel_lps"] * dt
            total += rate_t * dt
    return total


def reference_step_energy(t, v, h, i, m, cda, cr, *, eta, w, lhv=None, aux=0.0, ck=0.0, run=0.0, idle=0.0,
                          cr0=0.004):
    """The energy of step i, plainly: an EV's battery energy [J] (``lhv`` None) or an
    ICE's fuel [l]. ``w`` weights a negative non-simplified step (eta * regen_eta for an
    EV, 1 or 0 for an ICE by braking mode); ``aux`` [W for an EV, l/s for an ICE] all
    the time, ``ck`` [l per J/kg] the fuel per unit of positive kinetic energy
    (m (1/eta_k - 1/eta) / U), ``run`` [l/s] on simplified steps, ``idle`` [l/s] at
    standstill."""
    dt, k, a, r, e = step_terms(t, v, h, i)
    delta = m * (k + e) + cda * a + cr * m * r
    simplified = k + e + cr0 * r > 0
    wheel = delta if (simplified or delta > 0) else w * delta
    if lhv is None:
        return wheel / eta + aux * dt, dt, r / G
    fuel = wheel / (lhv * eta) + ck * max(k, 0.0) + aux * dt
    if simplified:
        fuel += run * dt
    if a <= 0:
        fuel += idle * dt
    return fuel, dt, r / G


def reference_crossing(legs, level, *, lump=0.0, repeat=False, max_passes=100000, **step):
    """(time [s], distance [m]) at which the running energy (``lump`` before the first
    step, then :func:`reference_step_energy` of every step of every leg, in order,
    again and again with ``repeat``) first reaches ``level``, linearly inside the step;
    None if never. ``legs``: a list of (t, v, h)."""
    energy, time, dist = lump, 0.0, 0.0
    if energy >= level:
        return 0.0, 0.0
    for _ in range(max_passes if repeat else 1):
        for t, v, h in legs:
            for i in range(len(t) - 1):
                g, dt, dd = reference_step_energy(t, v, h, i, **step)
                if energy + g >= level:
                    f = (level - energy) / g
                    return time + f * dt, dist + f * dd
                energy += g
                time += dt
                dist += dd
    return None
