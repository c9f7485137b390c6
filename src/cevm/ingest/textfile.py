"""A log file's bytes as UTF-8 text, streamed in bounded pieces, within limits.

The first part of the reading stage (:mod:`cevm.ingest.reading`): no stage ever holds a
whole file. :class:`ByteStream` reads a file in chunks and, when its first bytes are the
gzip magic, decompresses it incrementally (every member of a multi-member file), never
more than a chunk at a time, so a small file that expands to gigabytes is stopped at a
limit instead of being expanded first. :class:`Utf8Stream` decodes those bytes from the
file's text encoding to UTF-8 (validating UTF-8 input as it goes) and refuses NUL bytes.
:func:`cevm.sniff.sniff_bom` names the encoding a byte order mark declares: a BOM decides
the encoding whatever the profile says (a UTF-8 BOM on a cp1252 portal export, UTF-16 from a
spreadsheet's "Unicode text" export).

:class:`ReadLimits` are the bounds, each an option of ``cevm ingest`` and of
:class:`cevm.ingest.IngestOptions`; :data:`MAX_LINE_BYTES` is fixed. Every violation is
an :class:`~cevm.errors.InputError` naming the file (and line where there is one) and
the option that would allow it.
"""

from __future__ import annotations

import codecs
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cevm.errors import InputError
from cevm.sniff import GZIP_MAGIC, ascii_transparent, sniff_bom, utf16_hint

# sniff_bom and utf16_hint (cevm.sniff, the text-sniffing rules of every text input) are
# named here too: the reader's callers take them from here
__all__ = ["MAX_LINE_BYTES", "ByteStream", "ReadLimits", "Utf8Stream", "count_newlines", "sniff_bom", "utf16_hint"]

#: Bytes compared at a time by :func:`count_newlines` (its temporary: one bool a byte).
_COUNT_BYTES = 1 << 18


def count_newlines(data: bytes | memoryview, start: int = 0, end: int | None = None) -> int:
    """Line breaks (``\\n`` bytes) in ``data[start:end]``: ``data.count(b"\\n", start, end)``,
    counted by numpy 256 kB at a time (about 4x faster than ``bytes.count``, which
    searches for a one-byte pattern byte by byte; every byte of a log is counted two
    or three times on its way through the reader)."""
    buf = np.frombuffer(data, np.uint8)
    end = buf.size if end is None else min(end, buf.size)
    n = 0
    for a in range(start, end, _COUNT_BYTES):
        n += int(np.count_nonzero(buf[a:min(a + _COUNT_BYTES, end)] == 10))
    return n

#: Raw bytes read from the file at a time; also the most one decompression call yields.
CHUNK_BYTES = 1 << 20

#: The longest line a log may have [bytes]: a longer one (a file without line breaks) is
#: not a CSV log. 1 MiB holds a header of 20,000 columns.
MAX_LINE_BYTES = 1 << 20


#: Default bound on a log's values (data rows x columns read, time included): 36 M keeps a
#: worker under 500 MB for a wide log (1.8 M rows of 20 columns), and lets a 16-column srf
#: log reach 2.25 M rows.
MAX_VALUES = 36_000_000

#: Default bound on the trip samples a file gives (on the 1 s grid): 6 M (about 100 days
#: of a bus's driving) keeps a worker under 500 MB with its stored trips held until
#: written (``python benchmarks/bench_memory.py``).
MAX_SAMPLES = 6_000_000


