"""The main job's closing summary (sample_logs/main-job.sh): what was calibrated, how
well (cross-validated error, and the intervals' coverage where calibrate wrote it), and
what the predictions say, in lines of at most 80 characters.

    python sample_logs/job_summary.py OUT_DIR

Reads the calibrated vehicle files (their [calibration] table), the predictions' CSV
files (predict-*.csv, cevm predict -f csv), the replays' summaries (replay-*.json,
cevm replay --summary) and the timetable's blocks (gtfs-blocks.csv, cevm gtfs -f csv) the
job wrote into OUT_DIR; the standard library only.
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import sys
import textwrap
import tomllib
from pathlib import Path

WIDTH = 80


def say(text: str, indent: int = 2) -> None:
    print(textwrap.fill(text, WIDTH, initial_indent=" " * indent, subsequent_indent=" " * (indent + 2),
                        break_long_words=False, break_on_hyphens=False))


def number(text: str) -> float | None:
    try:
        x = float(text)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def calibrated(path: Path) -> None:
    cal = tomllib.loads(path.read_text(encoding="utf-8")).get("calibration", {})
    text = (f"{cal.get('vehicle_id', '?')} -> {path.name}: {'+'.join(cal.get('terms', []))} on "
            f"{cal.get('n_trips', '?')} trips; cross-validated error {cal.get('cv_mean_pct', 0):+.1f} % mean, "
            f"{cal.get('cv_std_pct', float('nan')):.1f} % sigma")
    coverage, level = cal.get("cv_coverage"), cal.get("interval")
    if coverage is not None and level is not None:
        text += f"; its {level:.0%} intervals held {coverage:.0%} of the held-out trips"
    say(text)


def predicted(path: Path) -> None:
    with path.open(encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        say(f"{path.name}: no rows")
        return
    vehicles = sorted({r["vehicle_key"] for r in rows})
    sources = sorted({r["cycle"] for r in rows})
    what = sources[0] if len(sources) == 1 else f"{len(sources)} {rows[0]['source_kind']}s"
    if rows[0].get("source_kind") == "trip":  # whose trips: a trip id is VEHICLE:start:hash
        owners = sorted({src.rsplit(":", 2)[0] for src in sources if src.count(":") >= 2})
        if owners:
            what = f"{', '.join(owners)}'s {what}"
    text = f"{', '.join(vehicles)} on {what}"
    errors = [x for x in (number(r.get("error_pct")) for r in rows) if x is not None]
    if errors:
        sd = statistics.stdev(errors) if len(errors) > 1 else 0.0
        text += (f": error against the measured {statistics.fmean(errors):+.1f} % mean, {sd:.1f} % sigma "
                 f"({len(errors)} trips)")
    else:
        kwh = [x for x in (number(r.get("energy_kwh")) for r in rows) if x is not None]
        litres = [x for x in (number(r.get("fuel_l")) for r in rows) if x is not None]
        masses = [float(r["mass_kg"]) for r in rows]
        values, unit = (kwh, "kWh") if kwh else (litres, "l")
        if values:
            text += (f" at {min(masses):,.0f}-{max(masses):,.0f} kg: {min(values):,.2f}-{max(values):,.2f} {unit}")
        ranges = [x for x in (number(r.get("range_km")) for r in rows) if x is not None]
        if ranges:
            text += f", range {min(ranges):,.0f}-{max(ranges):,.0f} km"
    verdicts = [r.get("feasible") for r in rows]
    yes = sum(v == "true" for v in verdicts)
    text += f"; feasible {yes} of {len(rows)}"
    if yes < len(rows):
        reasons = []
        for key, word in (("over_max_gross", "over max gross"), ("over_power", "power"), ("over_speed", "speed"),
                          ("reserve_ok", "reserve"), ("tank_ok", "tank")):
            failing = "false" if key.endswith("_ok") else "true"
            bad = sum(r.get(key) == failing for r in rows)
            if bad:
                reasons.append(f"{bad} {word}")
        text += f" (not: {', '.join(reasons) or 'unknown energy'})"
    say(text)


def replayed(path: Path) -> None:
    sm = json.loads(path.read_text(encoding="utf-8"))
    unit = sm.get("unit", "kWh")
    text = (f"{sm.get('candidate', '?')} on {sm.get('vehicles', '?')} logged vehicles' {sm.get('duties', '?')} duties: "
            f"{sm.get('completes', '?')} complete with the reserve kept, {sm.get('completes_at_confidence', '?')} at "
            f"probability {sm.get('confidence', float('nan')):g}")
    need = sm.get(f"battery_for_target_{unit}")
    need_c = sm.get(f"battery_for_target_{unit}_at_confidence")
    if need is not None:
        text += (f"; {100 * sm.get('target_share', 0):.0f} % of them need a {need:,.0f} {unit} battery at the mean"
                 + (f", {need_c:,.0f} {unit} at probability {sm.get('confidence', float('nan')):g}"
                    if need_c is not None and need_c == need_c else "")
                 + f" (it has {sm.get(f'capacity_{unit}', float('nan')):,.0f})")
    say(text)


def timetabled(path: Path) -> None:
    rows = list(csv.DictReader(path.open(encoding="utf-8", newline="")))
    if not rows:
        return
    ev = bool(rows[0].get("energy_kwh"))
    key, unit = ("energy_kwh", "kWh") if ev else ("fuel_l", "l")
    energy = [number(r.get(key)) or 0.0 for r in rows]
    km = sum(number(r.get("distance_km")) or 0.0 for r in rows)
    p = [number(r.get("p_complete")) for r in rows]
    inferred = sum(r.get("block_from") == "inferred" for r in rows)
    say(f"{rows[0].get('vehicle_key', '?')} on {len(rows)} block-days ({inferred} inferred) of "
        f"{len({r.get('date') for r in rows})} date(s): {sum(r.get('completes') == 'true' for r in rows)} complete "
        f"with the reserve kept, {sum(x is not None and x >= 0.95 for x in p)} at probability 0.95; "
        f"{min(energy):,.1f}-{max(energy):,.1f} {unit} a block, {sum(energy) / km if km else float('nan'):.2f} "
        f"{unit}/km; driving {rows[0].get('driving_from', '?').split(',')[0]}")


def main(out: Path) -> None:
    print("== summary")
    files = sorted(out.glob("*.toml"))
    if files:
        print("calibrated (each vehicle's model from its own measured trips):")
        for path in files:
            calibrated(path)
    preds = sorted(out.glob("predict-*.csv"))
    if preds:
        print("predictions:")
        for path in preds:
            predicted(path)
    replays = sorted(out.glob("replay-*.json"))
    if replays:
        print("replayed (a candidate vehicle on the logged days):")
        for path in replays:
            replayed(path)
    blocks = out / "gtfs-blocks.csv"
    if blocks.exists():
        print("timetabled (the buses' GTFS timetable, blocks run with a candidate):")
        timetabled(blocks)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "out"))
