#!/usr/bin/env bash
# The main job on the shipped sample logs: ingest (with the operator's trip loads),
# calibrate (the terms chosen by cross-validation), predict.
#   bash sample_logs/main-job.sh            (after: pip install -e .)
# Writes the store and results under out/ (set CEVM_STORE to put the store elsewhere).
# Idempotent: run it again and ingest finds every file unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
CEVM=${CEVM:-cevm}
command -v "$CEVM" >/dev/null || CEVM=.venv/bin/cevm
export CEVM_STORE=${CEVM_STORE:-out/sample.sqlite}
mkdir -p out

echo "== 1. ingest: srf and portal logs, road elevation from the DSM tiles, the buses' passenger loads"
$CEVM ingest sample_logs/srf sample_logs/portal --dsm sample_logs/dsm --manifest sample_logs/manifests/bus-loads.csv
echo "== 1b. the portal trucks log no weight: their gross masses from the operator's TMS export"
$CEVM trips set-mass --manifest sample_logs/manifests/portal-tms.csv

echo "== 2. calibrate: bus EB-01 and trucks HGV-11 and KX19 LMR against what they measured"
$CEVM calibrate -v configs/vehicles/electric-bus.toml --vehicle-id EB-01 \
      --out out/electric-bus-EB-01.toml --force --plot out/calibration-EB-01.png
$CEVM calibrate -v configs/vehicles/diesel-hgv.toml --vehicle-id HGV-11 \
      --out out/diesel-hgv-HGV-11.toml --force --plot out/calibration-HGV-11.png
$CEVM calibrate -v configs/vehicles/diesel-hgv.toml --vehicle-id "KX19 LMR" \
      --out out/diesel-hgv-KX19-LMR.toml --force

echo "== 3. predict: the calibrated vehicles on the other bus's and the other truck's trips (at their own masses"
echo "      and temperatures, measured beside modelled), then a winter cycle and the bus's range"
$CEVM predict -v out/electric-bus-EB-01.toml --vehicle-id EB-02
$CEVM predict -v out/diesel-hgv-HGV-11.toml --vehicle-id HGV-21
$CEVM predict -v out/electric-bus-EB-01.toml --cycle configs/cycles/urban-bus.csv --payload-kg 0:5000:2500 \
      --ambient-c -5 --range
echo "results: out/ (calibrated vehicle files, plots); store: $CEVM_STORE"
