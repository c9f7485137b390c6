#!/usr/bin/env bash
# The main job on the shipped sample logs: ingest, calibrate, predict.
#   bash sample_logs/main-job.sh            (after: pip install -e .)
# Writes the store and results under out/ (set CEVM_STORE to put the store elsewhere).
# Idempotent: run it again and ingest finds every file unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
CEVM=${CEVM:-cevm}
command -v "$CEVM" >/dev/null || CEVM=.venv/bin/cevm
export CEVM_STORE=${CEVM_STORE:-out/sample.sqlite}
mkdir -p out

echo "== 1. ingest: srf and portal logs, road elevation from the DSM tiles"
$CEVM ingest sample_logs/srf sample_logs/portal --dsm sample_logs/dsm

echo "== 2. calibrate: eta of bus EB-01 and truck HGV-11 against what they measured"
$CEVM calibrate -v configs/vehicles/electric-bus.toml --vehicle-id EB-01 \
      --out out/electric-bus-EB-01.toml --force --plot out/calibration-EB-01.png
$CEVM calibrate -v configs/vehicles/diesel-hgv.toml --vehicle-id HGV-11 --ice-braking no-credit \
      --out out/diesel-hgv-HGV-11.toml --force --plot out/calibration-HGV-11.png

echo "== 3. predict: the calibrated vehicles on the other bus's and the other truck's trips"
$CEVM predict -v out/electric-bus-EB-01.toml --vehicle-id EB-02 --mass-kg 10000 --mass-kg 14000
$CEVM predict -v out/diesel-hgv-HGV-11.toml --vehicle-id HGV-21 --mass-kg 25000 --mass-kg 40000
echo "results: out/ (calibrated vehicle files, plots); store: $CEVM_STORE"
