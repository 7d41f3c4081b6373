#!/usr/bin/env bash
# bench/bench_sim.py of this tree and of git revision REV (default HEAD~1), in the same run, one
# after the other, twice (A B A B): the numbers of a loaded machine are comparable only so.
# REV compiles its kernels into a cache folder of its own (BENCH_REV_CACHE_DIR, default: temporary).
# Usage: bench/bench_sim_vs.sh [REV] [bench_sim.py options, e.g. --robots 1000 --seconds 3]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
rev="${1:-HEAD~1}"; shift || true
tmp="$(mktemp -d)"; trap 'rm -rf "$tmp"' EXIT
git -C "$here" archive "$rev" | tar -x -C "$tmp"
for round in 1 2; do
  echo "== $rev (round $round)"
  (cd "$tmp" && PYTHONPATH="$tmp" AMENT_FORMATION_CACHE_DIR="${BENCH_REV_CACHE_DIR:-$tmp/.cache}" \
    "$here/.venv/bin/python" bench/bench_sim.py --no-compile "$@")
  echo "== working tree (round $round)"
  (cd "$here" && "$here/.venv/bin/python" bench/bench_sim.py --no-compile "$@")
done
