"""A reference of what ``cevm ingest`` stores for the shipped sample logs, to check that
work on the ingest stages' speed leaves the results equal to rounding.

``summarise(store)`` reduces every stored trip to numbers that a change of results
would move: its scalars, per profile array the sum, total variation, minimum, maximum
and 17 values at fixed positions, and its drive-cycle vector's sums (12 significant
digits, far finer than the comparison's tolerances). The reference
(``tests/data/ingest_reference.json``) was written by::

    PYTHONPATH=src python tests/ingest_reference.py --write

on the code before the ingest stages were tuned for speed (2026-12-01); ``tests/test_ingest_reference.py``
ingests the sample logs again and compares. Regenerate it only when the sample logs
themselves change (the test then says so: the files' hashes are part of the reference),
never to make a changed result pass.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_logs"
REFERENCE = Path(__file__).parent / "data" / "ingest_reference.json"

#: Absolute tolerances per profile array (storage is float32 for speed and elevation),
#: on top of a relative tolerance of 1e-7.
ATOL = {"time_s": 1e-9, "speed_mps": 1e-5, "distance_m": 1e-4, "elevation_m": 1e-3, "lat_deg": 1e-9,
        "lon_deg": 1e-9}
RTOL = 1e-7


def sample_files() -> list[Path]:
    return sorted(p for p in (SAMPLE / "srf").iterdir() if p.is_file()) + sorted(
        p for p in (SAMPLE / "portal").iterdir() if p.is_file())


def file_hashes() -> dict[str, str]:
    return {p.relative_to(SAMPLE).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in sample_files()}


def _g(x) -> float | None:
    """A float to 12 significant digits (None for NaN or None)."""
    return None if x is None or not np.isfinite(x) else float(f"{float(x):.12g}")


def _array_summary(a: np.ndarray) -> dict:
    a = np.asarray(a, dtype=np.float64)
    fin = a[np.isfinite(a)]
    idx = np.unique(np.linspace(0, a.size - 1, 17).round().astype(int)) if a.size else np.empty(0, int)
    return {
        "n": int(a.size),
        "n_finite": int(fin.size),
        "sum": _g(fin.sum()),
        "variation": _g(np.abs(np.diff(fin)).sum()) if fin.size > 1 else 0.0,
        "min": _g(fin.min()) if fin.size else None,
        "max": _g(fin.max()) if fin.size else None,
        "at": [_g(a[i]) for i in idx],
    }


def summarise(store) -> dict:
    """Every stored trip of ``store`` as comparable numbers, keyed by trip id."""
    from cevm.core.cycle import CycleVector

    out: dict = {}
    df = store.list_trips()
    for r in df.itertuples(index=False):
        prof = store.load_profile(r.trip_id)
        vec = CycleVector.from_bytes(store.load_vector_bytes(r.trip_id))
        ns = vec.ns_sums
        out[r.trip_id] = {
            "n_samples": int(r.n_samples),
            "duration_s": float(r.duration_s),
            "distance_m": float(r.distance_m),
            "elevation_source": r.elevation_source,
            "dsm_coverage_pct": float(r.dsm_coverage_pct),
            "gross_weight_kg": None if not np.isfinite(r.gross_weight_kg) else float(r.gross_weight_kg),
            "measured_kind": r.measured_kind,
            "measured_value": None if not np.isfinite(r.measured_value) else float(r.measured_value),
            "measured_source": r.measured_source,
            "profile": {k: _array_summary(v) for k, v in sorted(prof.items())},
            "vector": {k: _g(v) for k, v in {
                "s_me": vec.s_me, "s_a": vec.s_a, "s_r": vec.s_r, "stand_x": vec.stand_x,
                "duration_s": vec.duration_s, "distance_m": vec.distance_m, "idle_s": vec.idle_s,
                "n_samples": vec.n_samples, "k_pos": vec.k_pos, "traction_s": vec.traction_s,
                "n_nonsimplified": vec.n_nonsimplified, "ns_x": ns[0], "ns_a": ns[1], "ns_r": ns[2],
            }.items()},
        }
    return out


def ingest_samples(store_path: Path):
    """Ingest the sample logs with the sample DSM into a new store at ``store_path``
    (serially); returns the open store."""
    from cevm.ingest import IngestOptions, ingest
    from cevm.store import TripStore

    st = TripStore.open(store_path)
    rep = ingest([SAMPLE / "srf", SAMPLE / "portal"], st, IngestOptions(dsm=str(SAMPLE / "dsm")))
    assert rep.failed == 0, [f.error for f in rep.files if f.error]
    return st


def close(a, b, atol: float) -> bool:
    """Equal to rounding: both None, or equal strings, or numbers within tolerance."""
    if a is None or b is None or isinstance(a, str) or isinstance(b, str):
        return a == b
    if not (np.isfinite(a) and np.isfinite(b)):
        return (np.isnan(a) and np.isnan(b)) or a == b
    return abs(a - b) <= atol + RTOL * abs(b)


def differences(got: dict, ref: dict) -> list[str]:
    """Human-readable differences of two :func:`summarise` results (empty: equal)."""
    diffs: list[str] = []
    if set(got) != set(ref):
        diffs.append(f"trip ids differ: missing {sorted(set(ref) - set(got))[:5]}, new "
                     f"{sorted(set(got) - set(ref))[:5]}")
    for tid in sorted(set(got) & set(ref)):
        g, r = got[tid], ref[tid]
        for k, rv in r.items():
            if k == "profile":
                for name, rs in rv.items():
                    gs = g[k][name]
                    atol = ATOL[name]
                    for stat, rstat in rs.items():
                        gstat = gs[stat]
                        pairs = zip(gstat, rstat, strict=True) if isinstance(rstat, list) else [(gstat, rstat)]
                        if isinstance(rstat, list) and len(gstat) != len(rstat):
                            diffs.append(f"{tid} {name}.{stat}: {len(gstat)} values, reference {len(rstat)}")
                            continue
                        tol = atol * max(1, rs["n"]) if stat in ("sum", "variation") else atol
                        for x, y in pairs:
                            if not close(x, y, tol):
                                diffs.append(f"{tid} {name}.{stat}: {gstat} != reference {rstat}")
                                break
            elif k == "vector":
                for name, rvv in rv.items():
                    if not close(g[k][name], rvv, 1e-6):
                        diffs.append(f"{tid} vector.{name}: {g[k][name]} != reference {rvv}")
            elif not close(g[k], rv, 1e-6):
                diffs.append(f"{tid} {k}: {g[k]!r} != reference {rv!r}")
    return diffs


def main() -> None:
    if "--write" not in sys.argv:
        sys.exit("usage: python tests/ingest_reference.py --write   (writes " + str(REFERENCE) + ")")
    with tempfile.TemporaryDirectory() as tmp:
        st = ingest_samples(Path(tmp) / "ref.sqlite")
        try:
            doc = {"files": file_hashes(), "trips": summarise(st)}
        finally:
            st.close()
    # one trip per line: readable diffs at a third of an indented file's size
    trips = ",\n".join(f"{json.dumps(k)}: {json.dumps(v, sort_keys=True, separators=(',', ':'))}"
                       for k, v in sorted(doc["trips"].items()))
    files = json.dumps(doc["files"], indent=0, sort_keys=True)
    REFERENCE.write_text(f'{{"files": {files},\n"trips": {{\n{trips}\n}}}}\n')
    print(f"wrote {REFERENCE}: {len(doc['trips'])} trips of {len(doc['files'])} files")


if __name__ == "__main__":
    main()
