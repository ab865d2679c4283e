#!/usr/bin/env bash
# The CompenNet backbone's convolution kernels on a GPU: correctness on the real adapter, then
# `direct`, `tiled` and `measured` alternated, on the synthetic backbone and on a trained
# `compennet++-res-full` model's whole pass (docs/bench/gpu-h100.md).
#
#   OUT=DIR [COMPEND=path/to/compend] [INTEGRATION=path/to/test-binary] scripts/gpu_conv_check.sh
#
# COMPEND defaults to target/release/compend. INTEGRATION, when given, is the integration test
# binary (`cargo test --no-run --test integration`); its in-process GPU tests run first with
# COMPEND_REQUIRE_GPU_ADAPTER=1. QUICK=1 shrinks everything for a dry run on lavapipe.
# Everything is written under OUT: one folder per bench-gpu run (bench-gpu.json, .md, the log).
# Each command has its own timeout; run the whole under one (`timeout 540`) on a lent machine.
set -u
: "${OUT:?set OUT to a folder for the results}"
B=${COMPEND:-target/release/compend}
W=${QUICK:+2}; W=${W:-100}
N=${QUICK:+2}; N=${N:-30}
SIZES=${QUICK:+160x120}; SIZES=${SIZES:-640x480,1920x1080,3840x2160}
RSIZES=${QUICK:+160x120}; RSIZES=${RSIZES:-1920x1080,3840x2160}
PRJ=${QUICK:+320x240}; PRJ=${PRJ:-1920x1080}
NET=${QUICK:+64x64}; NET=${NET:-256x256}
SECONDS_PLAY=${QUICK:+0}; SECONDS_PLAY=${SECONDS_PLAY:-2}
S=$OUT/scratch
mkdir -p "$S"
{ nvidia-smi --query-gpu=name,driver_version,clocks.max.sm --format=csv 2>&1 || true; nproc; } \
  > "$OUT/machine.txt"
if [ -n "${INTEGRATION:-}" ]; then
  echo "== GPU tests $(date +%T)"
  COMPEND_REQUIRE_GPU_ADAPTER=1 timeout 120 "$INTEGRATION" gpu::compennet_layers_match_candle \
    gpu::compennet_pass_matches gpu::residual_pass_matches gpu::linear_pass_matches \
    gpu::pass_is_reused --test-threads 2 --nocapture > "$OUT/tests.txt" 2>&1
  echo "tests: exit $?"
  grep -E "^test |test result|measured kernels" "$OUT/tests.txt"
fi
echo "== synthetic backbone $(date +%T)"
for r in 1 2; do
  for k in direct tiled measured; do
    L=""
    [ "$r" = 1 ] && L=--layers
    d=$OUT/synthetic-$k-$r
    mkdir -p "$d"
    timeout 90 "$B" bench-gpu --out "$d" --sizes "$SIZES" --network "$NET" --seconds 0 \
      --warmup "$W" --iters "$N" --compennet-iters "$N" --conv-kernels "$k" $L \
      > "$d/log.txt" 2>&1
    echo "synthetic $k round $r: exit $?"
    grep -E "CompenNet [0-9]" "$d/log.txt"
  done
done
echo "== a trained compennet++-res-full $(date +%T)"
timeout 60 "$B" sim export --out "$S/exp" --scene curved --seed 29 --ntrain 16 --ntest 2 \
  --projector "$PRJ" > "$OUT/export.txt" 2>&1
echo "export: exit $?"
timeout 90 "$B" train --setup "$S/exp/curved" --method compennet++-res-full --iters 3 \
  --batch 2 --out "$S/resfull" > "$OUT/train.txt" 2>&1
echo "train (3 iterations: the weights do not matter, the shapes do): exit $?"
for r in 1 2; do
  for k in direct tiled measured; do
    d=$OUT/res-full-$k-$r
    mkdir -p "$d"
    timeout 90 "$B" bench-gpu --model "$S/resfull" --out "$d" --sizes "$RSIZES" \
      --warmup "$W" --iters "$N" --compennet-iters 0 --seconds "$SECONDS_PLAY" \
      --conv-kernels "$k" > "$d/log.txt" 2>&1
    echo "res-full $k round $r: exit $?"
    grep -E "bench-gpu: [0-9]+x[0-9]+: copy" "$d/log.txt"
  done
done
rm -rf "$S"
echo "== done $(date +%T)"
