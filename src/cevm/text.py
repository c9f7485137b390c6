"""Text that cannot forge output: control characters escaped (pure, no I/O).

Ids and file names come from users' files (a logger's vehicle id, a file name holding a
newline or a carriage return). Printed as they are, they can forge a second line of an
error message, break a CSV record or a table. :func:`printable` escapes every character
Python does not call printable (C0 and C1 controls, DEL, line and paragraph separators,
bidirectional and other format characters) as ``\\n``, ``\\r``, ``\\t``, ``\\xNN``,
``\\uNNNN`` or ``\\UNNNNNNNN``; a backslash itself is kept, so escaping twice changes
nothing. Every table, CSV and plain line cevm prints goes through it; JSON output escapes
control characters by its own rules (``\\u000d``), so a JSON reader gets the exact value.

:func:`csv_safe` is what a text cell of cevm's CSV output holds: :func:`printable`, and
neutralised against spreadsheet formulas (OWASP's "CSV injection"): a text that starts
with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return (:data:`FORMULA_PREFIXES`)
gets a leading apostrophe (``'=HYPERLINK(...)``, ``'-EB-07``), which a spreadsheet shows
as the text itself and never evaluates. Numbers are never touched: number cells are
written as numbers, and a text that is a plain number (``-3.5``, ``+2``, ``-1e-3``: no
formula can be one) is kept as it is.
"""

from __future__ import annotations

import re

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(ch: str) -> str:
    named = _NAMED.get(ch)
    if named is not None:
        return named
    code = ord(ch)
    if code < 0x100:
        return f"\\x{code:02x}"
    if code < 0x10000:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def printable(text: str) -> str:
    """``text`` with every non-printable character escaped (see the module notes)."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else _escape(ch) for ch in text)


#: First characters that make a spreadsheet (Excel, LibreOffice, Google Sheets) read a cell
#: as a formula or a command (OWASP, "CSV Injection").
FORMULA_PREFIXES = ("=", "+", "-", "@", "\t", "\r")

_PLAIN_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def csv_safe(text: str) -> str:
    """A text cell of CSV output: :func:`printable`, with a leading apostrophe when it
    would start with one of :data:`FORMULA_PREFIXES` and is not a plain number (see the
    module notes)."""
    text = printable(text)
    if text.startswith(FORMULA_PREFIXES) and not _PLAIN_NUMBER.fullmatch(text):
        return "'" + text
    return text


#: The most characters of one piece of a user's text (a cell, a header name, a comment,
#: a key) quoted in a message: a 2 MB comment must not make a 2 MB error line.
QUOTE_CHARS = 200

#: The most characters of one line of cevm's own messages (errors, warnings, notes):
#: what a message still holds beyond this (a long list, a path quoted in full) is left
#: out in the middle, so that its start (what and where) and end (the remedy) stay.
LINE_CHARS = 2000


def shorten(text: str, limit: int = QUOTE_CHARS) -> str:
    """``text`` cut to its first ``limit`` characters, with ``...`` and the length it had
    when it was longer: what a message quotes of a user's text."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text):,} characters)"


def one_line(text: str, limit: int = LINE_CHARS) -> str:
    """A message as one bounded printable line: :func:`printable`, and when longer than
    ``limit`` characters its middle left out (its start and end kept, and how many
    characters were left out)."""
    text = printable(text)
    if len(text) <= limit:
        return text
    head, tail = limit * 2 // 3, limit // 3
    return f"{text[:head]} ... ({len(text) - head - tail:,} characters left out) ... {text[-tail:]}"


def iso_time(t_s: float, tz=None) -> str:
    """A time [s since the Unix epoch] in the one ISO 8601 form every cevm output writes:
    to the second, ``2019-01-31T07:00:00Z`` in UTC (``tz`` None or UTC), with its offset
    in another zone ``tz`` (a :class:`datetime.tzinfo`: ``2019-01-31T16:00:00+09:00``), as
    the trips list, the store and a calibrated file write them."""
    import datetime as dt

    when = dt.datetime.fromtimestamp(round(float(t_s)), dt.UTC)
    if tz is None or tz is dt.UTC:
        return when.strftime("%Y-%m-%dT%H:%M:%SZ")
    return when.astimezone(tz).isoformat(timespec="seconds")
