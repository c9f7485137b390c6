"""Calibration of a vehicle's CE-model terms against measured trip consumption (pure).

The paper fits one number, the average efficiency eta, "using data from a few drive
cycles" (section 2.3) and judges the model by the per-cycle relative error
e = (modelled - measured) / measured (tables 1 and 2). On real fleets one eta misses by
20-45 %: auxiliary loads that follow the weather, regeneration that is not eta^2, and a
diesel's fuel per wheel kWh that depends on the duty. This package fits those terms
(:mod:`cevm.core.energy`) as inference: physically informed priors on their
coefficients (:mod:`cevm.core.uncertainty`), a posterior, and a model of how trips
scatter around it, so that every prediction comes with its range
(:mod:`cevm.core.predictive`). It chooses the structural terms by grouped
cross-validation and refuses what physics refuses.

Modules, in the order a calibration uses them:

- :mod:`.data`             the trips (:class:`TripData`) and their screening into arrays
- :mod:`.terms`            the consumption model, linear in the terms' coefficients
- :mod:`.posterior`        priors x likelihood: the posterior, the trips' scatter
- :mod:`.identifiability`  which terms the trips can tell
- :mod:`.fit_plausibility` which fitted values physics refuses; the standstill evidence
- :mod:`.candidate`        one candidate: balance temperatures, posterior, held-out scatter
- :mod:`.validation`       grouped folds, error statistics, predictions, timing
- :mod:`.fitting`          :func:`fit`: one term set, its cross-validated intervals
- :mod:`.selection`        :func:`select`: the candidates, the one-standard-error choice,
                           nested cross-validation of the procedure
- :mod:`.options`          :class:`Options`: how trips are screened, folded and reported
                           (one set, shared by the two above and the estimator)
- :mod:`.estimator`        :class:`Calibrator`: the calibration in scikit-learn's shape
                           (``fit(trips)``, ``predict(cycles)`` with intervals)
- :mod:`.solve`            helpers of the fit (starting values, bounds, value covariance)
"""

from cevm.core.calibration.data import CalibrationError, TripData, TripSet
from cevm.core.calibration.estimator import Calibrator
from cevm.core.calibration.fitting import CalibrationResult, fit, fit_domain, predict_trips
from cevm.core.calibration.options import Options
from cevm.core.calibration.selection import Candidate, Selection, candidate_sets, select
from cevm.core.calibration.terms import ALIASES, EXTRA_TERMS, TERMS_BY_POWERTRAIN, Term, term
from cevm.core.calibration.validation import ErrorStats, TripRow
from cevm.units import J_PER_KWH

__all__ = [
    "ALIASES",
    "EXTRA_TERMS",
    "TERMS_BY_POWERTRAIN",
    "CalibrationError",
    "CalibrationResult",
    "Calibrator",
    "Candidate",
    "ErrorStats",
    "Options",
    "Selection",
    "Term",
    "TripData",
    "TripRow",
    "TripSet",
    "candidate_sets",
    "display_value",
    "fit",
    "fit_domain",
    "predict_trips",
    "select",
    "term",
]


def display_value(result: CalibrationResult, value: float) -> float:
    """Consumption in display units: litres, or kWh for joules."""
    return value / J_PER_KWH if result.unit == "J" else value
