"""A fuzz test of the cycle reader (a cycle file is untrusted input): whatever bytes a cycle file holds (headers
of the names cevm detects and of others, separators, decimal marks, numbers and junk, CR,
LF and CRLF line ends, byte order marks, NUL bytes, gzip), reading it either gives cycles
or raises cevm's own error (:class:`~cevm.errors.CevmError`, one line naming the file):
no other exception (``_csv.Error`` for a CR line end was one), and no warning leaks out of
the libraries it uses (numpy, pandas)."""

from __future__ import annotations

import gzip
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cevm.errors import CevmError
from cevm.io.cycles import CycleFormat, read_cycles

HEADERS = ["time_s", "Time", "t", "speed_kmh", "speed_mps", "Speed [km/h]", "v (m/s)", "speed_mph", "speed",
           "elevation_m", "altitude (ft)", "grade_pct", "Gradient [%]", "road grade", "x", "", "speed_kmh",
           "Long haul, 26t", "\ufeffTime", "time_s\x00"]
SEPS = [",", ";", "\t", "|", " "]
ENDS = ["\n", "\r\n", "\r"]

cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32).map(repr),
    st.integers(-10**6, 10**6).map(str),
    st.decimals(-400, 400, places=3, allow_nan=False).map(str),
    st.decimals(-400, 400, places=2, allow_nan=False).map(lambda d: str(d).replace(".", ",")),
    st.sampled_from(["", " ", "nan", "NaN", "inf", "-", "1e400", "0x10", "1,000.5", '"3"', '"', "\x00", "é", "1.2.3"]),
    st.text(max_size=6),
)


@st.composite
def cycle_files(draw) -> tuple[bytes, CycleFormat | None]:
    sep = draw(st.sampled_from(SEPS))
    end = draw(st.sampled_from(ENDS))
    n_cols = draw(st.integers(1, 5))
    header = [draw(st.sampled_from(HEADERS)) for _ in range(n_cols)]
    n_rows = draw(st.integers(0, 30))
    regular = draw(st.booleans())  # a plausible cycle: times 0, 1, 2, ... and smooth speeds
    rows = []
    for i in range(n_rows):
        if regular and draw(st.integers(0, 9)) > 0:
            row = [str(i)] + [f"{10 + (i % 7) * 0.5:.1f}" for _ in range(n_cols - 1)]
        else:
            row = [draw(cell) for _ in range(draw(st.integers(max(0, n_cols - 1), n_cols + 1)))]
        rows.append(sep.join(row))
    text = end.join([sep.join(header), *rows]) + draw(st.sampled_from(["", end, end + end]))
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig", "cp1252", "utf-16"]))
    try:
        data = text.encode(encoding)
    except UnicodeEncodeError:
        data = text.encode("utf-8")
    if draw(st.booleans()) and data:  # a byte or two broken
        k = draw(st.integers(0, len(data) - 1))
        data = data[:k] + bytes([draw(st.integers(0, 255))]) + data[k + 1:]
    if draw(st.integers(0, 5)) == 0:
        data = gzip.compress(data)
    fmt = draw(st.one_of(st.none(), st.builds(
        CycleFormat, speed_unit=st.sampled_from([None, "km/h", "m/s"]),
        time_step_s=st.sampled_from([None, 1.0]), sep=st.sampled_from([None, ",", ";"]),
        decimal=st.sampled_from([None, ".", ","]))))
    return data, fmt


@pytest.mark.slow
@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(cycle_files())
def test_the_cycle_reader_raises_only_its_own_errors_and_leaks_no_warning(case):
    data, fmt = case
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / ("c.csv.gz" if data[:2] == b"\x1f\x8b" else "c.csv")
        path.write_bytes(data)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                cycles = read_cycles(path, fmt)
            except CevmError as exc:
                text = str(exc)
                assert "\n" not in text and "\r" not in text, text
                assert text.startswith((str(path), "cycle options:")), text  # names the file, or the options
            else:
                for c in cycles:  # what it read is a cycle: finite, time increasing, speeds plausible
                    assert c.time_s.size == c.speed_mps.size >= 2
                    assert np.all(np.isfinite(c.time_s)) and np.all(np.diff(c.time_s) > 0)
                    assert np.all(np.isfinite(c.speed_mps)) and np.all(c.speed_mps >= 0)
        assert [str(w.message) for w in caught] == []
