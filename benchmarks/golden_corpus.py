"""A golden corpus for ingest: the same inputs ingested by two checkouts, to compare
their stores (``benchmarks/compare_stores.py``) and their outputs.

    python benchmarks/golden_corpus.py DIR [--src SRC] [--label NAME] [--shared PATH]

Writes, once, ``DIR/corpus/`` (copied so that every checkout reads the same paths):
``sample_logs`` (srf, portal, dsm, manifests), the Twizy logs of ``../shared`` (when
there), ``tests/data``'s logs, and ``hostile/``: logs made from a sample srf log and the
portal log with the faults real loggers write (clock steps forward and back, duplicated
lines and ticks, gaps, junk GPS fixes, corrupt dates, a truncated last line, an energy
counter that resets and one that wraps, a UTF-8 BOM, UTF-16, mixed zone designators,
gzip, bad cells in measured and required columns, a spliced speed jump, N/A cells);
and, generated (:func:`make_generated`), ``fleet/`` (12 vehicle-days of the benchmark
fleet: many trips, the DSM) and ``large/`` (one log of 600,000 rows: the chunked steps).

Then ingests each case with the ``cevm`` of ``--src`` (default: this checkout's
``src``), serially (``--workers 1``) with ``--log-json``, into
``DIR/LABEL/CASE.sqlite``, and saves ``CASE.stdout``, ``CASE.stderr`` and ``CASE.rc``
beside it. Compare two labels with::

    python benchmarks/compare_stores.py DIR/main DIR/this

The baseline checkout: ``git -C /work/main archive main src configs | tar -x -C
/tmp/base`` and ``--src /tmp/base/src --label main``.
"""

from __future__ import annotations

import argparse
import gzip
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Cases: name -> (ingest arguments relative to the corpus, extra options).
CASES: dict[str, list[str]] = {
    "samples": ["sample_logs/srf", "sample_logs/portal", "--dsm", "sample_logs/dsm",
                "--manifest", "sample_logs/manifests/bus-loads.csv"],
    "twizy": ["twizy"],
    "testdata": ["testdata"],
    "hostile": ["hostile", "--dsm", "sample_logs/dsm"],
    "fleet": ["fleet", "--dsm", "sample_logs/dsm"],
    "large": ["large", "--dsm", "sample_logs/dsm", "--max-rows", "6000000"],
}

#: Rows of the ``large`` case's log: more than the cleaning's chunks
#: (``cevm.ingest.consumption.CHUNK_ROWS``) and the elevation's batches many times over.
LARGE_ROWS = 600_000


def _srf_lines(path: Path) -> tuple[list[str], list[str]]:
    """(comment and header lines, data lines) of a plain srf log."""
    lines = path.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("timestamp_utc"))
    return lines[: k + 1], lines[k + 1:]


def _set_field(line: str, col: int, value: str) -> str:
    f = line.split(",")
    f[col] = value
    return ",".join(f)


def _shift_time(line: str, seconds: float) -> str:
    import numpy as np

    ts, rest = line.split(",", 1)
    t = np.datetime64(ts.rstrip("Z"), "ms") + np.timedelta64(int(round(seconds * 1000)), "ms")
    return f"{np.datetime_as_string(t, unit='ms')}Z,{rest}"


def _write(path: Path, head: list[str], data: list[str], *, encoding: str = "utf-8", bom: bool = False,
           gz: bool = False, end: str = "\n") -> None:
    text = "\n".join(head + data) + end
    raw = text.encode(encoding)
    if bom:
        raw = b"\xef\xbb\xbf" + raw
    if gz:
        raw = gzip.compress(raw, mtime=0)
    path.write_bytes(raw)


