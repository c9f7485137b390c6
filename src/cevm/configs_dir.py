"""Where the project's shipped configuration files are: ``configs/`` (logger profiles,
vehicles, cycles, fleet scenarios).

In a source checkout (and an editable install) they are the repository's ``configs/``;
an installed wheel carries the same files as the package data ``cevm/configs``
(pyproject.toml maps one onto the other).
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent / "configs"
_CHECKOUT = Path(__file__).resolve().parents[2] / "configs"


def shipped_configs_dir() -> Path:
    """The directory of the shipped ``configs``: the installed package data if present,
    else the source checkout's (which need not exist: callers check what they need)."""
    return _PACKAGE if _PACKAGE.is_dir() else _CHECKOUT
