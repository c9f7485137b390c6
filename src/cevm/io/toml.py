"""Reading TOML files, with errors that name the file, the line and what it should be.

A TOML file (a vehicle file, a logger profile, a fleet scenario) is read only if it is a
regular file of at most :data:`~cevm.io.inputs.MAX_TOML_BYTES` (1 MiB, refused from its
size before it is read: :mod:`cevm.io.inputs`), and its tables and arrays may nest at
most as deep as Python's parser recurses (a few hundred levels, measured 330 to 500 for
arrays; no cevm file nests more than 3): a deeper one is refused with one line instead of
a RecursionError.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from cevm.errors import InputError
from cevm.io.inputs import MAX_TOML_BYTES, read_bounded


def read_toml(path: str | Path, what: str = "file") -> dict:
    """Parse a TOML file; errors name the file, the line and what the file should be."""
    path = Path(path)
    data = read_bounded(path, MAX_TOML_BYTES, what)
    try:
        text = data.decode("utf-8-sig")  # a byte order mark (a Windows editor's) is not TOML: dropped
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    return parse_toml(text, path)


def parse_toml(text: str, path: str | Path) -> dict:
    """Parse TOML ``text`` read from ``path`` (named in the errors)."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        # Python 3.11's message ends "(at line L, column C)"; newer ones also set lineno.
        found = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        line = getattr(exc, "lineno", None) or (int(found.group(1)) if found else None)
        msg = getattr(exc, "msg", None) or str(exc)
        raise InputError(path, f"not valid TOML: {msg}", line=line) from None
    except RecursionError:
        raise InputError(path, "not a usable TOML file: its arrays or tables nest too deeply (cevm's files nest "
                               "3 levels)") from None
