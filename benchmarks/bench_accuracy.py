"""Real-world accuracy: every vehicle of sample_logs/ and the Twizy logs, calibrated
with each candidate term set, cross-validated side by side with eta alone and the paper.

    python benchmarks/bench_accuracy.py [--twizy PATH] [--markdown] [--no-fleet]

For each vehicle the trips are ingested as a user would (``cevm ingest``: sample logs
with their DSM tiles, the Twizy logs without), then calibrated as ``cevm calibrate``
does by default (:func:`cevm.core.calibration.select`: every supported term set, grouped
cross-validation over days, the one-standard-error choice, nested cross-validation of
the choice). Printed per vehicle: the trips, the cross-validated mean and sigma of the
per-trip error e = (modelled - measured) / measured of eta alone (the paper's model),
of the best candidate of each size, of the chosen model, and the nested sigma (the
honest figure for the procedure); then the paper's tables 1 and 2 for comparison.

Vehicles: EB-* with configs/vehicles/electric-bus.toml, HGV-* and the portal trucks
with diesel-hgv.toml in "no-credit" braking (the trucks of the portal export record no
gross weight: they are fitted at the file's mass, and say so), the Twizy with
renault-twizy.toml.

Then the paper's fleet case study (configs/fleet/paper-case-study.toml) is planned
twice: with the paper's diesel model (eq. 24, eta 0.45) and with the diesel model
calibrated on HGV-11 by the selection above, and the assignments are compared (does the
choice of who serves the shared stops move?). Nothing is tuned to table 4.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

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
            eta = next((c for c in sel.candidates if c.terms == ("eta",)), None)
            best_by_k = {}
            for c in ok:
                k = len(c.terms)
                if k not in best_by_k or c.mse < best_by_k[k].mse:
                    best_by_k[k] = c
            rows.append({
                "set": label, "vehicle": vid, "powertrain": veh.powertrain, "trips": sel.result.cv.n if sel.result.cv else 0,
                "eta_only": eta, "best_by_k": best_by_k, "chosen": sel.chosen, "result": sel.result,
                "nested": sel.nested_cv, "seconds": dt, "n_candidates": len(sel.candidates), "n_ok": len(ok),
                "notes": sel_trips.notes + sel.notes,
            })
    return rows


def _ms(stats) -> str:
    if stats is None or stats.n == 0:
        return "-"
    return f"{stats.mean_pct:+.1f} / {stats.std_pct:.1f} %"


def print_table(rows: list[dict], markdown: bool) -> None:
    head = ["set", "vehicle", "trips", "eta only (paper's model)", "chosen terms", "chosen CV mu / sigma",
            "nested sigma", "best 2 / 3 / 4 terms (sigma)", "candidates ok of", "s"]
    lines = []
    for r in rows:
        if "error" in r:
            lines.append([r["set"], r["vehicle"], "-", r["error"][:60], "", "", "", "", "", ""])
            continue
        res = r["result"]
        best = " / ".join(f"{'+'.join(r['best_by_k'][k].terms[1:]) or '-'} {r['best_by_k'][k].cv.std_pct:.1f}"
                          for k in (2, 3, 4) if k in r["best_by_k"])
        lines.append([r["set"], r["vehicle"], str(r["trips"]), _ms(r["eta_only"].cv if r["eta_only"] else None),
                      "+".join(r["chosen"]), _ms(res.cv), "-" if r["nested"] is None else f"{r['nested'].std_pct:.1f} %",
                      best or "-", f"{r['n_ok']} of {r['n_candidates']}", f"{r['seconds']:.2f}"])
    for pt, (name, mu, sd) in PAPER.items():
        lines.append(["paper", name, "", "", "eta", f"{mu:+.1f} / {sd:.1f} %", "", "", "", ""])
    if markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for line in lines:
            print("| " + " | ".join(line) + " |")
    else:
        widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(head)]
        print("  ".join(h.ljust(w) for h, w in zip(head, widths)))
        for line in lines:
            print("  ".join(c.ljust(w) for c, w in zip(line, widths)))
    for r in rows:
        for note in r.get("notes", ()):
            print(f"  {r['vehicle']}: {note}")


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


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--twizy", default=str(ROOT.parent / "shared" / "real-logs" / "twizy"),
                    help="directory of the Twizy logs (skipped when absent)")
    ap.add_argument("--markdown", action="store_true", help="print the table as Markdown (for the README)")
    ap.add_argument("--no-fleet", action="store_true", help="skip the fleet case study")
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
    if not args.no_fleet:
        hgv = next((r for r in rows if r.get("vehicle") == "HGV-11" and "result" in r), None)
        if hgv is not None:
            fleet_comparison(hgv["result"])


if __name__ == "__main__":
    main()
