"""Write the stand-in public cycles of tests/data/cycles (deterministic: the same bytes on
every run). ``python tests/data/cycles/make_standins.py`` rewrites them in place.

The public cycles the tests were written against (``../shared/cycles``: NREL ADVISOR's
library and the VECTO missions of carculator_utils) are not copied into the project (the
folder's README asks for that: the project ships or generates its own cycles). These files
have the same layouts and the same quirks, with speed traces from the project's micro-trip
generator (``cevm_samplegen.cycles``); ``README.md`` beside this file lists each quirk and
where it is. Nothing here is a copy or an excerpt of a public cycle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cevm_samplegen.cycles import MicroTripSpec, micro_trip_cycle

HERE = Path(__file__).resolve().parent

URBAN = MicroTripSpec(n_trips=6, cruise_kmh=(18.0, 48.0), cruise_s=(8.0, 40.0), dwell_s=(5.0, 30.0),
                      accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 1.0))
REGIONAL = MicroTripSpec(n_trips=2, cruise_kmh=(50.0, 80.0), cruise_s=(40.0, 80.0), dwell_s=(5.0, 20.0),
                         accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 0.9))
MOTORWAY = MicroTripSpec(n_trips=1, cruise_kmh=(80.0, 85.0), cruise_s=(200.0, 260.0), dwell_s=(5.0, 10.0),
                         accel_mps2=(0.2, 0.35), decel_mps2=(0.3, 0.6), fluctuation_kmh=1.5)
FAST = MicroTripSpec(n_trips=1, cruise_kmh=(70.0, 90.0), cruise_s=(90.0, 120.0), dwell_s=(5.0, 10.0),
                     accel_mps2=(0.3, 0.6), decel_mps2=(0.5, 0.9))
BUS = MicroTripSpec(n_trips=8, cruise_kmh=(20.0, 45.0), cruise_s=(10.0, 30.0), dwell_s=(8.0, 25.0))

#: The speed [km/h] the spliced 'Long haul, 7.5t' mission jumps to from standstill in one
#: second (VECTO's public truck file does the same, 0 to 59.8763 km/h): 16.6 m/s^2.
SPLICE_KMH = 59.8763


def kmh(spec: MicroTripSpec, seed: int, dt_s: float = 1.0) -> np.ndarray:
    return micro_trip_cycle(spec, seed, dt_s=dt_s).speed_mps * 3.6


def grade(n: int, seed: int, amplitude: float = 0.03) -> np.ndarray:
    """A smooth road grade [fraction] per second, within +-amplitude."""
    rng = np.random.default_rng(seed)
    s = np.arange(n, dtype=float)
    waves = [a * np.sin(2 * np.pi * s / rng.uniform(150.0, 600.0) + rng.uniform(0, 2 * np.pi))
             for a in (0.6, 0.3, 0.1)]
    return amplitude * np.sum(waves, axis=0)


def spliced_long_haul() -> np.ndarray:
    """A stop-and-go start, then a motorway trace spliced in at SPLICE_KMH (no acceleration)."""
    start = kmh(URBAN, 31)[:120]
    start[-20:] = 0.0
    motorway = kmh(MOTORWAY, 32)
    k = int(np.argmax(motorway >= SPLICE_KMH))
    tail = motorway[k:].copy()
    tail[0] = SPLICE_KMH
    return np.concatenate([start, tail])


def vecto_number(x: float, decimals: int) -> str:
    """VECTO's way: whole numbers without a decimal point, others to ``decimals``."""
    r = round(float(x), decimals)
    return str(int(r)) if r == int(r) else f"{r:.{decimals}f}".rstrip("0")


def write_vecto(path: Path, time: np.ndarray | None, columns: dict[str, np.ndarray], n: int, decimals: int) -> None:
    """``;``-separated, a ``Time`` column (1, 2, ...; None: empty cells past its length),
    one column per mission, each ending with empty cells where the mission ends."""
    lines = [";".join(["Time", *columns])]
    for i in range(n):
        cells = ["" if time is None or i >= time.size else vecto_number(time[i], 0)]
        cells += ["" if i >= v.size else vecto_number(v[i], decimals) for v in columns.values()]
        lines.append(";".join(cells))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_advisor(path: Path, t: np.ndarray, v: np.ndarray, t_decimals: int) -> None:
    """ADVISOR's conversion: ``time_s,speed_kmh``, whole seconds printed as integers."""
    lines = ["time_s,speed_kmh"]
    lines += [f"{vecto_number(ti, t_decimals)},{vi:.4f}" for ti, vi in zip(t, v, strict=True)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main() -> None:
    vecto = HERE / "vecto-standin"
    vecto.mkdir(exist_ok=True)
    missions = {
        "Urban delivery, 7.5t": kmh(URBAN, 11),
        "Regional delivery, 7.5t": kmh(REGIONAL, 12),
        "Long haul, 7.5t": spliced_long_haul(),
        "Long haul, 26t": kmh(MOTORWAY, 14),
        "Long haul, 40t": kmh(MOTORWAY, 15),
    }
    n = max(v.size for v in missions.values())
    # the long-haul missions run to the end of the file, as VECTO's do (standing at the end)
    for name in ("Long haul, 26t", "Long haul, 40t"):
        missions[name] = np.concatenate([missions[name], np.zeros(n - missions[name].size)])
    time = np.arange(1, n + 1, dtype=float)
    write_vecto(vecto / "driving_cycles_truck.csv", time, missions, n, 4)
    # The gradient file names one column differently, as VECTO's does ('8.5t' for '7.5t').
    grades = {name.replace("Regional delivery, 7.5t", "Regional delivery, 8.5t"): grade(v.size, 20 + j)
              for j, (name, v) in enumerate(missions.items())}
    write_vecto(vecto / "gradient_truck.csv", time, grades, n, 6)
    # The bus file's Time column stops long before its missions do.
    buses = {"Urban, 9m": kmh(BUS, 41), "Coach, 13m": kmh(REGIONAL, 42)}
    nb = max(v.size for v in buses.values())
    write_vecto(vecto / "driving_cycles_bus.csv", np.arange(1, 121, dtype=float), buses, nb, 4)
    write_vecto(vecto / "gradient_bus.csv", np.arange(1, nb + 1, dtype=float),
                {name: grade(v.size, 50 + j) for j, (name, v) in enumerate(buses.items())}, nb, 6)

    advisor = HERE / "advisor-standin"
    advisor.mkdir(exist_ok=True)
    bus = kmh(BUS, 61)
    write_advisor(advisor / "CYC_STANDIN_BUS.csv", np.arange(1, bus.size + 1, dtype=float), bus, 0)
    town = kmh(URBAN, 62)
    write_advisor(advisor / "CYC_STANDIN_TOWNTRUCK.csv", np.arange(town.size, dtype=float), town, 0)
    fast = kmh(FAST, 63, dt_s=0.1)
    write_advisor(advisor / "CYC_STANDIN_10HZ.csv", np.round(np.arange(fast.size) * 0.1, 1), fast, 1)


if __name__ == "__main__":
    main()
