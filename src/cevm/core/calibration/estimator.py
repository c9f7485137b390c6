"""The calibration as an estimator, in scikit-learn's shape (pure).

Parameters go to the constructor, explicitly (nothing positional but the vehicle to
start from); :meth:`Calibrator.fit` takes the trips and returns the estimator, its
results in attributes ending in ``_``; :meth:`Calibrator.predict` predicts cycles with
their intervals::

    cal = Calibrator(truck, vehicle_id="HGV-11").fit(trips)
    cal.terms_                 # ('eta', 'idle', 'kin', 'heat', 'cool'): chosen by grouped CV
    cal.cv_results_["mean_cv_error_pct"]                  # every candidate compared
    p = cal.predict(vector, mass_kg=[18000, 44000])       # l (ICE) or J (EV)
    p.mean, p.interval(0.9)

The trips come from a store with :func:`cevm.store.calibration.trips_for_calibration`, or are
built as :class:`~.data.TripData`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cevm.core.calibration.data import TripData
from cevm.core.calibration.fitting import CalibrationResult, fit
from cevm.core.calibration.options import Options
from cevm.core.calibration.selection import Selection, select
from cevm.core.calibration.validation import ErrorStats
from cevm.core.cycle import CycleVector, DriveCycle, cycle_vector
from cevm.core.predictive import Features, Predictive, predictive
from cevm.core.vehicle import Vehicle


@dataclass(frozen=True, kw_only=True, eq=False)
class Calibrator(Options):
    """Calibrate a vehicle's CE-model terms against measured trips (scikit-learn's shape).

    Parameters
    ----------
    vehicle
        the vehicle to start from (its file's values, class and priors); the one
        positional parameter
    terms
        the extra terms to choose among by grouped cross-validation (default all of
        the powertrain's: EV regen, aux, heat, cool, warm; ICE idle, run, kin, heat,
        cool, warm); ignored with ``fit_terms``
    fit_terms
        a forced term set instead of a choice ("eta" plus any of the above and
        "cda", "cr"), as ``cevm calibrate --fit``; default None: choose
    nested
        with a choice, also cross-validate the choice itself (nested
        cross-validation: the error to quote for the procedure), default True
    priors, cv_folds, loo_below, max_rel_uncertainty, min_distance_m, rel_uncertainty_floor
        and max_correlation, max_rel_se, time_repeats, seed, vehicle_id, robust,
        interval, fit_balance, plausible: the calibration's options, each with its
        default and why in :class:`.options.Options`

    Attributes
    ----------
    vehicle_
        the calibrated :class:`~cevm.core.vehicle.Vehicle` (fitted values, its
        posterior and what it was calibrated on: it predicts with intervals)
    terms_
        the terms of the fitted model, chosen or forced
    fitted_
        vehicle field -> (value, standard deviation), SI units
    cv_results_
        dict of lists, one element per candidate compared (a forced term set:
        one): ``terms``, ``standstill``, ``status``, ``mean_cv_error_pct``,
        ``std_cv_error_pct``, ``rms_cv_error_pct``, ``std_in_sample_error_pct``, ``loss``
        (the selection's mean loss), ``se_vs_best``, ``rank`` (1 the lowest loss)
    nested_cv_
        the nested cross-validated error statistics (None without a choice)
    result_
        the full :class:`~.fitting.CalibrationResult` (per-trip rows, coverage,
        warnings, excluded trips, ...)
    selection_
        the :class:`~.selection.Selection` (None for a forced term set)

    The parameters are fixed at construction; :meth:`fit` fills the attributes (they end
    in ``_``) and returns the estimator.
    """

    vehicle: Vehicle = field(kw_only=False)
    terms: Sequence[str] | None = None
    fit_terms: Sequence[str] | None = None
    nested: bool = True
    _fitted: dict = field(default_factory=dict, init=False, repr=False)

    # ------------------------------------------------------------------ fitting

    def options(self) -> Options:
        """The calibration options of this estimator (:class:`.options.Options`)."""
        return Options.of(**{k: getattr(self, k) for k in Options.__dataclass_fields__})

    def fit(self, trips: Sequence[TripData] | Any) -> Calibrator:
        """Fit to ``trips`` (:class:`~.data.TripData`, or what
        :func:`cevm.store.calibration.trips_for_calibration` returns: its ``trips``) and return
        the estimator. Raises :class:`~.data.CalibrationError` when the trips cannot
        calibrate the vehicle (fewer than 3 usable, a physically implausible forced fit)."""
        trips = tuple(getattr(trips, "trips", trips))
        opts = self.options()
        selection: Selection | None = None
        if self.fit_terms is not None:
            result = fit(self.vehicle, trips, tuple(self.fit_terms), opts)
        else:
            selection = select(self.vehicle, trips, opts, terms=self.terms, nested=self.nested)
            result = selection.result
        self._fitted.clear()
        self._fitted.update(result_=result, selection_=selection, cv_results_=_cv_results(result, selection))
        return self

    def _get(self, name: str):
        try:
            return self._fitted[name]
        except KeyError:
            raise AttributeError(f"{name}: this Calibrator is not fitted yet; call fit(trips) first") from None

    @property
    def result_(self) -> CalibrationResult:
        return self._get("result_")

    @property
    def selection_(self) -> Selection | None:
        return self._get("selection_")

    @property
    def cv_results_(self) -> dict[str, list]:
        return self._get("cv_results_")

    @property
    def vehicle_(self) -> Vehicle:
        return self.result_.vehicle

    @property
    def terms_(self) -> tuple[str, ...]:
        return tuple(self.result_.terms)

    @property
    def fitted_(self) -> dict:
        return dict(self.result_.fitted)

    @property
    def nested_cv_(self) -> ErrorStats | None:
        sel = self.selection_
        return None if sel is None else sel.nested_cv

    # --------------------------------------------------------------- predicting

    def predict(self, cycles: CycleVector | DriveCycle | Sequence[CycleVector | DriveCycle], *,
                mass_kg: ArrayLike | None = None, ambient_c: ArrayLike | None = None) -> Predictive:
        """The calibrated vehicle's predictive distribution on ``cycles``.

        Parameters
        ----------
        cycles : a cycle's vector (:func:`cevm.drive_cycle_vector`) or the cycle
            (:class:`cevm.DriveCycle`, reduced here), or a sequence of them
        mass_kg : gross mass(es) [kg], default the vehicle's
        ambient_c : ambient temperature(s) [degC], broadcast with ``mass_kg``; default
            the vehicle's reference temperature

        Returns
        -------
        :class:`cevm.core.predictive.Predictive`: ``mean`` and ``sd`` [l (ICE) or J (EV)]
        of the shape of ``mass_kg`` and ``ambient_c`` broadcast (with a leading axis per
        cycle for a sequence), ``interval(level)`` their central range, ``source`` and
        ``note`` what the range rests on.
        """
        vehicle = self.vehicle_
        single = isinstance(cycles, (CycleVector, DriveCycle))
        items: list[CycleVector | DriveCycle] = [cycles] if isinstance(cycles, (CycleVector, DriveCycle)) \
            else list(cycles)
        out = [predictive(vehicle, Features.of(_vector(c), vehicle, mass_kg, ambient_c)) for c in items]
        if single:
            return out[0]
        return Predictive(np.stack([p.mean for p in out]), np.stack([p.sd for p in out]),
                          out[0].source if out else "none", out[0].note if out else "")


def _vector(cycle: CycleVector | DriveCycle) -> CycleVector:
    return cycle if isinstance(cycle, CycleVector) else cycle_vector(cycle)


def _cv_results(result: CalibrationResult, selection: Selection | None) -> dict[str, list]:
    """scikit-learn's ``cv_results_``: a dict of equal-length lists, one element per
    candidate (a forced term set: the one fitted)."""
    nan = float("nan")
    rows: list[tuple[str, bool, str, ErrorStats | None, ErrorStats | None, float, float]]
    if selection is None:
        rows = [("+".join(result.terms), False, "forced", result.cv, result.in_sample, nan, nan)]
    else:
        rows = [(c.label.removesuffix(" (standstill)"), c.standstill, c.status, c.cv, c.in_sample, c.mse,
                 c.se_vs_best) for c in selection.candidates]

    def stat(s: ErrorStats | None, name: str) -> float:
        return nan if s is None else float(getattr(s, name))

    loss = np.array([r[5] for r in rows], dtype=np.float64)
    order = np.argsort(np.where(np.isfinite(loss), loss, np.inf), kind="stable")
    rank = np.empty(len(rows), dtype=np.int64)
    rank[order] = np.arange(1, len(rows) + 1)
    return {
        "terms": [r[0] for r in rows],
        "standstill": [r[1] for r in rows],
        "status": [r[2] for r in rows],
        "mean_cv_error_pct": [stat(r[3], "mean_pct") for r in rows],
        "std_cv_error_pct": [stat(r[3], "std_pct") for r in rows],
        "rms_cv_error_pct": [stat(r[3], "rms_pct") for r in rows],
        "std_in_sample_error_pct": [stat(r[4], "std_pct") for r in rows],
        "loss": [float(r[5]) for r in rows],
        "se_vs_best": [float(r[6]) for r in rows],
        "rank": [int(k) for k in rank],
    }
