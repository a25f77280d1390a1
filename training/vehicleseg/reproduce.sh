#!/bin/sh
# Re-make the shipped vehicle segmenter: v2 (asphalt roads: data, two training stages), then v3 (fine-tuned on
# roads from dark asphalt to light concrete), export into the package (see README.md).
# Usage: nice -n 5 training/vehicleseg/reproduce.sh WORKDIR [STAGE2_STEPS]
set -eu
cd "$(dirname "$0")/../.."
W="${1:?usage: reproduce.sh WORKDIR [STAGE2_STEPS]}"
STEPS2="${2:-4000}"
PY=.venv/bin/python
[ -f "$W/data/scene_00149.json" ] || $PY -m training.vehicleseg.data --out "$W/data" --scenes 0:150 --duration 10 --surfaces asphalt
[ -f "$W/stage1/final.pt" ] || $PY -m training.vehicleseg.train --data "$W/data" --out "$W/stage1" --steps 2000 \
    --shadow-weight 0 --boundary-weight 1
[ -f "$W/stage2/final.pt" ] || $PY -m training.vehicleseg.train --data "$W/data" --out "$W/stage2" \
    --init "$W/stage1/final.pt" --steps "$STEPS2" --lr 2e-3 --seed 1 --shadow-weight 0 --boundary-weight 1
[ -f "$W/data3/scene_00119.json" ] || $PY -m training.vehicleseg.data --out "$W/data3" --scenes 0:120 --duration 10
[ -f "$W/stage3/final.pt" ] || $PY -m training.vehicleseg.train --data "$W/data3" --out "$W/stage3" \
    --init "$W/stage2/final.pt" --steps 3000 --lr 1e-3 --freeze-bn
$PY -m training.vehicleseg.export --checkpoint "$W/stage3/final.pt" \
    --out gst_trafficcal/detection/weights/vehicleseg.onnx
