"""Compare two trip stores row for row and blob for blob, and two ingests' outputs.

    python benchmarks/compare_stores.py A B [--tolerance X] [--ignore-bytes]

``A`` and ``B`` are two stores (``.sqlite`` files), or two folders of
``benchmarks/golden_corpus.py`` (each case's store, ``.stdout``, ``.stderr`` and
``.rc``, matched by name). Prints every difference and exits 1 if there is any.

Compared:

- ``files``: every column but ``mtime_s`` and ``ingested_utc_s`` (when it ran), by path;
- ``trips``: every column, by ``trip_id``; ``quality_json`` parsed and compared key by
  key (so a difference names its key);
- ``trip_blobs``: the vector decoded (every scalar and the non-simplified step arrays)
  and the profile decoded (every array), then the bytes themselves (a different encoding
  of the same values is one line, unless ``--ignore-bytes``);
- ``trip_masses`` (without ``set_utc_s``), ``routes``/``route_legs`` (without times),
  ``meta`` (without ``created_utc_s``), and the table list of the schema;
- the ``--log-json`` lines (without the timings ``seconds`` and ``stage_s``; ``repairs``
  line by line), stderr (line by line) and the exit code.

Floats are compared exactly unless ``--tolerance`` (relative) is given; an array's
difference is reported with its largest absolute and relative change and the first
index where it differs.
"""

from __future__ import annotations

import argparse
import json
import math
import sqlite3
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cevm.core.cycle import CycleVector
from cevm.store.codec import decode_profile

_VOLATILE = {"files": {"mtime_s", "ingested_utc_s"}, "trip_masses": {"set_utc_s"}, "routes": {"created_utc_s"}}
_VECTOR_SCALARS = ("s_me", "s_a", "s_r", "stand_x", "cr0", "duration_s", "distance_m", "idle_s", "n_samples",
                   "k_pos", "traction_s")
_VECTOR_ARRAYS = ("ns_x", "ns_a", "ns_r")


class Diff:
    def __init__(self, tolerance: float) -> None:
        self.tolerance = tolerance
        self.lines: list[str] = []

    def add(self, where: str, what: str) -> None:
        self.lines.append(f"{where}: {what}")

    def value(self, where: str, a, b) -> None:
        if isinstance(a, float) and isinstance(b, float):
            if (math.isnan(a) and math.isnan(b)) or a == b:
                return
            if self.tolerance and abs(a - b) <= self.tolerance * max(abs(a), abs(b)):
                return
            self.add(where, f"{a!r} -> {b!r} (change {b - a:+.3g})")
        elif isinstance(a, dict) and isinstance(b, dict):
            for k in sorted(set(a) | set(b), key=str):
                if k not in a:
                    self.add(f"{where}.{k}", f"new: {b[k]!r}")
                elif k not in b:
                    self.add(f"{where}.{k}", f"gone (was {a[k]!r})")
                else:
                    self.value(f"{where}.{k}", a[k], b[k])
        elif isinstance(a, list) and isinstance(b, list):
            if len(a) != len(b):
                self.add(where, f"{len(a)} items -> {len(b)}: {a!r} -> {b!r}"[:2000])
            else:
                for i, (x, y) in enumerate(zip(a, b, strict=True)):
                    self.value(f"{where}[{i}]", x, y)
        elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
            self.value(where, float(a), float(b)) if a != b else None
        elif a != b:
            self.add(where, f"{a!r} -> {b!r}"[:2000])

    def array(self, where: str, a: np.ndarray, b: np.ndarray) -> None:
        if a.shape != b.shape:
            self.add(where, f"shape {a.shape} -> {b.shape}")
            return
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        if self.tolerance:
            with np.errstate(invalid="ignore"):
                same |= np.abs(a - b) <= self.tolerance * np.maximum(np.abs(a), np.abs(b))
        if same.all():
            return
        i = int(np.flatnonzero(~same)[0])
        with np.errstate(invalid="ignore"):
            d = np.abs(a - b)[~same]
            rel = d / np.maximum(np.abs(a[~same]), 1e-300)
        self.add(where, f"{int((~same).sum())} of {a.size} values differ, first at [{i}] {a[i]!r} -> {b[i]!r}, "
                        f"largest change {np.nanmax(d) if d.size else 0:.3g} (relative {np.nanmax(rel):.3g})")


def _rows(con: sqlite3.Connection, table: str, key: str) -> dict:
    cur = con.execute(f"SELECT * FROM {table}")
    names = [c[0] for c in cur.description]
    return {row[names.index(key)]: dict(zip(names, row, strict=True)) for row in cur}


def _tables(con: sqlite3.Connection) -> set[str]:
    return {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}


def _compare_table(d: Diff, name: str, a: dict, b: dict, skip: set[str]) -> None:
    for k in sorted(set(a) | set(b), key=str):
        if k not in b:
            d.add(f"{name}[{k}]", "row gone")
            continue
        if k not in a:
            d.add(f"{name}[{k}]", "new row")
            continue
        ra, rb = a[k], b[k]
        for col in sorted(set(ra) | set(rb)):
            if col in skip:
                continue
            if col not in ra or col not in rb:
                d.add(f"{name}[{k}].{col}", "column only in " + ("B" if col not in ra else "A"))
                continue
            x, y = ra[col], rb[col]
            if col == "quality_json" and x is not None and y is not None:
                d.value(f"{name}[{k}].quality", json.loads(x), json.loads(y))
            elif isinstance(x, bytes) or isinstance(y, bytes):
                continue  # blobs: compared decoded
            else:
                d.value(f"{name}[{k}].{col}", x, y)


