"""Step 5 of the cleaning: the speed rows split into trips (ignition, gaps, holes in the
speed, long stops)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cevm.ingest.cleaning.arrays import _ffill, _nonzero, _runs
from cevm.ingest.cleaning.params import CleanParams

_SPLIT_REASONS = ("start", "ignition", "gap", "speed_gap", "long_stop", "charging", "max_duration")


@dataclass(frozen=True)
class StopSignals:
    """What tells a stop from a charge or from driving the log did not record, per speed
    row (``ts``): the battery power [W, + = discharge] (None: not logged), the state of
    charge [%] and the energy counter net of regeneration [J] forward-filled (None: not
    logged), and ``displacement_m(t0, t1)``: the
    distance [m] between the GPS fixes at the times ``t0`` and ``t1`` [s] (arrays; NaN
    where no fix is near enough), None without positions."""

    battery_power_w: np.ndarray | None = None
    soc_pct: np.ndarray | None = None
    displacement_m: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    energy_counter_j: np.ndarray | None = None

    def subset(self, idx: np.ndarray | None) -> StopSignals:
        if idx is None:
            return self

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[idx]

        return StopSignals(pick(self.battery_power_w), pick(self.soc_pct), self.displacement_m,
                           pick(self.energy_counter_j))


def _segment(ts, vs, on, p: CleanParams, signals: StopSignals = StopSignals(), notes: list | None = None):
    """Split the speed rows (times ts, speeds vs, ignition on) into trips (step 5 of
    the module docstring); ``signals`` tell charging stops and holes the vehicle drove
    through (:class:`StopSignals`).

    Returns the kept row indices (into ts; None: every row), the position of each
    trip's first row among the kept rows, and the reason each trip started ('start',
    'ignition', 'gap', 'speed_gap', 'long_stop', 'charging', 'max_duration'). ``notes``, a list, gets a
    dict for each charging stop and each hole between standstill rows over which the
    vehicle moved (``kind`` 'charging' or 'moved_hole', ``t0_s``, ``t1_s`` [s, UTC], and
    ``kwh``, ``soc_rise_pct`` or ``displacement_m``), for the file's repairs."""
    if not ts.size:
        return np.empty(0, dtype=np.int64), np.zeros(0, dtype=np.int64), []
    keep = on.copy()
    keep[1:] |= on[:-1]  # the first "off" row ends the trip before it
    if keep.all():
        idx, t_kept, v_kept, on_kept = None, ts, vs, on
    else:
        idx = _nonzero(keep)
        if idx.size == 0:
            return idx, np.zeros(0, dtype=np.int64), []
        t_kept, v_kept, on_kept = ts[idx], vs[idx], on[idx]
    del keep
    notes = [] if notes is None else notes
    reason = _split_points(t_kept, v_kept, on_kept, idx, p, signals.displacement_m, notes)
    idx, reason = _split_long_stops(t_kept, v_kept, idx, reason, p, signals.subset(idx), notes)
    if p.max_trip_s is not None:
        t_now = t_kept if idx is None else ts[idx]
        cut = _split_long_trips(t_now, reason, p.max_trip_s)
        if cut.size:
            notes.append({"kind": "max_duration", "t0_s": float(t_now[cut[0]]), "splits": int(cut.size),
                          "max_trip_s": float(p.max_trip_s)})
        del t_now
    starts = np.concatenate(([0], np.flatnonzero(reason > 0)))
    start_reasons = [_SPLIT_REASONS[int(reason[s])] if s > 0 else "start" for s in starts]
    return idx, starts, start_reasons


def _split_points(t_kept, v_kept, on_kept, idx, p: CleanParams, displacement_m=None,
                  notes: list | None = None) -> np.ndarray:
    """Per kept row, why a trip starts there (an index into :data:`_SPLIT_REASONS`, 0
    for none): the ignition turned on (or came back after dropped rows; ``idx`` the
    kept rows, None: all), no speed for more than ``gap_s``, or a hole over
    ``max_fill_s`` with the vehicle moving at either end (a hole between two standstill
    rows is a stop, unless the GPS fixes at its ends are more than
    ``stop_max_displacement_m`` apart: then it drove in the hole)."""
    k = t_kept.size
    reason = np.zeros(k, dtype=np.int8)
    dt = np.diff(t_kept)
    st = v_kept <= p.standstill_mps
    hole = dt > p.max_fill_s
    stop = st[1:] & st[:-1]
    moved = np.zeros(hole.size, dtype=bool)
    j = np.flatnonzero(hole & stop & (dt <= p.gap_s))
    if displacement_m is not None and j.size:
        d = np.asarray(displacement_m(t_kept[j], t_kept[j + 1]), dtype=float)
        far = d > p.stop_max_displacement_m  # NaN (no fix near an end): unknown, a stop
        moved[j[far]] = True
        if notes is not None:
            notes.extend({"kind": "moved_hole", "t0_s": float(t_kept[a]), "t1_s": float(t_kept[a + 1]),
                          "displacement_m": float(x)} for a, x in zip(j[far].tolist(), d[far].tolist(), strict=True))
    sgap = np.concatenate(([False], hole & (~stop | moved)))
    del hole, stop, moved
    reason[sgap] = 3
    del sgap, st
    gap = np.concatenate(([False], dt > p.gap_s))
    reason[gap] = 2
    del gap, dt
    back = ~on_kept[:-1] if idx is None else ~on_kept[:-1] | (np.diff(idx) > 1)
    ign = np.concatenate(([False], on_kept[1:] & back))
    reason[ign] = 1
    return reason


