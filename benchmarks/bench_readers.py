"""Benchmark of the readers against their input's size: a log's header against its width
and the comment lines before it, a fleet scenario against its routes. The time must grow
linearly (a count per name made a header of 100,000 names take 100 s; a scan from the
start with each 1 MiB piece of text made 17 MB of comment lines take 5 s; a scan of every
route for every stop made a scenario of 4,000 routes take 19 s).

    python benchmarks/bench_readers.py [--widths 10000 100000] [--comments-mb 2 20]
                                       [--routes 1000 4000]

For each header width: the time of the column plan (``_plan_columns``, srf profile, every
tenth name a duplicate) and of finding the header in its text (``_read_header`` over
1 MiB pieces), against a baseline measured in the same run on the same names: one pass
of a ``collections.Counter`` over them (linear; its time per name still grows with the
width, as the names outgrow the processor's caches). For each volume of comment lines
before the header: the time of finding it, against one Python pass over its lines
(``bytes.split``, ``startswith``). For each number of routes: ``load_scenario`` of a
scenario of that many vehicles, each with a route of two stops (the shipped HGV and
long-haul cycle), against parsing its TOML alone (``tomllib``). A linear reader keeps
its ratio to the baseline at every size; a quadratic one's grows with the size (ten
times at ten times the names). Best of three runs each (one for the scenarios).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


class Pieces:
    """A text stream handing out ``data`` 1 MiB at a time (as the log reader's)."""

    def __init__(self, data: bytes, size: int = 1 << 20) -> None:
        self.data, self.size, self.pos = data, size, 0

    def read(self) -> bytes:
        out = self.data[self.pos:self.pos + self.size]
        self.pos += len(out)
        return out


def best_of(fn, runs: int = 3) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--widths", type=int, nargs="*", default=[10_000, 100_000])
    ap.add_argument("--comments-mb", type=float, nargs="*", default=[2.0, 20.0])
    ap.add_argument("--routes", type=int, nargs="*", default=[1_000, 4_000])
    args = ap.parse_args()
    from cevm.ingest.profiles import load_profiles
    from cevm.ingest.reading.header import Header, _plan_columns, _read_header

    prof = load_profiles()["srf"]
    path = Path("bench.csv")
    print(f"{'case':32s} {'seconds':>9s} {'baseline s':>10s} {'ratio':>7s}")
    for w in args.widths:
        names = ("timestamp_utc", "gps_speed_kmh", *(f"x{i - (i % 10 == 9)}" for i in range(w)))
        s = best_of(lambda names=names: _plan_columns(prof, Header(names, 1, 0, ()), path))
        text = (",".join(names) + "\n1,2\n").encode()
        s += best_of(lambda text=text: _read_header(Pieces(text), prof, path))
        ref = best_of(lambda names=names: Counter(names))
        print(f"{'header of ' + format(w, ',') + ' names':32s} {s:9.3f} {ref:10.3f} {s / ref:7.1f}")
    for mb in args.comments_mb:
        line = b"# note=abcdefghijklmnopqrstuvwxyz0123456789\n"
        text = b"# vehicle_id=EB-01\n" + line * int(mb * 1e6 / len(line)) + b"timestamp_utc,gps_speed_kmh\n1,2\n"
        s = best_of(lambda text=text: _read_header(Pieces(text), prof, path))
        ref = best_of(lambda text=text: sum(1 for ln in text.split(b"\n") if ln.startswith(b"#")))
        print(f"{format(mb, 'g') + ' MB of comment lines':32s} {s:9.3f} {ref:10.3f} {s / ref:7.1f}")
    scenarios(args.routes)


def write_scenario(path: Path, n: int) -> Path:
    """A scenario of ``n`` HGVs, each with a route of two stops, one day; the shipped
    HGV and long-haul cycle copied beside it (short names: 4,000 routes fit in 1 MiB)."""
    import shutil

    shutil.copy(ROOT / "configs" / "vehicles" / "diesel-hgv-paper.toml", path.parent / "hgv.toml")
    shutil.copy(ROOT / "configs" / "cycles" / "long-haul-standin.csv", path.parent / "lh.csv")
    lines = ['name = "many routes"', 'objective = "fuel"', "return_to_depot = true", 'days = ["d1"]', "[[depot]]",
             'id = "depot"']
    for i in range(n):
        lines += ["[[vehicle]]", f'id = "V{i}"', 'file = "hgv.toml"']
    for i in range(n):
        lines += ["[[route]]", f'id = "R{i}"', f'vehicle = "V{i}"', f'stops = ["S{i}a", "S{i}b"]',
                  'leg = { cycle = "lh.csv" }']
    lines += ["[payload_kg]"] + [f'"S{i}{x}" = [1000]' for i in range(n) for x in "ab"]
    path.write_text("\n".join(lines) + "\n")
    return path


def scenarios(sizes: list[int]) -> None:
    import tempfile
    import tomllib

    from cevm.io.scenario import load_scenario

    with tempfile.TemporaryDirectory(prefix="cevm-readers-") as tmp:
        for n in sizes:
            path = write_scenario(Path(tmp) / f"s{n}.toml", n)
            s = best_of(lambda path=path: load_scenario(path), runs=1)
            ref = best_of(lambda path=path: tomllib.loads(path.read_text()), runs=1)
            print(f"{'scenario of ' + format(n, ',') + ' routes':32s} {s:9.3f} {ref:10.3f} {s / ref:7.1f}")


if __name__ == "__main__":
    main()
