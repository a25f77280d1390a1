#!/bin/sh
# Re-make the shipped vehicle segmenter: data, two training stages, export into the package (see README.md).
# Usage: nice -n 5 training/vehicleseg/reproduce.sh WORKDIR [STAGE2_STEPS]
set -eu
cd "$(dirname "$0")/../.."
W="${1:?usage: reproduce.sh WORKDIR [STAGE2_STEPS]}"
STEPS2="${2:-4000}"
PY=.venv/bin/python
$PY -m training.vehicleseg.data --out "$W/data" --scenes 0:150 --duration 10
[ -f "$W/stage1/final.pt" ] || $PY -m training.vehicleseg.train --data "$W/data" --out "$W/stage1" --steps 2000
[ -f "$W/stage2/final.pt" ] || $PY -m training.vehicleseg.train --data "$W/data" --out "$W/stage2" \
    --init "$W/stage1/final.pt" --steps "$STEPS2" --lr 2e-3 --seed 1
$PY -m training.vehicleseg.export --checkpoint "$W/stage2/final.pt" \
    --out gst_trafficcal/detection/weights/vehicleseg.onnx
