"""Where the trip store lives, and how a source file is keyed in it.

``--store PATH`` if given, else the environment variable ``CEVM_STORE``, else
``$XDG_DATA_HOME/cevm/cevm.sqlite`` (``~/.local/share/cevm/cevm.sqlite`` when
``XDG_DATA_HOME`` is unset or not absolute, as the XDG spec says). A fixed per-user
location works the same from a shell and from cron, unlike the current directory.
See :func:`default_store_path` and :func:`resolve_store_path`.
"""

from __future__ import annotations

import os
from pathlib import Path

from cevm.errors import CevmError

STORE_ENV_VAR = "CEVM_STORE"


def default_store_path() -> Path:
    """Where the store lives when ``--store`` is not given.

    Returns ``$CEVM_STORE`` if set and non-empty (``~`` expanded), else
    ``$XDG_DATA_HOME/cevm/cevm.sqlite`` if ``XDG_DATA_HOME`` is an absolute path, else
    ``~/.local/share/cevm/cevm.sqlite`` (the XDG default). A per-user fixed location
    works the same from an interactive shell and from cron.
    """
    env = os.environ.get(STORE_ENV_VAR, "").strip()
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_DATA_HOME", "").strip()
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".local" / "share"
    return base / "cevm" / "cevm.sqlite"


def resolve_store_path(store: str | Path | None = None) -> Path:
    """The store path for a ``--store`` option value: ``store`` (``~`` expanded) if
    given, else :func:`default_store_path`."""
    if store is not None and str(store).strip():
        return Path(store).expanduser()
    return default_store_path()


NO_STORE_HINT = "run 'cevm ingest' first or give --store"


def existing_store_path(store: str | Path | None = None, hint: str = NO_STORE_HINT) -> Path:
    """:func:`resolve_store_path`, for commands that read: a missing store is the user's
    error (:class:`CevmError` ending with ``hint``), not a new empty one."""
    path = resolve_store_path(store)
    if not path.exists():
        raise CevmError(f"{path}: no trip store here; {hint}")
    return path


def file_key(path: str | Path) -> str:
    """The key of a source file in the store: its absolute path with symlinks resolved
    (the file need not exist)."""
    return str(Path(path).expanduser().resolve())
