"""The pure core: arrays and small frozen dataclasses in and out; no file, network,
database or process I/O (tests/test_layout.py checks it).

- :mod:`~cevm.core.cycle`: drive cycles and the CE drive-cycle vector;
- :mod:`~cevm.core.model`: the CE model's energy and fuel from a vector;
- :mod:`~cevm.core.vehicle`: vehicles (read from files by :mod:`cevm.io.vehicles`) and
  :func:`~cevm.core.vehicle.predict`;
- :mod:`~cevm.core.trip`: a trip, its stored record and measured consumption;
- :mod:`~cevm.core.calibration`: fitting a vehicle to measured trips, cross-validated;
- :mod:`~cevm.core.sweep`: fleet predictions (sources x vehicles x masses, state of charge);
- :mod:`~cevm.core.feasibility`: margins and the largest payload;
- :mod:`~cevm.core.assignment`: the paper's fleet assignment (enumeration, MILP);
- :mod:`~cevm.core.detailed`: the detailed time-step model (the baseline).

Executors (:mod:`cevm.executors`) may be passed in (``sweep(..., executor=)``); the core
never creates one. This package imports none of its modules: import what you use.
"""