@dataclass(frozen=True)
class ReadLimits:
    """Bounds on one log file, so that memory and time stay bounded whatever the input.

    Parameters
    ----------
    max_file_mb : the most text a file may hold [MB = 10^6 bytes], after decompression
        (default 1000: about 10 million rows of a typical srf log; the row limit comes
        first for ordinary rows). A plain file larger than this on disk is refused before
        it is read.
    max_expansion : the most a gzip file may expand (decompressed bytes per compressed
        byte, default 100; logger CSVs compress 3-20 times); checked once more than
        :data:`EXPANSION_FLOOR_BYTES` are decompressed, so that small files never trip it.
        A gzip bomb is stopped after its first 32 MB.
    max_rows : the most data rows a file may hold (default 2,500,000: a 2 M-row log, 23
        days of 1 Hz logging in one file, still ingests).
    max_values : the most values (data rows x the columns the profile reads, time
        included) a file may hold, or None for no such bound (default
        :data:`MAX_VALUES`). With ``max_rows`` this bounds a worker's memory whatever the
        input: the peak grows with a file's rows and its columns (``python
        benchmarks/bench_memory.py``: 0.42 GB at 2 M rows of a 16-column srf log, 0.47 GB
        at 2.5 M; 0.51 GB at 2 M rows of a 20-column one, 0.59 GB at 2.5 M), and the
        values bound keeps a wide log under 500 MB (1.8 M rows of 20 columns). The
        command line lifts it when ``--max-rows`` is given.
    max_samples : the most trip samples (on the cleaning's 1 s grid) the trips of a file
        may hold, or None for no bound (default :data:`MAX_SAMPLES`). A worker holds a
        file's stored trips until they are written (profiles, vectors: about 25 bytes a
        sample), and a log that ticks every 5 s, as telematics portals do, gives five
        samples a row: a 2.5 M-row portal export makes 12 M samples and 0.79 GB. Checked
        once the trips are cut, before any is made.
    """

    max_file_mb: float = 1000.0
    max_expansion: float = 100.0
    max_rows: int = 2_500_000
    max_values: int | None = MAX_VALUES
    max_samples: int | None = MAX_SAMPLES

    def __post_init__(self) -> None:
        if not (self.max_file_mb > 0 and self.max_expansion >= 1 and self.max_rows >= 1
                and (self.max_values is None or self.max_values >= 1)
                and (self.max_samples is None or self.max_samples >= 1)):
            raise ValueError(f"read limits must be positive (expansion at least 1): {self}")

    def row_limit(self, n_columns: int) -> int:
        """The most data rows of a file whose profile reads ``n_columns`` columns."""
        if self.max_values is None:
            return self.max_rows
        return max(1, min(self.max_rows, self.max_values // max(1, n_columns)))

    @property
    def max_file_bytes(self) -> int:
        return int(self.max_file_mb * 1e6)


def mb(n_bytes: int) -> str:
    """A size in MB (10^6 bytes) for messages: 3 significant digits, thousands
    separated."""
    x = n_bytes / 1e6
    return f"{x:,.0f}" if x >= 100 else f"{x:.3g}"


#: Decompressed bytes after which the expansion limit applies.
EXPANSION_FLOOR_BYTES = 32 << 20



class ByteStream:
    """A file's bytes, gunzipped if its first two bytes are the gzip magic, in chunks of
    at most :data:`CHUNK_BYTES`, counted against ``limits``.

    ``read()`` returns the next chunk (``b""`` at the end); ``peek(n)`` the first ``n``
    bytes without consuming them. Use as a context manager (closes the file).
    """

    def __init__(self, path: Path, limits: ReadLimits) -> None:
        self.path = path
        self.limits = limits
        try:
            self._fh = open(path, "rb")  # noqa: SIM115 (held by the reader, closed by its close())
            self.size_on_disk = os.fstat(self._fh.fileno()).st_size
            self.gzip = self._fh.read(2) == GZIP_MAGIC
            self._fh.seek(0)
        except OSError as exc:
            raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None
        self._z = zlib.decompressobj(31) if self.gzip else None
        self._zin = b""  # compressed bytes read and not yet decompressed
        self._pushed: list[bytes] = []
        self.bytes_in = 0  # raw bytes read from the file
        self.bytes_out = 0  # bytes returned (decompressed)

    def __enter__(self) -> ByteStream:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._fh.close()

    def check_size(self) -> None:
        """Refuse a plain file larger than ``max_file_mb`` before reading it."""
        if not self.gzip and self.size_on_disk > self.limits.max_file_bytes:
            raise InputError(self.path, f"file of {mb(self.size_on_disk)} MB: more than the limit of "
                                        f"{self.limits.max_file_mb:g} MB per file (--max-file-mb)")

    def peek(self, n: int) -> bytes:
        """The next ``n`` bytes (fewer at the end), left to be read again."""
        got, size = [], 0
        while size < n:
            chunk = self.read()
            if not chunk:
                break
            got.append(chunk)
            size += len(chunk)
        data = b"".join(got)
        if data:
            self._pushed.append(data)
        return data[:n]

    def read(self) -> bytes:
        if self._pushed:
            return self._pushed.pop()
        try:
            data = self._read_gzip() if self.gzip else self._read_plain()
        except OSError as exc:
            raise InputError(self.path, f"cannot read file: {exc.strerror or exc}") from None
        if data:
            self._count(len(data))
        return data

    def _read_plain(self) -> bytes:
        data = self._fh.read(CHUNK_BYTES)
        self.bytes_in += len(data)
        return data

    def _read_gzip(self) -> bytes:
        z = self._z
        assert z is not None  # a gzip file's decompressor
        try:
            while True:
                if z.eof:  # a member ended: another may follow (zero padding is allowed)
                    rest = z.unused_data or self._raw_chunk()
                    while rest and not rest.strip(b"\x00"):
                        rest = self._raw_chunk()
                    rest = rest.lstrip(b"\x00")
                    if not rest:
                        return b""
                    if not rest.startswith(GZIP_MAGIC[: len(rest)]):
                        raise InputError(self.path, "corrupt gzip data: trailing bytes after the compressed data")
                    z = self._z = zlib.decompressobj(31)
                    self._zin = rest
                if not self._zin:
                    self._zin = self._raw_chunk()
                    if not self._zin:
                        raise InputError(self.path, "corrupt gzip data: the file ends inside the compressed stream")
                out = z.decompress(self._zin, CHUNK_BYTES)
                self._zin = z.unconsumed_tail
                if out:
                    return out
        except zlib.error as exc:
            raise InputError(self.path, f"corrupt gzip data: {exc}") from None

    def _raw_chunk(self) -> bytes:
        data = self._fh.read(CHUNK_BYTES)
        self.bytes_in += len(data)
        return data

    def _count(self, n: int) -> None:
        self.bytes_out += n
        lim = self.limits
        if self.bytes_out > lim.max_file_bytes:
            what = "decompresses to" if self.gzip else "holds"
            raise InputError(self.path, f"file {what} more than the limit of {lim.max_file_mb:g} MB of text per "
                                        f"file (--max-file-mb)")
        if not self.gzip or self.bytes_out <= EXPANSION_FLOOR_BYTES:
            return
        z = self._z  # a gzip file's: not None here
        pending = len(z.unused_data) if z is not None and z.eof else len(self._zin)  # read, not yet decompressed
        consumed = self.bytes_in - pending
        if self.bytes_out > lim.max_expansion * max(consumed, 1):
            raise InputError(self.path, f"gzip data expands more than {lim.max_expansion:g} times "
                                        f"({mb(self.bytes_out)} MB from {mb(consumed)} MB so far): "
                                        "refused as a likely zip bomb; if the file is genuine, raise the limit "
                                        "(--max-expansion)")


_UTF8_NAMES = {"utf-8", "utf8", "utf-8-sig", "u8"}
_ASCII_NAMES = {"ascii", "us-ascii"}


class Utf8Stream:
    """The text of a :class:`ByteStream` as UTF-8 bytes, chunk by chunk.

    ``encoding``: the profile's (a BOM at the start overrides it; the BOM itself is
    dropped). UTF-8 and ASCII input is validated and passed through; any other encoding
    is decoded incrementally and re-encoded. A byte that does not decode, or a NUL byte
    (binary data), raises :class:`~cevm.errors.InputError` with its line; with
    ``column_of(line_bytes)`` set (by the reader, once it knows the header) the error
    names the column too: it is called with the UTF-8 text before the error's line in
    the current chunk (where the header may be) and the raw bytes of that line before
    the bad byte.
    """

    def __init__(self, raw: ByteStream, encoding: str, profile_name: str) -> None:
        self.raw = raw
        self.path = raw.path
        self.profile_name = profile_name
        bom = sniff_bom(raw.peek(4))
        self._skip = 0
        if bom is not None:
            encoding, self._skip = bom
        self.encoding = encoding
        enc = codecs.lookup(encoding).name
        self._utf8 = enc in ("utf-8", "utf-8-sig") or encoding.lower() in _UTF8_NAMES
        self._ascii = enc == "ascii" or encoding.lower() in _ASCII_NAMES
        self._ascii_compatible = self._utf8 or self._ascii or ascii_transparent(encoding)
        self._dec = codecs.getincrementaldecoder("ascii" if self._ascii else "utf-8" if self._utf8
                                                 else encoding)(errors="strict")
        self.lines_done = 0  # line breaks in the text returned so far
        self._carry = b""  # the start of a UTF-8 sequence cut at the end of a chunk
        self._tail = b""  # raw bytes of the current (unfinished) line, for error columns
        self.column_of = None  # callable(text before the line, line's bytes before the error) -> column
        self._done = False

    def read(self) -> bytes:
        """The next chunk of UTF-8 text (``b""`` at the end)."""
        while not self._done:
            chunk = self.raw.read()
            if self._skip:
                chunk, self._skip = chunk[self._skip:], 0
            final = not chunk
            self._done = final
            out = self._decode(chunk, final)
            if out:
                nul = out.find(b"\x00")
                if nul >= 0:
                    raise InputError(self.path, "binary data (NUL byte), not a CSV text file" + utf16_hint(out),
                                     line=self.lines_done + count_newlines(out, 0, nul) + 1)
                self.lines_done += count_newlines(out)
                return out
        return b""

    def _decode(self, chunk: bytes, final: bool) -> bytes:
        data = self._carry + chunk if self._carry else chunk
        self._carry = b""
        try:
            if self._utf8 or self._ascii:  # validate, pass the bytes through
                if data.isascii():  # a fast scan
                    out = data
                elif self._ascii:
                    data.decode("ascii")  # raises
                    out = data
                else:
                    _, used = codecs.utf_8_decode(data, "strict", final)
                    out, self._carry = data[:used], data[used:]  # a sequence cut by the chunk waits
            elif self._ascii_compatible and data.isascii() and not self._dec.getstate()[0]:
                out = data  # what decoding and re-encoding as UTF-8 would give
            else:
                out = self._dec.decode(data, final).encode("utf-8")
        except UnicodeDecodeError as exc:
            raise self._decode_error(exc) from None
        if self._ascii_compatible:
            done = data[: len(data) - len(self._carry)]
            nl = done.rfind(b"\n")
            self._tail = done[nl + 1:] if nl >= 0 else (self._tail + done)[-MAX_LINE_BYTES:]
        return out

    def _decode_error(self, exc: UnicodeDecodeError) -> InputError:
        data, start = exc.object, exc.start
        column = None
        if self._ascii_compatible:
            line = self.lines_done + data.count(b"\n", 0, start) + 1
            ls = data.rfind(b"\n", 0, start) + 1
            line_bytes = (self._tail if ls == 0 else b"") + data[ls:start]
            if self.column_of is not None:
                before = data[:ls].decode(self.encoding, errors="replace").encode("utf-8")
                column = self.column_of(before, line_bytes)
        else:
            line = self.lines_done + data[:start].decode(self.encoding, errors="replace").count("\n") + 1
        return InputError(
            self.path,
            f"byte 0x{data[start]:02x} is not valid {self.encoding} text (binary data, or a file in "
            f"another encoding: check csv.encoding of profile {self.profile_name!r})",
            line=line,
            column=column,
        )
