#!/usr/bin/env bash
# Runs the whole test suite on a fresh machine: installs missing system packages, then cargo test
# with the benchmarks built in (the `benches` feature: their tests run too).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/deps.sh
cargo test --locked --features benches "$@"