def _split_long_stops(t_kept, v_kept, idx, reason, p: CleanParams, signals: StopSignals = StopSignals(),
                      notes: list | None = None):
    """Standstill runs (not crossing a split) lasting more than ``stop_s``, or during
    which the vehicle charged (:func:`_charging_runs`), end their trip where the stop
    starts; the next starts where it ends, and the rows inside are dropped. Returns the
    kept ``idx`` (None: all rows) and ``reason``."""
    k = t_kept.size
    st = v_kept <= p.standstill_mps
    first, last = _runs(st, reason > 0)
    del st
    long_ = (t_kept[last] - t_kept[first]) > p.stop_s
    charge = _charging_runs(t_kept, first, last, p, signals, notes) & ~long_
    split = long_ | charge
    if not split.any():
        return idx, reason
    f, la = first[split], last[split]
    diff = np.zeros(k + 1, dtype=np.int8)  # runs are disjoint: the sum is 0 or 1
    np.add.at(diff, f + 1, 1)
    np.add.at(diff, la, -1)
    sel = ~(np.cumsum(diff, dtype=np.int8)[:k] > 0)  # not inside a long stop
    free = reason[la] == 0
    reason[la[free]] = np.where(long_[split][free], 4, 5)
    return (_nonzero(sel) if idx is None else idx[sel]), reason[sel]


def _split_long_trips(t_kept: np.ndarray, reason: np.ndarray, max_trip_s: float) -> np.ndarray:
    """Split each trip (rows from one ``reason > 0`` to the next) that lasts longer than
    ``max_trip_s`` into pieces of at most that long: a piece starts at the first row
    ``max_trip_s`` or more after the piece before it started (``"max_duration"``, in
    ``reason``, in place). One pass over the rows: within a trip the pieces are whole
    multiples of ``max_trip_s`` from its start, so a piece can be a little shorter when
    the rows do not fall on its boundary. Returns the rows where a piece starts."""
    k = t_kept.size
    if k < 2 or t_kept[-1] - t_kept[0] <= max_trip_s:
        return np.zeros(0, dtype=np.int64)
    starts = np.concatenate(([0], np.flatnonzero(reason[1:] > 0) + 1))
    lengths = np.diff(np.append(starts, k))
    t0 = np.repeat(t_kept[starts], lengths)  # each row's trip start [s]
    piece = np.floor((t_kept - t0) / max_trip_s).astype(np.int64)
    del t0
    new = np.flatnonzero(np.diff(piece) > 0) + 1  # rows where a trip's piece changes
    new = new[reason[new] == 0]
    reason[new] = _SPLIT_REASONS.index("max_duration")
    return new


def _charging_runs(t_kept, first, last, p: CleanParams, signals: StopSignals, notes: list | None) -> np.ndarray:
    """Which standstill runs (rows ``first[i]`` to ``last[i]``) are charging stops: the
    battery took in more than ``charge_power_w`` for ``charge_min_s`` in all, the
    state of charge rose by ``charge_soc_rise_pct``, or the energy counter (net of
    regeneration) fell by ``charge_counter_kwh`` (cleaning parameters). Each found
    gets a note (energy taken in [kWh] from the power, or the state of charge's rise)."""
    found = np.zeros(first.size, dtype=bool)
    if not first.size:
        return found
    kwh = np.full(first.size, np.nan)
    rise = np.full(first.size, np.nan)
    if signals.battery_power_w is not None:
        pw = signals.battery_power_w
        dt = np.append(np.minimum(np.diff(t_kept), p.max_fill_s), 0.0)  # each row's step, holes capped
        taking = pw < -p.charge_power_w  # NaN: not known to charge
        secs = np.concatenate(([0.0], np.cumsum(np.where(taking, dt, 0.0))))
        joules = np.concatenate(([0.0], np.cumsum(np.where(taking, -pw * dt, 0.0))))
        by_power = (secs[last + 1] - secs[first]) >= p.charge_min_s
        found |= by_power
        kwh = np.where(by_power, (joules[last + 1] - joules[first]) / 3.6e6, np.nan)
    if signals.soc_pct is not None:
        r = signals.soc_pct[last] - signals.soc_pct[first]
        by_soc = r >= p.charge_soc_rise_pct  # NaN: unknown
        found |= by_soc
        rise = np.where(by_soc, r, np.nan)
    if signals.energy_counter_j is not None:
        fall = signals.energy_counter_j[first] - signals.energy_counter_j[last]
        by_counter = ~found & (fall >= p.charge_counter_kwh * 3.6e6)  # NaN: unknown
        found |= by_counter
        kwh = np.where(by_counter, fall / 3.6e6, kwh)
    if notes is not None:
        for i in np.flatnonzero(found).tolist():
            notes.append({"kind": "charging", "t0_s": float(t_kept[first[i]]), "t1_s": float(t_kept[last[i]]),
                          "kwh": None if np.isnan(kwh[i]) else float(kwh[i]),
                          "soc_rise_pct": None if np.isnan(rise[i]) else float(rise[i])})
    return found


def _ignition_on(cols: dict, rows: np.ndarray | None, n: int) -> np.ndarray:
    """Ignition state of ``rows`` (None: all ``n``): the ignition column forward-filled
    (unknown before its first value = on); all on without the column."""
    if "ignition" in cols and np.isfinite(cols["ignition"]).any():
        ign = _ffill(cols["ignition"])
        return ~((ign if rows is None else ign[rows]) < 0.5)  # NaN before the first value = on
    return np.ones(n if rows is None else rows.size, dtype=bool)
