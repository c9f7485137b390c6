"""Reading TOML files, with errors that name the file, the line and what it should be."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from cevm.errors import InputError


def read_toml(path: str | Path, what: str = "file") -> dict:
    """Parse a TOML file; errors name the file, the line and what the file should be."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except IsADirectoryError:
        raise InputError(path, f"is a directory, not a {what}") from None
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        # Python 3.11's message ends "(at line L, column C)"; newer ones also set lineno.
        found = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        line = getattr(exc, "lineno", None) or (int(found.group(1)) if found else None)
        msg = getattr(exc, "msg", None) or str(exc)
        raise InputError(path, f"not valid TOML: {msg}", line=line) from None
