"""count_newlines (the reader's line counting) against bytes.count, the reference."""

from hypothesis import given, settings
from hypothesis import strategies as st

from cevm.ingest import textfile
from cevm.ingest.textfile import count_newlines


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=3000), st.integers(0, 3100), st.integers(0, 3100))
def test_count_newlines_is_bytes_count(data, a, b):
    data = data.replace(b"\x00", b"\n")  # more line breaks than random bytes give
    assert count_newlines(data) == data.count(b"\n")
    assert count_newlines(data, a) == data.count(b"\n", a)
    assert count_newlines(data, a, b) == data.count(b"\n", a, b)
    assert count_newlines(memoryview(data), a, b) == data.count(b"\n", a, b)


def test_count_newlines_across_its_chunks(monkeypatch):
    """A count over many of its chunks (made small here) and ranges cutting them."""
    monkeypatch.setattr(textfile, "_COUNT_BYTES", 7)
    data = b"a\nbb\n\n" * 50 + b"\n"
    for a, b in ((0, None), (3, 250), (13, 14), (100, 99), (0, 10_000)):
        assert count_newlines(data, a, b) == data.count(b"\n", a, b if b is not None else len(data))
