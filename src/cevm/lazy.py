"""pandas, imported on first use (:data:`pd`), for the modules of ingest and the store
that need it only on some paths: reading and cleaning a log need it only for some
formats (two time columns, a vehicle column, value maps, local times, cells pyarrow
refuses) and for callers that pass a DataFrame; the store only for the tables it lists.
Importing pandas costs a process about 0.8 s of CPU and 80 MB: a `cevm ingest` of srf
logs, or a worker that reads them, does not pay that."""

from __future__ import annotations

import importlib
import sys
from typing import Any

__all__ = ["is_pandas", "pd"]


class _Lazy:
    """A module imported on the first attribute asked of it."""

    def __init__(self, name: str) -> None:
        self._name = name

    def __getattr__(self, attr: str) -> Any:
        return getattr(importlib.import_module(self._name), attr)


#: pandas, imported when first used.
pd: Any = _Lazy("pandas")


def is_pandas(x: object, kind: str) -> bool:
    """Whether ``x`` is a pandas ``kind`` (``"DataFrame"``, ``"Series"``), without
    importing pandas (nothing is a DataFrame before pandas is imported)."""
    mod = sys.modules.get("pandas")
    return mod is not None and isinstance(x, getattr(mod, kind))
