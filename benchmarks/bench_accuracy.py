"""Real-world accuracy and honest ranges: every vehicle of sample_logs/ and the Twizy
logs, calibrated as `cevm calibrate` does, cross-validated with their intervals, and the
sample buses calibrated on one season and predicting the other.

    python benchmarks/bench_accuracy.py [--twizy PATH] [--markdown] [--no-fleet] [--no-seasons]

For each vehicle the trips are ingested as a user would (``cevm ingest``: sample logs
with their DSM tiles, the Twizy logs without), then calibrated as ``cevm calibrate``
does by default (:func:`cevm.core.calibration.select`: every supported term set, grouped
cross-validation over days, the one-standard-error choice, nested cross-validation of
the choice). Printed per vehicle: the trips, the cross-validated mean and sigma of the
per-trip error e = (modelled - measured) / measured of eta alone (the paper's model),
of the best candidate of each size, of the chosen model, and the nested sigma (the
honest figure for the procedure), the share of held-out trips inside their 90 %
interval (coverage; at 50 / 80 / 95 % too) and the intervals' mean width [% of the
measured]; then the paper's tables 1 and 2 for comparison.

Season split (the buses, whose six days run from -6 to 30 degC): each bus calibrated on
its summer days (May to September) predicts its other days with
:func:`cevm.core.predictive.predictive` (the calibrated file's posterior), and the
reverse: mean and worst error, and the share of those trips inside their 90 % interval.
For comparison, the same split with the calibration before priors and intervals
(the figures on real logs: a summer-only calibration predicted the winter trips
27 % low, a winter-only one the summer trips 27 % high).

Vehicles: EB-* with configs/vehicles/electric-bus.toml, HGV-* and the portal trucks
with diesel-hgv.toml in "no-credit" braking (the trucks of the portal export record no
gross weight: they are fitted at the file's mass, and say so), the Twizy with
renault-twizy.toml.

With the Twizy logs, a candidate written from the Twizy's spec sheet and never calibrated
(:func:`spec_sheet`: class, masses, CdA, Cr, battery, power, at three drive efficiencies a
buyer might write) predicts the logged trips: the share inside their 90 % intervals and the
mean error (what a file leaves out takes its class's prior).

Then the paper's fleet case study (configs/fleet/paper-case-study.toml) is planned
twice: with the paper's diesel model (eq. 24, eta 0.45) and with the diesel model
calibrated on HGV-11 by the selection above, and the assignments are compared (does the
choice of who serves the shared stops move?). Nothing is tuned to table 4.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cevm.core.calibration import CalibrationError, select  # noqa: E402
from cevm.ingest import IngestOptions, ingest  # noqa: E402
from cevm.io import load_vehicle  # noqa: E402
from cevm.store import TripStore  # noqa: E402
from cevm.store.calibration import trips_for_calibration  # noqa: E402

PAPER = {"ev": ("paper, electric bus (table 1)", 0.4, 4.0), "ice": ("paper, diesel HGV (table 2)", 1.3, 3.7)}


def vehicle_file(vehicle_id: str) -> tuple[Path, str | None]:
    vehicles = ROOT / "configs" / "vehicles"
    if vehicle_id.startswith("EB-"):
        return vehicles / "electric-bus.toml", None
    if "twizy" in vehicle_id.lower():
        return vehicles / "renault-twizy.toml", None
    return vehicles / "diesel-hgv.toml", "no-credit"


def calibrate_store(store_path: Path, label: str) -> list[dict]:
    rows = []
    with TripStore.open(store_path) as st:
        ids = st.vehicle_ids()
        for vid in ids:
            path, braking = vehicle_file(vid)
            veh = load_vehicle(path)
            if braking:
                veh = dataclasses.replace(veh, ice_braking=braking)
            sel_trips = trips_for_calibration(st, vid, veh)
            t0 = time.perf_counter()
            try:
                sel = select(veh, sel_trips.trips, time_repeats=0, vehicle_id=vid)
            except CalibrationError as exc:
                rows.append({"set": label, "vehicle": vid, "error": str(exc)})
                continue
            dt = time.perf_counter() - t0
            ok = [c for c in sel.candidates if c.ok]
            eta = next((c for c in sel.candidates if c.terms == ("eta",)), None) or _eta_only(veh, sel_trips.trips)
            best_by_k = {}
            for c in ok:
                k = len(c.terms)
                if k not in best_by_k or c.mse < best_by_k[k].mse:
                    best_by_k[k] = c
            rows.append({
                "trips_data": sel_trips.trips, "veh": veh, "vehicle_path": path, "braking": braking,
                "store": str(store_path),
                "set": label, "vehicle": vid, "powertrain": veh.powertrain,
                "trips": sel.result.cv.n if sel.result.cv else 0,
                "eta_only": eta, "best_by_k": best_by_k, "chosen": sel.chosen, "result": sel.result,
                "nested": sel.nested_cv, "seconds": dt, "n_candidates": len(sel.candidates), "n_ok": len(ok),
                "standstill": sel.chosen_standstill,
                "notes": sel_trips.notes + sel.notes,
            })
    return rows


def _eta_only(veh, trips):
    """The paper's model (eta alone, every other term out, no prior) cross-validated as
    a candidate is, for the comparison column (its standstill check not applied: with
    priors it is no candidate)."""
    from types import SimpleNamespace

    from cevm.core.calibration.candidate import Settings, fit_candidate
    from cevm.core.calibration.data import select_trips
    from cevm.core.calibration.terms import TermModel, neutral
    from cevm.core.calibration.validation import ErrorStats

    base = dataclasses.replace(neutral(veh), priors=None)
    data, _ = select_trips(base, trips, 0.10, 1000.0, 0.001)
    model = TermModel(base, data)
    cf = fit_candidate(model, ("eta",), np.arange(data.n), None, Settings())
    return SimpleNamespace(cv=ErrorStats.of(cf.cv_error_pct()))


def _ms(stats) -> str:
    if stats is None or stats.n == 0:
        return "-"
    return f"{stats.mean_pct:+.1f} / {stats.std_pct:.1f} %"


def print_table(rows: list[dict], markdown: bool) -> None:
    head = ["set", "vehicle", "trips", "eta only (paper's model)", "chosen terms", "chosen CV mu / sigma",
            "nested sigma", "90 % interval: held-out inside", "mean width", "at 50 / 80 / 95 %",
            "candidates ok of", "s"]
    lines = []
    for r in rows:
        if "error" in r:
            lines.append([r["set"], r["vehicle"], "-", r["error"][:60], "", "", "", "", "", ""])
            continue
        res = r["result"]
        inside = [row.inside for row in res.rows if row.inside is not None]
        cov = res.coverage
        lines.append([r["set"], r["vehicle"], str(r["trips"]), _ms(r["eta_only"].cv if r["eta_only"] else None),
                      "+".join(r["chosen"]) + (" (standstill)" if r["standstill"] else ""), _ms(res.cv),
                      "-" if r["nested"] is None else f"{r['nested'].std_pct:.1f} %",
                      f"{sum(inside)} of {len(inside)} ({100 * cov.get(0.9, float('nan')):.0f} %)",
                      f"{res.mean_rel_width_pct:.1f} %",
                      " / ".join(f"{100 * cov[k]:.0f}" for k in (0.5, 0.8, 0.95) if k in cov) + " %",
                      f"{r['n_ok']} of {r['n_candidates']}", f"{r['seconds']:.2f}"])
    for name, mu, sd in PAPER.values():
        lines.append(["paper", name, "", "", "eta", f"{mu:+.1f} / {sd:.1f} %", "", "", "", "", "", ""])
    _print_lines(head, lines, markdown)
    for r in rows:
        for note in r.get("notes", ()):
            print(f"  {r['vehicle']}: {note}")


def _month(trip) -> int:
    return int(str(np.datetime64(int(trip.start_utc_s), "s"))[5:7])


def season_split(rows: list[dict], markdown: bool, baseline_src: Path | None) -> None:
    """Each bus calibrated on its summer (winter) days predicts its winter (summer) days."""
    from cevm.core.predictive import Features, predictive

    lines = []
    for r in rows:
        if "result" not in r or not r["vehicle"].startswith("EB-"):
            continue
        trips, veh = r["trips_data"], r["veh"]
        summer = [t for t in trips if 5 <= _month(t) <= 9]
        winter = [t for t in trips if not 5 <= _month(t) <= 9]
        for name, train, test in (("summer -> winter", summer, winter), ("winter -> summer", winter, summer)):
            sel = select(veh, train, time_repeats=0, vehicle_id=r["vehicle"], nested=False)
            v = sel.result.vehicle
            err, inside, width = [], [], []
            for t in test:
                p = predictive(v, Features.of(t.vector, v, [t.mass_kg], [t.ambient_c]))
                lo, hi = p.interval(0.9)
                err.append((p.mean[0] - t.measured) / t.measured * 100.0)
                inside.append(bool(lo[0] <= t.measured <= hi[0]))
                width.append((hi[0] - lo[0]) / t.measured * 100.0)
            err = np.array(err)
            old = _baseline_split(baseline_src, r, train, test)
            lines.append([r["vehicle"], name, f"{len(train)} / {len(test)}", "+".join(sel.chosen),
                          f"{err.mean():+.1f} %", f"{err[np.argmax(np.abs(err))]:+.1f} %",
                          f"{sum(inside)} of {len(inside)}", f"{np.mean(width):.0f} %", old])
    head = ["bus", "calibrated on -> predicts", "trips", "model", "mean error", "worst", "inside 90 %",
            "mean width", "before (mean / worst error, no interval)"]
    print()
    _print_lines(head, lines, markdown)


def _baseline_split(src: Path | None, r: dict, train, test) -> str:
    """The same split with the calibration of another checkout (``--baseline-src``), in a
    subprocess: mean and worst error."""
    if src is None:
        return "-"
    import pickle
    import subprocess

    ids = ({t.trip_id for t in train}, {t.trip_id for t in test})
    path = Path(r["vehicle_path"]).resolve()
    with contextlib.suppress(ValueError):  # the baseline's own copy of a shipped file (its format may be older)
        own = src.resolve().parent / path.relative_to(ROOT.resolve())
        path = own if own.is_file() else path
    payload = pickle.dumps((str(path), r["braking"], r["store"], r["vehicle"], ids))
    code = """
