"""The ingest pipeline: logger CSV exports -> clean trips with road elevation, measured
consumption and drive-cycle vectors -> the trip store.

Its modules, in the order the data flows through them:

- :mod:`~cevm.ingest.profiles`: logger profiles (how each logger writes its CSV);
- :mod:`~cevm.ingest.reading` (with :mod:`~cevm.ingest.timestamps`): a file's bytes ->
  canonical log frames in SI units;
- :mod:`~cevm.ingest.cleaning`: sorting, repairs, trip splitting, speed and distance;
- :mod:`~cevm.ingest.dsm` and :mod:`~cevm.ingest.elevation`: DSM samples -> a road
  profile;
- :mod:`~cevm.ingest.consumption`: measured energy or fuel of each trip;
- :mod:`~cevm.ingest.task`: all of the above for one file (:func:`process_file`, the
  task that executors run);
- :mod:`~cevm.ingest.pipeline`: :func:`ingest`, discovery, dispatch, and the writes to
  the store.

Re-exported here: :func:`ingest`, :class:`IngestOptions`, :func:`process_file` and the
report types.
"""

from cevm.ingest.pipeline import FileReport, IngestReport, discover, ingest
from cevm.ingest.task import FileOutcome, IngestOptions, process_file

__all__ = ["FileOutcome", "FileReport", "IngestOptions", "IngestReport", "discover", "ingest", "process_file"]
