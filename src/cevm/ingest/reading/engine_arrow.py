"""The pyarrow parse engine: a block read by pyarrow's CSV reader on one thread, numbers
and ISO 8601 times typed by it; ``None`` for a block it refuses (the pandas engine,
:mod:`.engine_pandas`, then parses it, and must agree with it on every block both take)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from cevm.ingest.profiles import Profile
from cevm.ingest.reading.blocks import _NUMERIC_NA, ParsedBlock, _drop_empty_rows
from cevm.ingest.reading.header import ColumnPlan
from cevm.ingest.textfile import count_newlines
from cevm.ingest.timestamps import NAT


@lru_cache(maxsize=1)
def _arrow():
    """pyarrow's csv and compute modules (imported on first use; pandas imports pyarrow
    anyway where it is installed)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    return pa, pc, pacsv


def _arrow_block(block: bytes, first_line: int, plan: ColumnPlan, prof: Profile,
                 time_type) -> ParsedBlock | None:
    """The block parsed by pyarrow's CSV reader (one thread): numeric columns as
    float64, the single ISO 8601 time column as a timestamp (``time_type``), other text
    as strings; ``None`` where pyarrow refuses the block (a row with more or fewer
    fields, a value it cannot convert) or its rows do not match the lines."""
    pa, pc, pacsv = _arrow()
    if isinstance(block, memoryview):  # a block ending with a line break (blocks._data_blocks)
        n_lines = count_newlines(block.obj, 0, len(block))
    else:
        n_lines = count_newlines(block) + (0 if block.endswith(b"\n") else 1)
    types = {c: pa.float64() for c in plan.num_cols}
    types.update({c: pa.string() for c in plan.text_cols})
    tcol = prof.time.columns[0] if len(prof.time.columns) == 1 else None
    if time_type is not None and tcol is not None:  # time_type: the single ISO 8601 time column's
        types[tcol] = time_type
    try:
        tbl = pacsv.read_csv(
            pa.py_buffer(block), memory_pool=pa.system_memory_pool(),
            read_options=pacsv.ReadOptions(use_threads=False, column_names=plan.unique_names,
                                           block_size=max(len(block) + 1, 1 << 16)),
            parse_options=pacsv.ParseOptions(delimiter=prof.separator, quote_char='"', double_quote=True,
                                             newlines_in_values=False, ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types=types, include_columns=plan.used,
                                                 null_values=_NUMERIC_NA, strings_can_be_null=False,
                                                 decimal_point=prof.decimal),
        )
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return None
    if tbl.num_rows != n_lines:
        return None
    has_value = np.zeros(n_lines, bool)
    numbers: dict[str, np.ndarray] = {}
    for c in plan.num_cols:
        x = _arrow_values(tbl.column(c), np.float64, np.nan)
        numbers[c] = x
        has_value |= ~np.isnan(x)
    text: dict[str, np.ndarray] = {}
    time_ns = None
    for c in plan.text_cols:
        col = tbl.column(c)
        if c == tcol and time_type is not None:
            time_ns = _arrow_values(col, np.int64, NAT)  # timestamps are int64 ns
            has_value |= time_ns != NAT
            continue
        col = pc.if_else(pc.equal(col, ""), pa.scalar(None, pa.string()), col)
        valid = col.is_valid().to_numpy(zero_copy_only=False)
        has_value |= valid
        vals = col.to_numpy(zero_copy_only=False)
        vals[~valid] = np.nan  # None -> NaN, as pandas gives
        text[c] = vals
    del tbl
    lines = first_line + np.arange(n_lines, dtype=np.int64)
    part = ParsedBlock(lines, numbers, text, time_ns, time_type is not None and time_type.tz is not None,
                 last_line=first_line + n_lines - 1)
    return _drop_empty_rows(part, ~has_value)


def _arrow_values(col, dtype, null) -> np.ndarray:
    """A pyarrow column of fixed-width values as a numpy array of its own (``null``
    where a value is missing). Copied from pyarrow's buffers here rather than by
    ``to_numpy``, which allocates in pyarrow's pool: memory that pool keeps after a
    block would add up to a second copy of the columns."""
    out = np.empty(len(col), dtype)
    pos = 0
    for ch in col.chunks:
        n = len(ch)
        validity, data = ch.buffers()[:2]
        seg = out[pos:pos + n]
        if data is None or ch.null_count == n:
            seg[:] = null
        else:
            seg[:] = np.frombuffer(data, dtype, count=n, offset=ch.offset * out.itemsize)
            if ch.null_count:
                bits = np.unpackbits(np.frombuffer(validity, np.uint8), bitorder="little")[ch.offset:ch.offset + n]
                seg[bits == 0] = null
        pos += n
    return out
