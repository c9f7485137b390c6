"""A fuzz test of srf ingest (a log is untrusted input): mutated srf logs give a stored result or one of
cevm's own errors (naming the file, and the line and column where there is one), never
another exception, and leak no warning.

The seed log is small (90 rows, two trips' worth of driving); each example applies a few
byte- and line-level mutations that real files suffer (cut, duplicated, swapped or
deleted lines, a field replaced by junk, stray bytes, a truncated end).
"""

from __future__ import annotations

import re
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cevm.ingest.task import IngestOptions, process_file
from test_ingest import write_srf

_JUNK = ["", "ERR", "-", "nan", "inf", "1e309", "-0", "0x1F", "\u00e9", "\x00", "\"", "\"a,b\"", "9" * 30, ";",
         "2019-13-45T99:99:99Z", "1970-01-01T00:00:00Z", " ", "\r", "#", "N/A", "1,5", "+-3", "--"]

_mutation = st.one_of(
    st.tuples(st.just("delete_line"), st.integers(0, 10_000)),
    st.tuples(st.just("duplicate_line"), st.integers(0, 10_000)),
    st.tuples(st.just("swap_lines"), st.integers(0, 10_000)),
    st.tuples(st.just("field"), st.integers(0, 10_000), st.integers(0, 20), st.sampled_from(_JUNK)),
    st.tuples(st.just("insert_bytes"), st.integers(0, 10**6), st.binary(min_size=1, max_size=4)),
    st.tuples(st.just("truncate"), st.integers(0, 10**6)),
)


def _mutate(data: bytes, mutations) -> bytes:
    for m in mutations:
        lines = data.split(b"\n")
        kind = m[0]
        if kind == "delete_line" and len(lines) > 1:
            del lines[m[1] % len(lines)]
        elif kind == "duplicate_line":
            i = m[1] % len(lines)
            lines.insert(i, lines[i])
        elif kind == "swap_lines" and len(lines) > 2:
            i = m[1] % (len(lines) - 1)
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        elif kind == "field":
            i = m[1] % len(lines)
            cells = lines[i].split(b",")
            cells[m[2] % len(cells)] = m[3].encode("utf-8")
            lines[i] = b",".join(cells)
        elif kind == "insert_bytes":
            j = m[1] % (len(data) + 1)
            data = data[:j] + m[2] + data[j:]
            continue
        elif kind == "truncate":
            data = data[: m[1] % (len(data) + 1)]
            continue
        data = b"\n".join(lines)
    return data


_FOREIGN = re.compile(r"internal error|: (?:ValueError|OSError|Error|UnicodeError|UnicodeDecodeError|[A-Za-z]+Error): ")


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                   HealthCheck.too_slow])
@given(st.lists(_mutation, min_size=1, max_size=4))
def test_mutated_srf_logs_give_a_result_or_cevms_own_error(tmp_path, mutations):
    seed = tmp_path / "seed.csv"
    if not seed.exists():
        write_srf(seed, "EB-01", 1_557_820_800, 3, n=90)
    f = tmp_path / "fuzz.csv"
    f.write_bytes(_mutate(seed.read_bytes(), mutations))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning leaking out of ingest fails the example
        out = process_file(f, IngestOptions())
    if out.error is not None:
        assert out.error.startswith(str(f)), out.error  # names the file
        assert not _FOREIGN.search(out.error), out.error  # cevm's own message, not a stray exception
    else:
        assert all(t.n_samples >= 2 for t in out.trips)


def test_a_lost_longitude_header_cell_gives_no_positions_not_an_internal_error(tmp_path):
    """Regression (found by the fuzz test on main): the header's longitude name blanked
    (the header line duplicated, then a field of it emptied) left a latitude column
    without its longitude, and the reader failed with KeyError: 'lon_deg'. The file is
    ingested from its speeds, with a repair note that no positions were read."""
    seed = tmp_path / "seed.csv"
    write_srf(seed, "EB-01", 1_557_820_800, 3, n=90)
    f = tmp_path / "fuzz.csv"
    f.write_bytes(_mutate(seed.read_bytes(), [("duplicate_line", 0), ("field", 100, 16, "")]))
    out = process_file(f, IngestOptions())
    assert out.error is None, out.error
    assert any("without its longitude column: no GPS positions read" in r for r in out.repairs), out.repairs
