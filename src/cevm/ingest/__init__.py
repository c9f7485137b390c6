"""The ingest pipeline: logger CSV exports -> clean trips with road elevation, measured
consumption and drive-cycle vectors -> the trip store.

Its modules, in the order the data flows through them:

- :mod:`~cevm.ingest.profiles`: logger profiles (how each logger writes its CSV);
- :mod:`~cevm.ingest.reading` (with :mod:`~cevm.ingest.textfile`: bytes, gzip and text
  encodings streamed within limits; and :mod:`~cevm.ingest.timestamps`): a file's bytes
  -> canonical log frames in SI units;
- :mod:`~cevm.ingest.cleaning`: sorting, repairs, trip splitting, speed and distance;
- :mod:`~cevm.ingest.dsm` (with :mod:`~cevm.ingest.dsm_sources`: which rasters may be
  opened, remote ones only when asked for) and :mod:`~cevm.ingest.elevation` (its
  filters in :mod:`~cevm.ingest.road_filters`): DSM samples -> a road profile;
- :mod:`~cevm.ingest.consumption` (what is measured, and the choice among sources) and
  :mod:`~cevm.ingest.measured` (the estimators, over all of a batch's trips at once):
  measured energy or fuel of each trip;
- :mod:`~cevm.ingest.evidence`: ambient temperature and standstill measurements of each
  trip, over all of a batch's trips at once (evidence for a calibration, never a model
  input);
- :mod:`~cevm.ingest.task`: all of the above for one file (:func:`process_file`, the
  task that executors run);
- :mod:`~cevm.ingest.pipeline`: :func:`ingest`, discovery, dispatch, and the writes to
  the store.

Re-exported here: :func:`ingest`, :class:`IngestOptions`, :func:`process_file` and the
report types, each imported on first use (so that importing one light module of the
package, such as :mod:`~cevm.ingest.textfile` for the CLI's option defaults, does not
load the whole pipeline).
"""

import importlib

_EXPORTS = {
    "FileReport": "cevm.ingest.pipeline",
    "IngestReport": "cevm.ingest.pipeline",
    "discover": "cevm.ingest.pipeline",
    "ingest": "cevm.ingest.pipeline",
    "FileOutcome": "cevm.ingest.task",
    "IngestOptions": "cevm.ingest.task",
    "process_file": "cevm.ingest.task",
}

__all__ = ["FileOutcome", "FileReport", "IngestOptions", "IngestReport", "discover", "ingest", "process_file"]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'cevm.ingest' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next lookup is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
