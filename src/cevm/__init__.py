"""cevm: computationally efficient vehicle energy models.

A drive cycle (time, speed, elevation) is reduced once to a small drive-cycle vector;
afterwards the wheel energy, fuel or battery energy of any vehicle at any mass costs a
binary search and a few multiply-adds::

    import numpy as np
    import cevm
    from cevm.units import J_PER_KWH

    t = np.arange(0.0, 601.0)                       # s
    vec = cevm.drive_cycle_vector(t, np.full(t.size, 15.0))   # m/s; once per cycle
    bus = cevm.load_vehicle("configs/vehicles/electric-bus.toml")
    p = cevm.predict(vec, bus, mass_kg=np.linspace(9000, 14000, 6))
    p.energy_j / J_PER_KWH                          # kWh at the battery

The public API, by what it is for:

- cycles and predictions: :class:`DriveCycle`, :func:`drive_cycle_vector`,
  :class:`CycleVector`, :class:`Vehicle`, :func:`predict`, :class:`Prediction`;
- files: :func:`load_vehicle`, :func:`load_vehicles`, :func:`read_cycle_csv`;
- calibration: :class:`Calibrator` (scikit-learn's shape: ``Calibrator(vehicle, ...)
  .fit(trips)``, then ``.vehicle_``, ``.terms_``, ``.cv_results_``, ``.predict(cycles)``
  with intervals; a store's trips from :func:`trips_for_calibration`), :class:`TripData`,
  :class:`CalibrationResult`, and :func:`fit` (one forced term set, as a function);
- fleet predictions: :class:`Source`, :class:`PredictionSet`, :func:`sweep`,
  :func:`feasibility`;
- fleet assignment: :func:`load_scenario`, :func:`plan`;
- the detailed time-step model: :func:`simulate`;
- logger data: :class:`TripStore` (the SQLite trip store), :func:`trips_for_calibration`
  (a vehicle's stored trips as a calibration's input), :class:`IngestOptions` (the
  pipeline itself is :func:`cevm.ingest.ingest`);
- errors: :class:`CevmError`, :class:`InputError`;
- :func:`tune_allocator`, for long sweeps in your own program (the CLI calls it).

The names are loaded on first use, so ``import cevm`` stays cheap (numpy, pandas,
rasterio, matplotlib and typer are imported only by what needs them). The packages
behind them: :mod:`cevm.core` (pure: arrays and small frozen dataclasses in and out, no
I/O), :mod:`cevm.io` (the user's files), :mod:`cevm.ingest` (logger exports -> trips),
:mod:`cevm.store` (the trip store), :mod:`cevm.executors` (serial, process pool, Dask)
and :mod:`cevm.cli` (the command line, which the library never imports).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_PUBLIC = {
    "DriveCycle": "cevm.core.cycle",
    "CycleVector": "cevm.core.cycle",
    "drive_cycle_vector": "cevm.core.cycle",
    "Vehicle": "cevm.core.vehicle",
    "predict": "cevm.core.vehicle",
    "Prediction": "cevm.core.model",
    "load_vehicle": "cevm.io.vehicles",
    "load_vehicles": "cevm.io.vehicles",
    "read_cycle_csv": "cevm.io.cycles",
    "Calibrator": "cevm.core.calibration",
    "TripData": "cevm.core.calibration",
    "fit": "cevm.core.calibration",
    "CalibrationResult": "cevm.core.calibration",
    "Source": "cevm.core.sweep",
    "PredictionSet": "cevm.core.sweep",
    "sweep": "cevm.core.sweep",
    "feasibility": "cevm.core.feasibility",
    "load_scenario": "cevm.io.scenario",
    "plan": "cevm.core.assignment",
    "simulate": "cevm.core.detailed",
    "TripStore": "cevm.store.tripstore",
    "trips_for_calibration": "cevm.store.calibration",
    "IngestOptions": "cevm.ingest.task",
    "CevmError": "cevm.errors",
    "InputError": "cevm.errors",
    "tune_allocator": "cevm.runtime",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'cevm' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next lookup is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
