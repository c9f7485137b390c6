"""Reading stage of ``cevm ingest``: logger CSV exports -> canonical log frames.

A logger is described by a *profile* (:mod:`cevm.ingest.profiles`).
:func:`read_log` turns one file into one :class:`ParsedLog` per vehicle: a DataFrame
with canonical columns in SI units (rows in file order; cleaning, sorting and trip
splitting are later stages), the file's metadata, the energy sources available, and a
human-readable list of every repair made while reading. Bad input raises
:class:`cevm.errors.InputError` naming file, line and column.

A file is streamed, never held whole: its bytes, decompressed and decoded in chunks
(:mod:`cevm.ingest.textfile`, within :class:`ReadLimits`), are cut into blocks of whole
lines of about 4 MiB, and each block is parsed on its own into the columns the profile
maps (the others are dropped by the parser), so the memory of reading a file is that of
its canonical columns plus one block; the blocks' pieces are returned to the system once
a column is joined. A column that is in SI as logged and whose every value is exactly a
float32 (binary steps: 1/8 rpm, whole kg, 1/32 degC, a 0/1 switch) is kept as float32,
the same values in half the memory; file lines are int32. Each block is parsed by
pyarrow's CSV reader on one thread, numbers and ISO 8601 times included; a block that
reader refuses (a row with fewer or more fields than the header, a value that is not a
number, mixed time notation, ...) is parsed again by pandas' C parser, which either
repairs what it can (and says so) or raises the error with its line and column.

Everything is vectorised (pyarrow, pandas, numpy); nothing loops over rows in Python.

The package, one module per stage: :mod:`.detection` (the profile), :mod:`.header` (header,
metadata, the columns to read), :mod:`.blocks` (blocks of whole lines), two parse
engines that must agree, :mod:`.engine_arrow` (pyarrow) and :mod:`.engine_pandas`
(pandas, with the byte-level time path of :func:`cevm.ingest.timestamps.fast_first_column`;
``tests/test_reading.py`` runs both on the same bytes), :mod:`.gather` (whole-file columns),
:mod:`.local_time` (times to UTC), :mod:`.canonical` (SI columns, one log per vehicle) and
:mod:`.plausibility`, :mod:`.lines` (byte-level line statistics, messages), driven by
:func:`.reader.read_log`; :mod:`.logs` holds what it returns.

Not handled: quoted fields holding line breaks (line numbers would shift).
"""

from cevm.ingest.reading.detection import detect_profile
from cevm.ingest.reading.logs import EnergySource, ParsedLog
from cevm.ingest.reading.plausibility import PLAUSIBLE_RANGE_SI
from cevm.ingest.reading.reader import read_log
from cevm.ingest.textfile import ReadLimits

__all__ = [
    "PLAUSIBLE_RANGE_SI",
    "EnergySource",
    "ParsedLog",
    "ReadLimits",
    "detect_profile",
    "read_log",
]
