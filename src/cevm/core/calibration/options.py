"""How a calibration screens its trips, validates and reports: one set of options, shared
by a forced term set (:func:`.fitting.fit`), the model selection
(:func:`.selection.select`) and the estimator (:class:`.estimator.Calibrator`) (pure)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

from cevm.core.calibration.candidate import Settings
from cevm.core.calibration.data import CalibrationError
from cevm.core.calibration.solve import HUBER_C
from cevm.core.uncertainty import Priors


@dataclass(frozen=True, kw_only=True)
class Options:
    """The options of a calibration, each with its default and why.

    Parameters
    ----------
    priors
        the terms' priors (:class:`cevm.core.uncertainty.Priors`); default the
        vehicle's own (``vehicle.priors``, read with its file), else none: each term is
        then what the trips say, within its physical range, and refused where they
        cannot say it
    cv_folds
        folds of the cross-validation, default 5 (the common choice: 80 % of the
        trips train each fit); 0 or 1 turns cross-validation off
    loo_below
        with fewer groups (trips without a group are their own group) than this,
        default 10, cross-validation is leave-one-(group-)out: 5 folds of so few trips
        would remove too much of the training data
    max_rel_uncertainty
        trips whose uncertainty / measured exceeds this are excluded,
        default 0.10: beyond 10 % a trip says less about eta than the model's own error
        (the paper's CE model scatters by about 4 %)
    min_distance_m
        shorter trips are excluded [m], default 1000 m: below that, counter
        resolution and the energy of the start (battery or engine warm-up) dominate
    rel_uncertainty_floor
        lower bound of the relative uncertainty [-], default 0.001:
        no on-board counter is better than 0.1 %, and a zero would be an infinite weight
    max_correlation, max_rel_se
        the identifiability limits of a term without a prior
        (:mod:`.identifiability`: refused above a multiple correlation of 0.98 with the
        others, or a standard error above 50 % of its value)
    time_repeats
        predictions timed per trip, default 20; 0 skips the timing
    seed
        seed of the fold assignment, default 0 (results are reproducible)
    vehicle_id
        recorded in the result's :attr:`~.fitting.CalibrationResult.domain`
    robust
        default True, Huber's M-estimate (:mod:`.posterior`): a trip whose
        measurement is far off cannot pull the fit more than one 2.5 sigma away; the
        model selection then compares candidates with a Huber loss too
    interval
        level of the rows' held-out intervals, default 0.9
    fit_balance
        search the balance temperatures of temperature terms on a grid
        (:data:`.candidate.HEATING_GRID_C`); default None: searched when the terms are
        chosen, the vehicle's own for a forced term set
    plausible
        physical ranges {term: (low, high)} of the values (SI, vehicle-field
        meaning: eta as an efficiency) that replace the terms' own, for research fits on
        models that are no real vehicle (benchmarks/bench_tables.py fits the detailed
        model with every loss switched off: eta 0.95, above any real EV's 0.89); a fit
        on real trips keeps the defaults
    """

    priors: Priors | None = None
    cv_folds: int = 5
    loo_below: int = 10
    max_rel_uncertainty: float = 0.10
    min_distance_m: float = 1000.0
    rel_uncertainty_floor: float = 0.001
    max_correlation: float = 0.98
    max_rel_se: float = 0.5
    time_repeats: int = 20
    seed: int = 0
    vehicle_id: str | None = None
    robust: bool = True
    interval: float = 0.9
    fit_balance: bool | None = None
    plausible: Mapping[str, tuple[float, float]] | None = None

    @classmethod
    def of(cls, options: Options | None = None, **changes) -> Options:
        """``options`` (default all defaults) with ``changes``; an unknown name is
        refused with the names there are (a typo must not be a silent default)."""
        names = {f.name for f in fields(Options)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise TypeError(f"unknown calibration option(s) {', '.join(unknown)}; the options are: "
                            f"{', '.join(sorted(names))}")
        base = Options() if options is None else options
        return replace(base, **changes) if changes else base

    def check(self) -> None:
        """Refuse an interval level outside (0, 1)."""
        level = self.interval
        if not (isinstance(level, (int, float)) and 0.0 < level < 1.0):
            raise CalibrationError(f"the interval level must be in (0, 1), got {level!r}")

    def settings(self, fit_balance: bool) -> Settings:
        """How the candidates are fitted (:class:`.candidate.Settings`); ``fit_balance``
        where :attr:`fit_balance` is None."""
        return Settings(huber_c=HUBER_C if self.robust else None, cv_folds=self.cv_folds, loo_below=self.loo_below,
                        seed=self.seed, fit_balance=fit_balance if self.fit_balance is None else self.fit_balance,
                        max_correlation=self.max_correlation, max_rel_se=self.max_rel_se, plausible=self.plausible)

    def screening(self) -> tuple[float, float, float]:
        """(max_rel_uncertainty, min_distance_m, rel_uncertainty_floor), as
        :func:`.data.select_trips` takes them."""
        return self.max_rel_uncertainty, self.min_distance_m, self.rel_uncertainty_floor
