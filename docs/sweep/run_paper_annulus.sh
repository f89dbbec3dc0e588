#!/usr/bin/env bash
# Run docs/sweep/paper_annulus.yaml (10,080 cases) on this machine's cores, or on a Dask
# cluster: bash docs/sweep/run_paper_annulus.sh --scheduler tcp://HOST:8786
# Restartable: an interrupted run continues where it stopped (--resume).  At the end the
# summary and the heat map are copied next to the spec, to be committed.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
OUT=${OUT:-sweeps/paper_annulus}
.venv/bin/toc-sweep docs/sweep/paper_annulus.yaml --out "$OUT" --resume "$@"
mkdir -p docs/sweep/paper_annulus
cp "$OUT/summary.md" "$OUT/summary.json" "$OUT/heatmap.png" docs/sweep/paper_annulus/
echo "results: $OUT/results (Parquet); summary and heat map: docs/sweep/paper_annulus/"