def _compare_blobs(d: Diff, a: dict, b: dict, ignore_bytes: bool) -> None:
    for k in sorted(set(a) & set(b)):
        ra, rb = a[k], b[k]
        try:
            va, vb = CycleVector.from_bytes(ra["vector"]), CycleVector.from_bytes(rb["vector"])
            for s in _VECTOR_SCALARS:
                d.value(f"vector[{k}].{s}", float(getattr(va, s)), float(getattr(vb, s)))
            for s in _VECTOR_ARRAYS:
                d.array(f"vector[{k}].{s}", getattr(va, s), getattr(vb, s))
        except ValueError as exc:
            d.add(f"vector[{k}]", f"undecodable: {exc}")
        try:
            pa, pb = decode_profile(ra["profile"]), decode_profile(rb["profile"])
            d.value(f"profile[{k}] arrays", sorted(pa), sorted(pb))
            for s in sorted(set(pa) & set(pb)):
                d.array(f"profile[{k}].{s}", pa[s], pb[s])
        except Exception as exc:
            d.add(f"profile[{k}]", f"undecodable: {exc}")
        if not ignore_bytes:
            for col in ("vector", "profile"):
                if bytes(ra[col]) != bytes(rb[col]):
                    d.add(f"{col}[{k}]", f"bytes differ ({len(ra[col])} -> {len(rb[col])} bytes)")


def compare_stores(d: Diff, a_path: Path, b_path: Path, ignore_bytes: bool) -> None:
    ca = sqlite3.connect(f"file:{a_path}?mode=ro", uri=True)
    cb = sqlite3.connect(f"file:{b_path}?mode=ro", uri=True)
    ta, tb = _tables(ca), _tables(cb)
    d.value("tables", sorted(ta), sorted(tb))
    keys = {"files": "path", "trips": "trip_id", "trip_masses": "trip_id", "routes": "name", "meta": "key"}
    for table, key in keys.items():
        if table in ta and table in tb:
            skip = set(_VOLATILE.get(table, ()))
            ra, rb = _rows(ca, table, key), _rows(cb, table, key)
            if table == "meta":
                for m in (ra, rb):
                    m.pop("created_utc_s", None)
            _compare_table(d, table, ra, rb, skip)
    if "trip_blobs" in ta and "trip_blobs" in tb:
        _compare_blobs(d, _rows(ca, "trip_blobs", "trip_id"), _rows(cb, "trip_blobs", "trip_id"), ignore_bytes)
    ca.close()
    cb.close()


def _text(path: Path) -> str:
    """A saved output, its own folder (where its store is) written as ``<DIR>``."""
    return path.read_text().replace(str(path.parent.resolve()), "<DIR>")


def _json_lines(path: Path) -> list:
    out = []
    for line in _text(path).splitlines():
        try:
            obj = json.loads(line)
        except ValueError:
            out.append(line)
            continue
        if isinstance(obj, dict):
            obj.pop("seconds", None)
            obj.pop("stage_s", None)
        out.append(obj)
    return out


def compare_outputs(d: Diff, case: str, a_dir: Path, b_dir: Path) -> None:
    for ext in ("rc", "stderr"):
        pa, pb = a_dir / f"{case}.{ext}", b_dir / f"{case}.{ext}"
        if pa.exists() and pb.exists():
            d.value(f"{case}.{ext}", _text(pa).splitlines(), _text(pb).splitlines())
    pa, pb = a_dir / f"{case}.stdout", b_dir / f"{case}.stdout"
    if pa.exists() and pb.exists():
        d.value(f"{case}.stdout", _json_lines(pa), _json_lines(pb))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", type=Path)
    ap.add_argument("b", type=Path)
    ap.add_argument("--tolerance", type=float, default=0.0, help="relative tolerance of floats (default: exact)")
    ap.add_argument("--ignore-bytes", action="store_true",
                    help="do not report blobs whose bytes differ but decode equal")
    args = ap.parse_args(argv)
    d = Diff(args.tolerance)
    if args.a.is_dir():
        cases = sorted({p.stem for p in args.a.glob("*.sqlite")} | {p.stem for p in args.b.glob("*.sqlite")})
        for case in cases:
            sa, sb = args.a / f"{case}.sqlite", args.b / f"{case}.sqlite"
            if not (sa.exists() and sb.exists()):
                d.add(case, f"store only in {'A' if sa.exists() else 'B'}")
                continue
            n = len(d.lines)
            compare_stores(d, sa, sb, args.ignore_bytes)
            compare_outputs(d, case, args.a, args.b)
            print(f"{case}: {len(d.lines) - n} differences", file=sys.stderr)
    else:
        compare_stores(d, args.a, args.b, args.ignore_bytes)
    for line in d.lines:
        print(line)
    print(f"{len(d.lines)} differences", file=sys.stderr)
    return 1 if d.lines else 0


if __name__ == "__main__":
    sys.exit(main())
