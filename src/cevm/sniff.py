"""What the first bytes of a text input say about it (pure, no I/O): the one set of
text-sniffing rules of every text file cevm reads, logger logs (:mod:`cevm.ingest`)
as well as cycle files and manifests (:mod:`cevm.io`).

- :data:`GZIP_MAGIC`: a gzip file, whatever its name;
- :func:`sniff_bom`: the encoding a byte order mark declares (a BOM is what a text's
  writer says its encoding is, so it wins over any encoding configured for the file);
- :func:`looks_binary`: a NUL, or more than 1 % control bytes: an image, a spreadsheet,
  random junk, whatever the text encoding would be;
- :func:`utf16_without_bom`, :func:`utf16_hint`: UTF-16 text without a byte order mark
  (every other byte NUL), named in the message that refuses it as binary;
- :func:`not_text_reason`: the reason a reader of UTF-8 (or cp1252) text refuses the
  bytes, or None;
- :func:`ascii_transparent`: whether an encoding leaves ASCII text as it is.
"""

from __future__ import annotations

import codecs
from functools import lru_cache

__all__ = ["GZIP_MAGIC", "ascii_transparent", "looks_binary", "not_text_reason", "sniff_bom", "utf16_hint",
           "utf16_without_bom"]

#: The first two bytes of every gzip member.
GZIP_MAGIC = b"\x1f\x8b"

#: Byte order marks and the encodings they declare (UTF-32 before UTF-16: FF FE 00 00
#: starts with the UTF-16 LE mark).
_BOMS = (
    (codecs.BOM_UTF8, "utf-8"),
    (codecs.BOM_UTF32_LE, "utf-32-le"),
    (codecs.BOM_UTF32_BE, "utf-32-be"),
    (codecs.BOM_UTF16_LE, "utf-16-le"),
    (codecs.BOM_UTF16_BE, "utf-16-be"),
)

#: Bytes that never occur in a text CSV: C0 controls other than tab, LF, CR; and DEL.
_BINARY_BYTES = bytes(b for b in range(32) if b not in (9, 10, 13)) + b"\x7f"


def sniff_bom(head: bytes) -> tuple[str, int] | None:
    """(encoding, length of the mark) of the byte order mark ``head`` starts with, if
    any."""
    for bom, enc in _BOMS:
        if head.startswith(bom):
            return enc, len(bom)
    return None


def looks_binary(head: bytes) -> bool:
    """True when the first bytes (8 kB looked at) hold a NUL, or more than 1 % control
    bytes."""
    sample = head[:8192]
    if b"\x00" in sample:
        return True
    n_ctrl = len(sample) - len(sample.translate(None, _BINARY_BYTES))
    return n_ctrl > 0.01 * len(sample)


def utf16_without_bom(data: bytes) -> str | None:
    """"utf-16-le" or "utf-16-be" when ``data`` looks like UTF-16 text without a byte
    order mark (every other byte NUL, the others not), else None."""
    sample = data[:4096]
    if len(sample) < 16:
        return None
    even, odd = sample[0::2], sample[1::2]
    for zeros, enc in ((odd, "utf-16-le"), (even, "utf-16-be")):
        other = even if zeros is odd else odd
        if zeros.count(0) > 0.9 * len(zeros) and other.count(0) < 0.1 * len(other):
            return enc
    return None


def utf16_hint(data: bytes) -> str:
    """A logger log's hint for a message about binary data when ``data`` looks like
    UTF-16 text without a byte order mark (:func:`utf16_without_bom`), else ``""``."""
    enc = utf16_without_bom(data)
    if enc is None:
        return ""
    return f" (it looks like {enc.upper()} text without a byte order mark: set csv.encoding = {enc!r})"


def not_text_reason(head: bytes, what: str) -> str | None:
    """Why a reader of 8-bit text (UTF-8, or cp1252 for a header) refuses the first
    bytes ``head`` of a ``what`` ("cycle file"), or None: UTF-16 or UTF-32 text (by its
    byte order mark: to be saved as UTF-8), or binary data (:func:`looks_binary`)."""
    bom = sniff_bom(head)
    if bom is not None and bom[0] != "utf-8":
        return f"{bom[0].upper()} text (its byte order mark says so): save the {what} as UTF-8"
    if looks_binary(head):
        enc = utf16_without_bom(head)
        hint = f" (it looks like {enc.upper()} text without a byte order mark: save it as UTF-8)" if enc else ""
        return f"binary data, not a {what} (CSV text){hint}"
    return None


@lru_cache(maxsize=64)
def ascii_transparent(encoding: str) -> bool:
    """Whether ``encoding`` decodes every ASCII byte to that character (utf-8, cp1252,
    latin-1, ...; not utf-16 or utf-7), so that ASCII text needs no re-encoding."""
    try:
        return bytes(range(128)).decode(encoding) == "".join(map(chr, range(128)))
    except (UnicodeDecodeError, LookupError):
        return False
