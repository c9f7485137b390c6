"""``python -m cevm_samplegen gtfs-feed OUTDIR``: a GTFS feed of the sample buses' services
(``sample_logs/gtfs/``), made from the sample world so that it is reproducible: the two
urban loops the electric buses EB-01 and EB-02 drive (``bus-1``, ``bus-2`` of
:data:`cevm_samplegen.world.ROUTE_POINTS`, in Milton Keynes) as shapes (WGS84, every 25 m,
``shape_dist_traveled`` in metres), a stop every 400 m or so, a weekday timetable for 2019.

Route 1 (``bus-1``) runs two blocks given by ``block_id`` (a morning and an afternoon
bus, 30 min a loop and 10 min of layover); route 2 (``bus-2``) runs its afternoon loops
without ``block_id`` (``cevm gtfs`` chains them: one block inferred). No service on
Christmas Day (``calendar_dates.txt``). Nothing is random: the running times are the
loop's length at 18 km/h, the service speed of an urban bus with its stops.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

#: Service speed of the timetable [m/s] (18 km/h: an urban bus with its stops).
SERVICE_MPS = 18.0 / 3.6
#: Distance between stops [m] along a loop (urban bus stops: 300-500 m apart).
STOP_SPACING_M = 400.0
#: Layover at the terminus between two loops [s].
LAYOVER_S = 600.0
#: Shape point spacing [m].
SHAPE_STEP_M = 25.0


def _hms(t: float) -> str:
    t = int(round(t))
    return f"{t // 3600:02d}:{t % 3600 // 60:02d}:{t % 60:02d}"


def _loop(name: str):
    import pyproj

    from cevm_samplegen.common import BNG, WGS84
    from cevm_samplegen.world import make_route

    r = make_route(name)
    s = np.arange(0.0, r.length_m, SHAPE_STEP_M)
    s = np.append(s, r.length_m)
    x, y = r.xy(np.where(s >= r.length_m, r.length_m - 1e-6, s))
    lon, lat = pyproj.Transformer.from_crs(BNG, WGS84, always_xy=True).transform(x, y)
    n_stops = max(int(round(r.length_m / STOP_SPACING_M)), 2)
    stop_s = np.linspace(0.0, r.length_m, n_stops + 1)[:-1]
    sx, sy = r.xy(stop_s)
    slon, slat = pyproj.Transformer.from_crs(BNG, WGS84, always_xy=True).transform(sx, sy)
    return s, lat, lon, stop_s, slat, slon, r.length_m


def write_feed(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, list[str]] = {
        "agency.txt": ["agency_id,agency_name,agency_url,agency_timezone",
                       "MKB,Sample Milton Keynes Buses,https://example.org,Europe/London"],
        "routes.txt": ["route_id,agency_id,route_short_name,route_long_name,route_type"],
        "calendar.txt": ["service_id,monday,tuesday,wednesday,thursday,friday,saturday,sunday,start_date,end_date",
                         "WK,1,1,1,1,1,0,0,20190101,20191231"],
        "calendar_dates.txt": ["service_id,date,exception_type", "WK,20191225,2"],
        "stops.txt": ["stop_id,stop_name,stop_lat,stop_lon"],
        "shapes.txt": ["shape_id,shape_pt_lat,shape_pt_lon,shape_pt_sequence,shape_dist_traveled"],
        "trips.txt": ["route_id,service_id,trip_id,block_id,shape_id"],
        "stop_times.txt": ["trip_id,arrival_time,departure_time,stop_id,stop_sequence,shape_dist_traveled"],
    }
    # (route, loop, [(block_id or "", first departure [h], loops)])
    plan = (("1", "bus-1", (("AM", 6.0, 7), ("PM", 13.0, 7))),
            ("2", "bus-2", (("MID", 9.5, 3), ("", 14.0, 6))))
    for route, loop, blocks in plan:
        s, lat, lon, stop_s, slat, slon, length = _loop(loop)
        files["routes.txt"].append(f"{route},MKB,{route},Loop {loop},3")
        shape = f"loop-{route}"
        files["shapes.txt"] += [f"{shape},{a:.6f},{b:.6f},{k + 1},{d:.1f}"
                                for k, (a, b, d) in enumerate(zip(lat, lon, s, strict=True))]
        ids = [f"{route}-{k:02d}" for k in range(stop_s.size)]
        files["stops.txt"] += [f"{i},Loop {route} stop {k},{a:.6f},{b:.6f}"
                               for k, (i, a, b) in enumerate(zip(ids, slat, slon, strict=True))]
        # a loop from stop 0 round to stop 0 again; 20 s dwell at each stop on the way
        dist = np.append(stop_s, length)
        run = np.diff(dist) / SERVICE_MPS
        for block, first_h, loops in blocks:
            block_id = f"{route}-{block}" if block else ""
            for n in range(loops):
                t0 = first_h * 3600.0 + n * (float(run.sum()) + LAYOVER_S)
                trip = f"{route}-{block or 'X'}-{n + 1:02d}"
                files["trips.txt"].append(f"{route},WK,{trip},{block_id},{shape}")
                t = t0 + np.concatenate([[0.0], np.cumsum(run)])
                for k, (tk, dk) in enumerate(zip(t, dist, strict=True)):
                    stop = ids[k % len(ids)]
                    files["stop_times.txt"].append(f"{trip},{_hms(tk)},{_hms(tk)},{stop},{k + 1},{dk:.1f}")
    for name, lines in files.items():
        (out / name).write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str]) -> None:
    if len(argv) != 1:
        sys.exit("usage: python -m cevm_samplegen gtfs-feed OUTDIR")
    write_feed(Path(argv[0]))
