""":func:`read_log`: one file, streamed through the stages, to one log per vehicle."""

from __future__ import annotations

from pathlib import Path

from cevm.ingest.profiles import Profile
from cevm.ingest.reading.blocks import Engine, ParsedBlock, ReadRepairs, _data_blocks
from cevm.ingest.reading.canonical import _canonical_columns, _split_vehicles
from cevm.ingest.reading.detection import _open_log
from cevm.ingest.reading.engine_arrow import _arrow_block
from cevm.ingest.reading.gather import ColumnGatherer
from cevm.ingest.reading.header import (
    ColumnPlan,
    _column_finder,
    _column_finder_before_header,
    _plan_columns,
    _read_header,
)
from cevm.ingest.reading.logs import ParsedLog
from cevm.ingest.textfile import ByteStream, ReadLimits, Utf8Stream


def read_log(path: str | Path, profile: Profile | str | None = None,
             profiles: dict[str, Profile] | None = None, *,
             vehicle_id: str | None = None, limits: ReadLimits = ReadLimits(),
             engine: Engine = "pyarrow") -> list[ParsedLog]:
    """Read one logger CSV (plain or gzip-compressed) into one :class:`ParsedLog` per vehicle.

    Parameters
    ----------
    path : the file. Gzip is recognised by its magic bytes, whatever the extension.
    profile : a :class:`Profile`, a profile name (looked up in ``profiles``), or ``None``
        (default) to detect it from the header with :func:`detect_profile`.
    profiles : available profiles (default ``None``: :func:`load_profiles()`).
    vehicle_id : override the vehicle id from the profile (default ``None``: use the
        profile's vehicle source); not allowed for a file split by a vehicle column.
    limits : bounds on the file's size, gzip expansion and rows (:class:`ReadLimits`;
        default: its defaults).
    engine : ``"pyarrow"`` (default) or ``"pandas"``: the CSV parser of each block (see
        the module docstring); the result is the same.

    Returns
    -------
    One ParsedLog per vehicle in order of first appearance in the file.

    Raises
    ------
    InputError : empty file, header only, bad encoding, binary data, missing time
        column, unreadable time or number (with line and column), mixed time zone
        notation, a vehicle id holding a control character, no position and no speed, a
        column mostly absurd, a truncated last line when the profile says
        ``truncated_last_line = "error"``, a file over a limit of ``limits``.

    The stages, each a function of its own: the file's bytes, decompressed, and its
    profile (:func:`_open_log`); the text as UTF-8 (:class:`Utf8Stream`); the header and
    metadata (:func:`_read_header`) and the columns the profile needs from it
    (:func:`_plan_columns`); blocks of data lines (:func:`_data_blocks`) each parsed into
    the used columns (:func:`_parse_block`) and gathered (:class:`ColumnGatherer`: vehicle ids,
    times, value maps, per block); times to UTC (:meth:`ColumnGatherer.utc_ns`); columns mapped
    to canonical SI columns and checked (:func:`_canonical_columns`); one log per vehicle
    (:func:`_split_vehicles`).
    """
    path = Path(path)
    with ByteStream(path, limits) as raw:
        prof = _open_log(path, raw, profile, profiles)
        text = Utf8Stream(raw, prof.encoding, prof.name)
        text.column_of = _column_finder_before_header(prof)
        hdr, metadata, rest = _read_header(text, prof, path)
        plan = _plan_columns(prof, hdr, path)
        text.column_of = _column_finder(plan.names, prof.separator)
        repairs = ReadRepairs()
        gather = ColumnGatherer(plan, prof, path, limits, repairs)
        gather.set_vehicle(vehicle_id, metadata, hdr)
        for first_line, block, last in _data_blocks(text, rest, hdr, plan.names, prof, path, repairs):
            gather.add(_parse_block(block, first_line, plan, prof, path, engine, gather), last)
            del block
    lines = gather.lines()
    codes, vehicles = gather.vehicle_codes()
    utc = gather.utc_ns(codes, lines)
    out = _canonical_columns(gather.pop_columns(), plan.maps, utc, lines, prof, path, repairs.columns)
    return _split_vehicles(out, codes, vehicles, plan.maps, prof, path, metadata, repairs.all())


def _parse_block(block: bytes, first_line: int, plan: ColumnPlan, prof: Profile, path: Path, engine: Engine,
                 gather: ColumnGatherer) -> ParsedBlock:
    """A block of whole lines parsed into the used columns: by pyarrow when it takes the
    block as it is, else by pandas (which repairs, or raises with line and column)."""
    if engine == "pyarrow":
        part = _arrow_block(block, first_line, plan, prof, gather.arrow_time_type(block, plan, prof))
        if part is not None:
            return part
    from cevm.ingest.reading.engine_pandas import _pandas_block  # imports pandas: only for such a block

    return _pandas_block(bytes(block), first_line, plan, prof, path)
