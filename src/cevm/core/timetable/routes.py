"""A block's legs as drive cycles, to be stored as a route (pure): each revenue trip's
cycle synthesised from its stop times (:func:`cevm.core.timetable.synthesis.synthesise_trip`)
with its road's elevation, each empty run's from its two ends, flat."""

from __future__ import annotations

import numpy as np

from cevm.core.cycle import DriveCycle
from cevm.core.timetable import geometry as geo


def block_cycles(tt, gm, sch, bd, params, *, seed: int = 0) -> list[DriveCycle]:
    """The drive cycles of the legs of ``bd`` (a :class:`~cevm.core.timetable.duties.BlockDay`),
    named after their trips (empty running: its kind and number)."""
    from cevm.core.timetable.synthesis import synthesise_trip

    rng = np.random.default_rng(seed)
    out: list[DriveCycle] = []
    lg = bd.legs
    for j in range(lg.n):
        inst = int(bd.instance[j])
        elev = None
        if inst >= 0:
            i = int(sch.trip[inst])
            d, arr, dep = gm.stops_of(tt, i)
            t0 = dep[0]
            c = synthesise_trip(d, arr - t0, dep - t0, params, rng)
            prof = sch.profiles.get(gm.key[i])
            if prof is not None:
                start = float(gm.along_m[tt.bounds[i]])
                pd, pz = geo.profile_between(prof[0], prof[1], start, start + float(d[-1]))
                elev = np.interp(c.distance_m, pd, pz)
            name = str(tt.trip_id[i])
        else:
            dur = max(float(lg.end_s[j] - lg.start_s[j]), 1.0)
            c = synthesise_trip(np.array([0.0, lg.distance_m[j]]), np.array([0.0, dur]), np.array([0.0, dur]),
                                params, rng)
            name = f"{lg.kind[j]}-{j + 1}"
        out.append(DriveCycle(np.asarray(c.time_s, dtype=np.float64), np.asarray(c.speed_mps, dtype=np.float64),
                              elev, name=name))
    return out
