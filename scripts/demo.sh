#!/usr/bin/env bash
# The main job on the built-in virtual rig (a simulated projector, a curved textured surface and a
# camera with 2 frames of delay and dropped frames): `compend calibrate` measures the latency,
# projects and captures the calibration patterns, trains the `linear` model, verifies it on
# held-out images and installs it; `compend play` then compensates a moving test pattern on the
# rig. Finally the installed model is scored closed-loop against the physical ceiling. A set's
# scene (`tiled`, `stacked`) is calibrated as a whole and its joint model played on its rig.
#   bash scripts/demo.sh [OUT_DIR] [SCENE] [SEED]      (defaults: ./demo curved 1)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-demo}
scene=${2:-curved}
seed=${3:-1}
bash scripts/deps.sh
cargo build --release --locked
c=${CARGO_TARGET_DIR:-target}/release/compend
set -x
"$c" calibrate --rig "virtual:$scene" --seed "$seed" --data "$out/calibration" --out "$out/model"
if [ -f "$out/model/set.json" ]; then
  # A set of projectors (`tiled`, `stacked`): its joint model plays on the set's virtual rig;
  # the set's verification (in calibrate's output above, and set.json) is its score.
  "$c" play --model "$out/model" --source 'pattern:moving?frames=30' --rig "virtual:$scene" \
      --seed "$seed" --out "$out/play"
  "$c" sim sheet --scene "$scene" --out "$out/sheets"
  set +x
  echo "demo: the set's model in $out/model (set.json records the set's verification, each" \
       "projector-N/model.json its own), camera views of playback in $out/play, the scene in" \
       "$out/sheets"
  exit 0
fi
"$c" eval --model "$out/model" --setup "$out/calibration/capture"
"$c" inspect --setup "$out/calibration/capture" --out "$out/inspect"
"$c" play --model "$out/model" --source 'pattern:moving?frames=30' --rig "virtual:$scene" \
    --seed "$seed" --out "$out/play" --pace source
# Closed loop against the physical ceiling: the same scene and seed exported with its oracle, the
# camera exposed and the desired images scaled as calibrate did for the model, each capture the
# mean of 3 frames as calibrate averages them.
setup="$out/score/$scene"
"$c" sim export --scene "$scene" --out "$out/score" --ntrain 4 --ntest 10 --seed "$seed" \
    --as-calibrated "$out/model"
"$c" compensate --model "$out/model" --input "$setup/cam/desire/test" \
    --out "$setup/prj/cmp/test/calibrated"
"$c" sim score --setup "$setup" --average 3
"$c" sim sheet --scene "$scene" --out "$out/sheets"
set +x
echo "demo: model in $out/model (model.json records the calibration), camera views of playback" \
     "in $out/play, FOV and displayable area in $out/inspect, the scene in $out/sheets"
