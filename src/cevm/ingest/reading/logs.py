"""What the reader returns: one :class:`ParsedLog` per vehicle of a file, with the
:class:`EnergySource` columns it holds."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np

from cevm.lazy import pd


@dataclass(frozen=True)
class EnergySource:
    """A measured-energy column present in a parsed log, for the consumption stage.

    Parameters
    ----------
    column : canonical column of ``ParsedLog.frame`` holding the measurement, or the
        virtual ``"battery_power_w"`` (= battery_voltage_v * battery_current_a, both in
        the frame; formed by :mod:`cevm.ingest.consumption`).
    kind : ``"rate"`` (fuel rate [l/s] or battery power [W], integrate over time),
        ``"counter"`` (cumulative total [l] or [J], take differences; may wrap or reset)
        or ``"soc"`` (state of charge [%]; energy = -delta SoC / 100 * ``capacity_j``).
    quantity : ``"fuel_l"`` (litres of fuel) or ``"energy_j"`` (joules at the battery).
    resolution : quantisation step in the column's SI unit: l/s for a fuel rate, W for
        battery power, l for a fuel counter, J for an energy counter, % for a state of
        charge; 0 when unknown or continuous.
    priority : trust rank, 1 = most trusted (e.g. the flow meter on trucks, the FMS total
        energy on buses, per LOGGERS.md); the consumption stage prefers the lowest number
        among sources of the same quantity that have usable data.
    capacity_j : usable battery capacity [J] for ``kind == "soc"`` when the profile knows
        it (the Twizy's 6.1 kWh); ``None`` otherwise (take it from the vehicle config).
    source_column : the logger's own column name(s), for messages.
    modulus : value at which a counter wraps to 0 (same unit), when the profile knows it
        (the FMS 32-bit fuel counter at 0.5 l per bit: 2**31 l); ``None`` otherwise.
    accuracy_pct : the profile's systematic (calibration) uncertainty of the source, 1
        sigma, in % of the value; ``None``: the default of its kind
        (:data:`cevm.ingest.consumption.DEFAULT_ACCURACY_PCT`).
    """

    column: str
    kind: Literal["rate", "counter", "soc"]
    quantity: Literal["fuel_l", "energy_j"]
    resolution: float
    priority: int
    capacity_j: float | None = None
    source_column: str = ""
    modulus: float | None = None
    accuracy_pct: float | None = None


@dataclass(frozen=True, eq=False)
class ParsedLog:
    """One vehicle's rows of one logger file, in canonical columns.

    ``columns`` holds ``time_s`` (UTC seconds since the Unix epoch, float64),
    ``source_line`` (1-based line in the file, int32; int64 past 2**31 lines) and every
    canonical column the profile maps and the file has (SI, NaN = no value; float64, or
    float32 where the column is SI as logged and every value is exactly a float32: the
    same values), as numpy arrays, rows in file order: what the cleaning takes
    (:class:`~cevm.ingest.cleaning.CleanStream`), with no frame in between. ``frame`` is
    the same as a DataFrame (its ``vehicle_id`` column categorical: one id), made on
    first use around the arrays (no copy).
    ``repairs`` lists every repair made while reading the file (file-wide, so shared by
    the logs of a multi-vehicle file).
    ``sha256`` is the hex digest of the file's bytes on disk (compressed bytes for a .gz
    file), computed on first use from the file (the ingest pipeline hashes files
    itself, before reading them).
    """

    path: Path
    profile: str
    vehicle_id: str
    columns: dict[str, np.ndarray]
    metadata: dict[str, str]
    energy_sources: tuple[EnergySource, ...]
    repairs: list[str]

    @cached_property
    def frame(self) -> pd.DataFrame:
        """:attr:`columns` as a DataFrame (``time_s``, ``source_line``, ``vehicle_id``,
        then the others), around the same arrays."""
        names = list(self.columns)
        n = len(self.columns["time_s"]) if "time_s" in self.columns else 0
        ids = pd.Categorical.from_codes(np.zeros(n, np.int8), dtype=pd.CategoricalDtype([self.vehicle_id]))
        return pd.DataFrame({**{c: self.columns[c] for c in names[:2]}, "vehicle_id": ids,
                             **{c: self.columns[c] for c in names[2:]}}, copy=False)

    def __len__(self) -> int:
        """Its rows."""
        return len(self.columns["time_s"]) if "time_s" in self.columns else 0

    @cached_property
    def sha256(self) -> str:
        """Hex SHA-256 of the file's bytes on disk."""
        with open(self.path, "rb") as fh:
            return hashlib.file_digest(fh, "sha256").hexdigest()
