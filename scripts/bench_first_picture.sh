#!/usr/bin/env bash
# The service's time to its first compensated picture (issue 47): `compend serve` started with
# no model on the virtual rig of config/compend.toml (another scene and seed with SCENE SEED),
# timed from its start to its "ready: playing" line (READY=1 goes with it: the first
# compensated frame presented), against the calibration it made on the way (its own total, from
# the installed model's record). Prints one line per run:
#   scene seed  first-picture-s  calibration-s  difference-s
#
#   scripts/bench_first_picture.sh [SCENE SEED]...    (default: curved 0)
# Needs a release build (cargo build --release); works in a temporary folder it removes.
set -euo pipefail
bin=${COMPEND_BIN:-$(cd "$(dirname "$0")/.." && pwd)/target/release/compend}
config=$(cd "$(dirname "$0")/.." && pwd)/config/compend.toml
[ -x "$bin" ] || { echo "bench_first_picture: $bin is not an executable (cargo build --release)" >&2; exit 2; }
[ $(( $# % 2 )) -eq 0 ] || { echo "bench_first_picture: give SCENE SEED pairs" >&2; exit 2; }
runs=("$@")
[ ${#runs[@]} -gt 0 ] || runs=(curved 0)
work=$(mktemp -d)
trap 'kill "${pid:-}" 2>/dev/null || true; rm -rf "$work"' EXIT
echo "scene seed first-picture-s calibration-s difference-s"
for ((k = 0; k < ${#runs[@]}; k += 2)); do
    scene=${runs[k]} seed=${runs[k + 1]}
    dir=$work/$scene-$seed
    mkdir -p "$dir"
    sed -e "s/^scene = .*/scene = \"$scene\"/" -e "s/^seed = .*/seed = $seed/" \
        -e 's/^listen = "127.0.0.1:7421"/listen = "off"/' "$config" > "$dir/compend.toml"
    start=$(date +%s%N)
    "$bin" serve --config "$dir/compend.toml" --state "$dir/state" --socket "$dir/sock" \
        2> "$dir/serve.log" &
    pid=$!
    ready=""
    for _ in $(seq 1 6000); do
        if grep -q "ready: playing" "$dir/serve.log"; then
            ready=$(( ($(date +%s%N) - start) / 1000000 ))
            break
        fi
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.05
    done
    "$bin" stop --socket "$dir/sock" > /dev/null 2>&1 || kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
    pid=""
    if [ -z "$ready" ]; then
        echo "bench_first_picture: $scene $seed: no first picture; the log:" >&2
        tail -20 "$dir/serve.log" >&2
        exit 1
    fi
    meta=$(find "$dir/state" -name model.json -print -quit)
    total=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["calibration"]["seconds"]["total"])' "$meta")
    python3 -c 'import sys; s, c = float(sys.argv[3]) / 1000, float(sys.argv[4]); print(f"{sys.argv[1]} {sys.argv[2]} {s:.1f} {c:.1f} {s - c:+.1f}")' \
        "$scene" "$seed" "$ready" "$total"
done