import pickle, sys, dataclasses
import numpy as np
sys.path.insert(0, %r)
from cevm.core.calibration import select
from cevm.core.vehicle import predict
from cevm.io import load_vehicle
from cevm.store import TripStore
from cevm.store.calibration import trips_for_calibration
path, braking, store, vid, (tr, te) = pickle.loads(sys.stdin.buffer.read())
veh = load_vehicle(path)
if braking: veh = dataclasses.replace(veh, ice_braking=braking)
with TripStore.open(store, readonly=True) as st: trips = trips_for_calibration(st, vid, veh).trips
v = select(veh, [t for t in trips if t.trip_id in tr], time_repeats=0, nested=False).result.vehicle
e = np.array([(float(predict(t.vector, v, t.mass_kg, ambient_c=t.ambient_c).energy_j) - t.measured) / t.measured * 100
              for t in trips if t.trip_id in te])
print(f"{e.mean():+.1f} / {e[np.argmax(np.abs(e))]:+.1f} %")
""".replace("%r", repr(str(src)))
    res = subprocess.run([sys.executable, "-c", code], input=payload, capture_output=True)
    return res.stdout.decode().strip() or ("failed: " + res.stderr.decode().strip().splitlines()[-1][:60])


def _print_lines(head, lines, markdown: bool) -> None:
    if markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for line in lines:
            print("| " + " | ".join(line) + " |")
        return
    widths = [max(len(h), *(len(line[i]) for line in lines)) if lines else len(h) for i, h in enumerate(head)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)))
    for line in lines:
        print("  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)))


def fleet_comparison(hgv_result) -> None:
    """The paper's case study under the paper's diesel model and under the calibrated one."""
    from cevm.core.assignment import plan, table4_rows
    from cevm.io.scenario import load_scenario

    path = ROOT / "configs" / "fleet" / "paper-case-study.toml"
    sc = load_scenario(path)
    calibrated = hgv_result.vehicle
    # the calibrated model on the paper's vehicle: the fitted terms, the scenario's masses
    fleet = []
    for fv in sc.vehicles:
        v = dataclasses.replace(calibrated, kerb_mass_kg=fv.vehicle.kerb_mass_kg, mass_kg=fv.vehicle.mass_kg,
                                max_gross_kg=fv.vehicle.max_gross_kg, tank_l=fv.vehicle.tank_l, calibration=None)
        fleet.append(dataclasses.replace(fv, vehicle=v))
    sc2 = dataclasses.replace(sc, vehicles=tuple(fleet))
    for label, scen in (("paper's diesel model (eq. 24, eta 0.45)", sc),
                        (f"calibrated on HGV-11 ({'+'.join(hgv_result.terms)}, no-credit)", sc2)):
        plans = [plan(scen, d) for d in scen.days]
        print(f"\n{label}:")
        for row in table4_rows(plans):
            print("  " + row["vehicle"] + ": " + " | ".join(f"{d}: {row[d]}" for d in scen.days))
        print("  totals: " + ", ".join(f"{p.day} {p.total:.2f} l (saving {p.saving_pct or 0:.2f} %)" for p in plans))


#: A Renault Twizy 80 as a buyer knows it from its spec sheet (class, masses, CdA, Cr, a
#: generic drive efficiency, battery, power): no auxiliary, heating or A/C keys, and not
#: the eta calibrated on the logs (0.63).
SPEC_TWIZY = {"name": "Twizy spec sheet", "powertrain": "ev", "class": "quadricycle", "kerb_mass_kg": 474.0,
              "payload_kg": 80.0, "max_gross_kg": 690.0, "cda_m2": 0.90, "cr": 0.010, "battery_kwh": 6.1,
              "max_power_kw": 13.0, "max_speed_kmh": 80.0}


def spec_sheet(store_path: Path, vehicle_id: str = "RSK-Twizy", etas=(0.70, 0.75, 0.80)) -> None:
    """A spec-sheet candidate (:data:`SPEC_TWIZY`) never calibrated, on the logged trips
    at the file's mass and each trip's temperature: the share of trips inside their 90 %
    interval, of the cold ones (below 10 degC), and the mean error, for a few efficiencies
    a buyer might write (the class's priors fill what the file leaves out)."""
    from cevm.core.predictive import Features, predictive
    from cevm.io.vehicles import vehicle_from_mapping

    print("\nspec-sheet candidate (never calibrated) on the logged trips:")
    with TripStore.open(store_path, readonly=True) as st:
        base = vehicle_from_mapping({**SPEC_TWIZY, "eta": etas[0]})
        trips = trips_for_calibration(st, vehicle_id, base).trips
    for eta in etas:
        v = vehicle_from_mapping({**SPEC_TWIZY, "eta": eta})
        inside, cold, err = [], [], []
        for t in trips:
            temp = t.ambient_c if np.isfinite(t.ambient_c) else None
            p = predictive(v, Features.of(t.vector, v, None, temp))
            lo, hi = p.interval(0.9)
            inside.append(bool(lo <= t.measured <= hi))
            cold.append(temp is not None and temp < 10.0)
            err.append((float(p.mean) - t.measured) / t.measured * 100.0)
        inside_a, cold_a = np.array(inside), np.array(cold)
        cold_txt = f"{inside_a[cold_a].mean():.0%} of {cold_a.sum()} cold" if cold_a.any() else "no cold trip"
        print(f"  eta {eta:.2f} (from priors: {'+'.join(v.from_prior) or 'none'}): {inside_a.mean():.0%} of "
              f"{len(trips)} trips inside their 90 % interval ({cold_txt}), mean error {np.mean(err):+.1f} %")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--twizy", default=str(ROOT.parent / "shared" / "real-logs" / "twizy"),
                    help="directory of the Twizy logs (skipped when absent)")
    ap.add_argument("--markdown", action="store_true", help="print the table as Markdown (for the README)")
    ap.add_argument("--no-fleet", action="store_true", help="skip the fleet case study")
    ap.add_argument("--no-seasons", action="store_true", help="skip the season split of the buses")
    ap.add_argument("--baseline-src", default=None,
                    help="a checkout's src/ whose calibration the season split is compared with (e.g. a worktree "
                         "of the round's starting code)")
    ap.add_argument("--no-manifests", action="store_true",
                    help="calibrate the sample vehicles without the manifests' masses (buses and portal trucks at "
                         "the vehicle file's mass)")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        sample = Path(tmp) / "sample.sqlite"
        with TripStore.open(sample) as st:
            ingest([ROOT / "sample_logs" / "srf", ROOT / "sample_logs" / "portal"], st,
                   IngestOptions(dsm=str(ROOT / "sample_logs" / "dsm")))
            if not args.no_manifests:  # the operator's loads: the buses' counts, the portal trucks' TMS
                from cevm.io.manifest import read_manifest
                from cevm.store.masses import match_manifest, set_masses

                for name in ("bus-loads.csv", "portal-tms.csv"):
                    set_masses(st, match_manifest(st, read_manifest(ROOT / "sample_logs" / "manifests" / name)).masses)
        rows += calibrate_store(sample, "sample_logs")
        twizy = Path(args.twizy)
        if twizy.is_dir():
            tw = Path(tmp) / "twizy.sqlite"
            with TripStore.open(tw) as st:
                ingest([twizy], st, IngestOptions())
            rows += calibrate_store(tw, "twizy (real)")
        print_table(rows, args.markdown)
        if twizy.is_dir():
            spec_sheet(tw)
        if not args.no_seasons:  # in the store's lifetime: the baseline reads it
            season_split(rows, args.markdown, None if args.baseline_src is None else Path(args.baseline_src))
    if not args.no_fleet:
        hgv = next((r for r in rows if r.get("vehicle") == "HGV-11" and "result" in r), None)
        if hgv is not None:
            fleet_comparison(hgv["result"])


if __name__ == "__main__":
    main()