def make_hostile(srf: Path, portal: Path, out: Path) -> None:
    """The hostile logs, from a sample srf log (its first 6,000 data lines) and the
    portal log; deterministic."""
    out.mkdir(parents=True, exist_ok=True)
    head, data = _srf_lines(srf)
    data = data[:6000]
    cols = head[-1].split(",")
    c = {name: i for i, name in enumerate(cols)}
    moving = [i for i, line in enumerate(data) if line.split(",")[c["gps_lat_deg"]] and
              float(line.split(",")[c["fms_wheel_speed_kmh"]] or 0) > 20]
    mid = moving[len(moving) // 2]

    def vid(h: list[str], name: str) -> list[str]:
        return [f"# vehicle_id={name}" if line.startswith("# vehicle_id=") else line for line in h]

    def w(name: str, rows: list[str], **kw) -> None:
        _write(out / name, vid(head, "HX-" + name.split(".")[0]), rows, **kw)

    w("plain.csv", data)
    w("clock_forward.csv", data[:mid] + [_shift_time(x, 3600.0) for x in data[mid:]])
    w("clock_back.csv", data[:mid] + [_shift_time(x, -4.25) for x in data[mid:]])
    w("clock_back_long.csv", data[:mid] + [_shift_time(x, -600.0) for x in data[mid:]])
    dup = []
    for i, x in enumerate(data):
        dup.append(x)
        if i % 97 == 5:
            dup.append(x)  # an identical line
        if i % 211 == 7 and x.split(",")[c["fms_wheel_speed_kmh"]]:
            dup.append(_set_field(x, c["fms_wheel_speed_kmh"], "13.5"))  # the same tick, other values
    w("duplicates.csv", dup)
    w("gaps.csv", data[:mid - 400] + data[mid:mid + 500] + data[mid + 1500:])
    junk = list(data)
    for k, i in enumerate(moving[::150][:20]):
        lat, lon = (("0.0", "0.0"), ("52.9", "-0.77"), ("91.5", "0.1"), ("", "-0.7"))[k % 4]
        junk[i] = _set_field(_set_field(junk[i], c["gps_lat_deg"], lat), c["gps_lon_deg"], lon)
    w("junk_gps.csv", junk)
    bad_dates = list(data)
    for k, i in enumerate(range(100, 5000, 700)):
        ts = bad_dates[i].split(",")[0]
        bad_dates[i] = bad_dates[i].replace(ts, ("2099" + ts[4:], ts[:11] + "25" + ts[13:],
                                                 ts[:5] + "13" + ts[7:])[k % 3], 1)
    w("corrupt_dates.csv", bad_dates)
    epoch = list(data)
    epoch[100] = "1970-01-01T00:00:07.000Z" + epoch[100][epoch[100].index(","):]
    w("epoch_date.csv", epoch)
    w("truncated.csv", data[:-1] + [data[-1][: len(data[-1]) // 2]], end="")
    ecol = c["fms_total_energy_used_kwh"]
    reset = [(_set_field(x, ecol, f"{float(x.split(',')[ecol]) - 48000:.1f}") if i >= mid and x.split(",")[ecol]
              else x) for i, x in enumerate(data)]
    w("counter_reset.csv", reset)
    wrap = [(_set_field(x, ecol, f"{(float(x.split(',')[ecol]) + 2 ** 32 * 0.05 - 48215) % (2 ** 32 * 0.05):.1f}")
             if x.split(",")[ecol] else x) for x in data]
    w("counter_wrap.csv", wrap)
    w("bom.csv", data, bom=True)
    w("utf16.csv", data, encoding="utf-16")
    w("gz.csv.gz", data, gz=True)
    zones = [x.replace("Z,", "+00:00,", 1) if i % 2 else x for i, x in enumerate(data)]
    w("other_zones.csv", zones)
    w("mixed_zones.csv", [x.replace("Z,", ",", 1) if i > mid else x for i, x in enumerate(data)])
    offset = [x.replace("Z,", "+01:00,", 1) for x in data]
    w("offset_zones.csv", offset)
    err = list(data)
    err[mid] = _set_field(err[mid], c["fms_battery_current_a"], "ERR")
    w("err_measured.csv", err)
    na = list(data)
    for i in range(200, 5000, 450):
        na[i] = _set_field(na[i], c["fms_battery_current_a"], "N/A")
    w("na_measured.csv", na)
    req = list(data)
    req[mid] = "garbage" + req[mid][req[mid].index(","):]
    w("bad_time.csv", req)
    splice = data[:mid] + [_set_field(x, c["fms_wheel_speed_kmh"],
                                      f"{float(x.split(',')[c['fms_wheel_speed_kmh']] or 0) + 119:.1f}")
                           for x in data[mid:mid + 300]] + data[mid + 300:]
    w("splice.csv", splice)
    # the portal log: a gap and a truncated last line, in its own encoding
    plines = portal.read_bytes().split(b"\n")
    body = plines[:1] + plines[1:400] + plines[700:-2] + [plines[-2][:20]]
    (out / "portal_hostile.csv").write_bytes(b"\n".join(body))


def make_corpus(corpus: Path, shared: Path | None) -> None:
    if (corpus / ".done").exists():
        return
    if corpus.exists():
        shutil.rmtree(corpus)
    corpus.mkdir(parents=True)
    s = corpus / "sample_logs"
    for sub in ("srf", "portal", "dsm", "manifests"):
        shutil.copytree(ROOT / "sample_logs" / sub, s / sub)
    (corpus / "testdata").mkdir()
    for f in sorted((ROOT / "tests" / "data").glob("*.csv")):
        shutil.copy(f, corpus / "testdata" / f.name)
    if shared is not None and (shared / "real-logs" / "twizy").is_dir():
        (corpus / "twizy").mkdir()
        for f in sorted((shared / "real-logs" / "twizy").glob("*.csv")):
            shutil.copy(f, corpus / "twizy" / f.name)
    make_hostile(s / "srf" / "EB-01_2019-01-31.csv", s / "portal" / "portal_export_2019-10-25_2019-10-28.csv",
                 corpus / "hostile")
    (corpus / ".done").touch()


def make_generated(corpus: Path) -> None:
    """The generated cases, once each (so that a corpus made before them gains them):
    ``fleet/``, 12 vehicle-days of the benchmark fleet (buses and trucks, 2-12 trips
    each, full working days for half of them) on the sample DSM, and ``large/``, one
    srf log of :data:`LARGE_ROWS` rows (a long-haul truck's working day repeated)."""
    from cevm_samplegen import fleet_for_benchmark

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_memory import make_large_srf

    if not (corpus / "fleet" / ".done").exists():
        shutil.rmtree(corpus / "fleet", ignore_errors=True)
        work = corpus / ".work-fleet"
        fleet_for_benchmark(4, 2, work / "short")
        fleet_for_benchmark(4, 1, work / "full", full_days=True, first_date="2019-06-03")
        (corpus / "fleet").mkdir()
        for f in sorted(work.rglob("*.csv")):
            shutil.copy(f, corpus / "fleet" / f"{f.parent.parent.name}-{f.name}")
        shutil.rmtree(work)
        (corpus / "fleet" / ".done").touch()
    if not (corpus / "large" / ".done").exists():
        shutil.rmtree(corpus / "large", ignore_errors=True)
        work = corpus / ".work-large"
        work.mkdir(parents=True, exist_ok=True)
        (corpus / "large").mkdir()
        make_large_srf(corpus / "large" / f"srf-{LARGE_ROWS}.csv", LARGE_ROWS, work)
        shutil.rmtree(work)
        (corpus / "large" / ".done").touch()


def run_cases(corpus: Path, out: Path, src: Path, cases: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    extra = os.environ.get("PYTHONPATH")  # e.g. a sitecustomize that changes a setting for a comparison
    env = {**os.environ, "PYTHONPATH": str(src) + (os.pathsep + extra if extra else ""), "OMP_NUM_THREADS": "1",
           "COLUMNS": "200"}
    env.pop("CEVM_STORE", None)
    for case in cases:
        args = CASES[case]
        if not (corpus / args[0]).exists():
            print(f"{case}: skipped ({args[0]} not in the corpus)")
            continue
        store = out / f"{case}.sqlite"
        for p in out.glob(f"{case}.sqlite*"):
            p.unlink()
        cmd = [sys.executable, "-m", "cevm", "ingest", *args, "--store", str(store), "--workers", "1", "--log-json"]
        r = subprocess.run(cmd, cwd=corpus, env=env, capture_output=True, text=True)
        (out / f"{case}.stdout").write_text(r.stdout)
        (out / f"{case}.stderr").write_text(r.stderr)
        (out / f"{case}.rc").write_text(f"{r.returncode}\n")
        print(f"{case}: exit {r.returncode}, {len(r.stdout.splitlines())} lines -> {store}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--src", type=Path, default=ROOT / "src", help="the src/ of the checkout to run")
    ap.add_argument("--label", default="this", help="the folder of this run's stores under DIR")
    ap.add_argument("--shared", type=Path, default=None,
                    help="the shared folder (default: ../shared, or ../../shared from a worktree)")
    ap.add_argument("--case", action="append", choices=sorted(CASES), help="only these cases")
    args = ap.parse_args(argv)
    shared = args.shared or next((p for p in (ROOT.parent / "shared", ROOT.parent.parent / "shared") if p.is_dir()),
                                 None)
    corpus = args.dir.resolve() / "corpus"
    make_corpus(corpus, shared)
    make_generated(corpus)
    run_cases(corpus, args.dir.resolve() / args.label, args.src.resolve(), args.case or list(CASES))


if __name__ == "__main__":
    main()
