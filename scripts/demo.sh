#!/usr/bin/env bash
# The main job on built-in data: simulate a projector-camera rig (a curved, textured surface),
# capture a calibration set through it, train the `linear` compensation model, evaluate it, write
# compensation images and score them closed-loop on the rig against the physical ceiling.
#   bash scripts/demo.sh [OUT_DIR] [SCENE] [SEED]      (defaults: ./demo curved 1)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-demo}
scene=${2:-curved}
seed=${3:-1}
bash scripts/deps.sh
cargo build --release --locked
c=target/release/compend
setup="$out/data/$scene"
set -x
"$c" sim export --scene "$scene" --out "$out/data" --ntrain 48 --ntest 10 --seed "$seed"
"$c" inspect --setup "$setup" --out "$out/inspect"
"$c" train --setup "$setup" --method linear --out "$out/models/linear"
"$c" eval --model "$out/models/linear" --setup "$setup"
"$c" compensate --model "$out/models/linear" --input "$setup/cam/desire/test" \
    --out "$setup/prj/cmp/test/linear"
"$c" sim score --setup "$setup"
"$c" sim sheet --scene "$scene" --out "$out/sheets"
set +x
echo "demo: pictures in $out/inspect (FOV mask, displayable area), $out/sheets (the scene)," \
     "$setup/prj/cmp/test/linear (compensation images)"
