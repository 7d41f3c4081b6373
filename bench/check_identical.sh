#!/usr/bin/env bash
# Run `formation sim` on paper.yaml and v_formation.yaml and compare metrics.json with a baseline
# folder made the same way (bench/compare_metrics.py: 1e-9 relative, same mode/graph events).
# Usage: bench/check_identical.sh BASELINE_DIR [OUT_DIR]   (BASELINE_DIR/{paper,v}/metrics.json)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
base="$1"; out="${2:-$(mktemp -d)}"
status=0
for pair in paper:paper v:v_formation; do
  name="${pair%%:*}"; file="${pair#*:}"
  "$here/.venv/bin/formation" sim "$here/config/scenarios/$file.yaml" --out "$out/$name" --no-figure --quiet
  echo -n "$file: "
  "$here/.venv/bin/python" "$here/bench/compare_metrics.py" "$base/$name/metrics.json" "$out/$name/metrics.json" || status=1
done
exit $status
