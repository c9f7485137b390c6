"""What a sweep gives per source: :class:`SweepBlock`, the predictions of one prediction
set on one source, as arrays of rows, and the defaults of the state of charge."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cevm.core.sweep.predictions import PredictionSet
from cevm.core.sweep.sources import Source

#: Default state of charge at the start [%]: a vehicle leaving the depot fully charged.
DEFAULT_SOC_START_PCT = 100.0
#: Default reserve [%]: the paper's example of the level at which commercial EVs warn the
#: driver, "e.g., 15%" (section 3.2, figure 4).
DEFAULT_RESERVE_PCT = 15.0


@dataclass(frozen=True, eq=False)
class SweepBlock:
    """The predictions of one :class:`PredictionSet` on one source (arrays of P rows).

    ``wheel_energy_j`` [J]; ``energy_j`` battery energy [J] (NaN for ICE rows);
    ``fuel_l`` [l] (NaN for EV rows); ``soc_end_pct``, ``soc_min_pct`` [%] (NaN for ICE
    rows, and for EVs when not computed); ``reserve_ok`` (EV rows: lowest SoC >=
    reserve); ``tank_ok`` 1.0 / 0.0 for ICE rows with a known tank, else NaN;
    ``ambient_c`` the ambient temperature each row assumed [degC] and ``ambient_from``
    where it came from (index into :data:`AMBIENT_ORIGINS`, as float). ``reserve_ok``,
    ``tank_ok`` and ``feasible`` are :func:`cevm.core.limits.verdict`'s, the one verdict
    of every command.
    """

    source: Source
    source_index: int
    pset: PredictionSet
    wheel_energy_j: np.ndarray
    energy_j: np.ndarray
    fuel_l: np.ndarray
    soc_end_pct: np.ndarray
    soc_min_pct: np.ndarray
    reserve_ok: np.ndarray
    tank_ok: np.ndarray
    ambient_c: np.ndarray
    ambient_from: np.ndarray
    # where the reserve / the battery or tank is first crossed, and the range
    # (:func:`source_ranges`); None when not computed or when no row of the block crosses
    reserve_at_m: np.ndarray | None = None
    reserve_at_s: np.ndarray | None = None
    empty_at_m: np.ndarray | None = None
    empty_at_s: np.ndarray | None = None
    range_m: np.ndarray | None = None
    range_reserve_m: np.ndarray | None = None
    # whether the vehicle can follow the source (:func:`follow_flags`); None: not known
    over_power: np.ndarray | None = None
    over_speed: np.ndarray | None = None
    # the power the source asks at each row's mass [W] (its peak mean wheel power over
    # cevm.core.limits.POWER_WINDOW_S); None: not computed
    power_demand_w: np.ndarray | None = None
    # the verdict of each row (cevm.core.limits.verdict): 1.0 / 0.0, NaN unknown
    feasible: np.ndarray | None = None
    # what the rows assumed of the battery [%]
    soc_start_pct: float = DEFAULT_SOC_START_PCT
    reserve_pct: float = DEFAULT_RESERVE_PCT

    @property
    def n(self) -> int:
        return self.pset.n
