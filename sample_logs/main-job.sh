#!/usr/bin/env bash
# The main job on the shipped sample logs: ingest (with the operator's trip loads),
# calibrate (the terms chosen by cross-validation), predict, replay the diesel trucks'
# days with a candidate electric truck, and run the buses' timetable (GTFS).
#   bash sample_logs/main-job.sh            (after: pip install -e .)
# Writes the store and results under "$OUT"/ (CEVM_OUT for another folder, CEVM_STORE for
# another store).
# Idempotent: run it again and ingest finds every file unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
CEVM=${CEVM:-cevm}
command -v "$CEVM" >/dev/null || CEVM=.venv/bin/cevm
OUT=${CEVM_OUT:-out}
export CEVM_STORE=${CEVM_STORE:-$OUT/sample.sqlite}
mkdir -p "$OUT"

echo "== 1. ingest: srf and portal logs, road elevation from the DSM tiles,"
echo "      the buses' passenger loads"
$CEVM ingest sample_logs/srf sample_logs/portal --dsm sample_logs/dsm --manifest sample_logs/manifests/bus-loads.csv
echo "== 1b. the portal trucks log no weight: their gross masses from the"
echo "       operator's TMS export"
$CEVM trips set-mass --manifest sample_logs/manifests/portal-tms.csv

echo "== 2. calibrate: bus EB-01 and trucks HGV-11 and KX19 LMR against what"
echo "      they measured"
$CEVM calibrate -v configs/vehicles/electric-bus.toml --vehicle-id EB-01 \
      --out "$OUT"/electric-bus-EB-01.toml --force --plot "$OUT"/calibration-EB-01.png
$CEVM calibrate -v configs/vehicles/diesel-hgv.toml --vehicle-id HGV-11 \
      --out "$OUT"/diesel-hgv-HGV-11.toml --force --plot "$OUT"/calibration-HGV-11.png
$CEVM calibrate -v configs/vehicles/diesel-hgv.toml --vehicle-id "KX19 LMR" \
      --out "$OUT"/diesel-hgv-KX19-LMR.toml --force

echo "== 3. predict: the calibrated vehicles on the other bus's and the other"
echo "      truck's trips (at their own masses and temperatures, measured beside"
echo "      modelled), then a winter cycle and the bus's range"
# each prediction twice: a table for this log, and every column in a CSV file for the record
predict() {
    local name=$1; shift
    $CEVM predict "$@"
    $CEVM predict "$@" --format csv --out "$OUT/predict-$name.csv" 2>/dev/null
}
predict EB-02 -v "$OUT"/electric-bus-EB-01.toml --vehicle-id EB-02
predict HGV-21 -v "$OUT"/diesel-hgv-HGV-11.toml --vehicle-id HGV-21
predict winter -v "$OUT"/electric-bus-EB-01.toml --cycle configs/cycles/urban-bus.csv --payload-kg 0:5000:2500 \
      --ambient-c -5 --range

echo "== 4. replay: the diesel trucks' logged days with a candidate battery-electric"
echo "      tractor (590 kWh usable), charged full at the depot overnight; then"
echo "      without any depot charge (the level carried from day to day); then with"
echo "      a 120 kWh battery, and with it a 150 kW charger at any stop of 30 min+"
TRUCKS=(--vehicle-id HGV-11 --vehicle-id HGV-21 --vehicle-id "KX19 LMR" --vehicle-id "KX19 LMT")
$CEVM replay -v configs/vehicles/electric-truck.toml "${TRUCKS[@]}" --plot "$OUT"/replay-electric-truck.png \
      --summary "$OUT"/replay-electric-truck.json
$CEVM replay -v configs/vehicles/electric-truck.toml "${TRUCKS[@]}" --overnight none
$CEVM replay -v configs/vehicles/electric-truck.toml "${TRUCKS[@]}" --battery-kwh 120
$CEVM replay -v configs/vehicles/electric-truck.toml "${TRUCKS[@]}" --battery-kwh 120 --charger-kw 150
echo "== 5. gtfs: the buses' timetable (sample_logs/gtfs, made by"
echo "      'python -m cevm_samplegen gtfs-feed') with the calibrated bus, the"
echo "      driving between stops learnt from EB-01's and EB-02's stored trips,"
echo "      the road from the DSM, a cold day; then the blocks and each trip as CSV"
GTFS=(sample_logs/gtfs -v "$OUT"/electric-bus-EB-01.toml --dsm sample_logs/dsm --vehicle-id EB-01 --vehicle-id EB-02
      --date 2019-01-31 --ambient-c -3)
$CEVM gtfs "${GTFS[@]}" --plot "$OUT"/gtfs-blocks.png
$CEVM gtfs "${GTFS[@]}" --format csv --out "$OUT"/gtfs-blocks.csv 2>/dev/null
$CEVM gtfs "${GTFS[@]}" --trips --format csv --out "$OUT"/gtfs-trips.csv 2>/dev/null
echo "results: $OUT/ (calibrated vehicle files, plots, predictions' CSV)"
echo "store: $CEVM_STORE"
# the summary, by the Python cevm runs on (3.11+: tomllib)
PYTHON=${PYTHON:-$(dirname "$(command -v "$CEVM")")/python}
[ -x "$PYTHON" ] || PYTHON=python3
"$PYTHON" sample_logs/job_summary.py "$OUT"
