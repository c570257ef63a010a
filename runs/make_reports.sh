#!/usr/bin/env bash
# Regenerate every report, figure and benchmark that README.md and docs/results.md quote.
# Run from a clone with the README's environment: .venv/bin/ is put first on PATH.
# Takes about 5 minutes on a 2-core machine (precision and stability dominate).
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$PWD/.venv/bin:$PATH"
dynfab precision --out docs/figures/precision
dynfab stability --out docs/figures/stability
dynfab figures --out docs/figures/paper
dynfab convergence --out docs/figures/convergence
dynfab fabric --out docs/figures/fabric
pullout=$(mktemp -d)
dynfab run runs/fabric_pullout.toml --out "$pullout/pullout.h5" --quiet
dynfab plot "$pullout/pullout.h5" --out "$pullout" >/dev/null
cp "$pullout/pullout.png" docs/figures/fabric/pullout.png
python benchmarks/static.py
python benchmarks/dynamic.py
python benchmarks/run_overhead.py
