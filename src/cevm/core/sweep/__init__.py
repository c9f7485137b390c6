"""Fleet predictions (pure): vehicles x sources x masses, state of charge along the way.

A *source* is what a vehicle drives: a cycle file, a stored trip or a named route (a
sequence of legs). It carries its CE drive-cycle vector (:class:`~cevm.core.cycle.CycleVector`,
for totals) and its legs' profiles (time, speed, elevation; for the state of charge along
the way). A :class:`PredictionSet` is the flat list of (vehicle, mass) predictions of a
sweep; :func:`predict_source` evaluates all of them on one source in numpy arrays, and
:func:`sweep` yields one such block per source, so a million rows never need a million
Python objects.

Totals (wheel energy, battery energy, fuel) are the CE model on the source's vector
(eq. 22-31); the lowest state of charge is the exact maximum of the energy drawn along
the way, found without summing every step of every prediction; where a row crosses its
reserve or runs empty, its range, and whether it can follow the source (power, speed)
come from the source's per-step terms.

One module per concern, in the order a prediction flows through them:

- :mod:`~cevm.core.sweep.steptable`: a leg's samples (:class:`LegProfile`) and a source's
  plain per-step terms in driving order (:class:`StepTable`);
- :mod:`~cevm.core.sweep.compressed`: the step terms compressed into blocks for the
  lowest state of charge (:class:`SourceSteps`);
- :mod:`~cevm.core.sweep.sources`: :class:`Source` (vector, legs, and the two above,
  built once on first use);
- :mod:`~cevm.core.sweep.predictions`: :class:`PredictionSet` and each row's terms
  beyond the wheel (:func:`row_terms`, :data:`AMBIENT_ORIGINS`);
- :mod:`~cevm.core.sweep.wheel`: the CE wheel energy of any mix of predictions in one
  pass (:func:`ce_wheel_energy_j`);
- :mod:`~cevm.core.sweep.peak`: the largest energy drawn along the way, by block bounds
  and pruning (:func:`peak_energy_j`);
- :mod:`~cevm.core.sweep.stepenergy`: the energy of each step per row, with every term of
  :mod:`cevm.core.energy` (:func:`energy_trajectory`);
- :mod:`~cevm.core.sweep.ranges`: where the reserve is crossed and the battery or tank
  runs empty, and the range (:func:`source_ranges`);
- :mod:`~cevm.core.sweep.power`: the power and speed a source asks
  (:func:`follow_flags`);
- :mod:`~cevm.core.sweep.block`: :class:`SweepBlock`, the rows of one source;
- :mod:`~cevm.core.sweep.evaluate`: a set on a few sources at once
  (:func:`predict_source`, :func:`predict_sources`);
- :mod:`~cevm.core.sweep.driver`: :func:`sweep`, batches of sources in this process or
  on an executor.

This package re-exports the names the rest of cevm uses; the helpers stay in their
modules.
"""

from cevm.core.sweep.block import DEFAULT_RESERVE_PCT, DEFAULT_SOC_START_PCT, SweepBlock
from cevm.core.sweep.compressed import BLOCK_ELEMENTS, SourceSteps, build_steps
from cevm.core.sweep.driver import SWEEP_BATCH_CELLS, sweep
from cevm.core.sweep.evaluate import check_cr, predict_source, predict_sources
from cevm.core.sweep.peak import peak_energy_j
from cevm.core.sweep.power import POWER_WINDOW_S, follow_flags, peak_wheel_power_w, power_mass_window
from cevm.core.sweep.predictions import AMBIENT_ORIGINS, PredictionSet, RowTerms, row_terms
from cevm.core.sweep.ranges import RANGE_FIELDS, crossings, source_ranges
from cevm.core.sweep.sources import Source
from cevm.core.sweep.stepenergy import energy_trajectory, step_coefficients, step_energies
from cevm.core.sweep.steptable import LegProfile, StepTable, build_step_table
from cevm.core.sweep.wheel import ce_wheel_energy_j

__all__ = [
    "AMBIENT_ORIGINS", "BLOCK_ELEMENTS", "DEFAULT_RESERVE_PCT", "DEFAULT_SOC_START_PCT", "POWER_WINDOW_S",
    "RANGE_FIELDS", "SWEEP_BATCH_CELLS", "LegProfile", "PredictionSet", "RowTerms", "Source", "SourceSteps",
    "StepTable", "SweepBlock", "build_step_table", "build_steps", "ce_wheel_energy_j", "check_cr", "crossings",
    "energy_trajectory", "follow_flags", "peak_energy_j", "peak_wheel_power_w", "power_mass_window",
    "predict_source", "predict_sources", "row_terms", "source_ranges", "step_coefficients", "step_energies",
    "sweep",
]
