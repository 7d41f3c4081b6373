#!/usr/bin/env bash
# The main job: set up .venv if missing, then run the paper's experiment (spec S12 scenario 1)
# and write out/paper/ (metrics.json, figure.png, trajectories). Extra args go to `formation sim`.
# (A later step switches this to the whole ROS 2 system on the simulated hardware twin.)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
# shellcheck source=ros_env.sh
source "$here/scripts/ros_env.sh" "$here/out/paper/ros_log"
cd "$here"
out="$here/out/paper"
"$here/.venv/bin/formation" sim "$here/config/scenarios/paper.yaml" --out "$out" "$@"
"$here/.venv/bin/python" - "$out/metrics.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
ok = m["prohibited_entries"] == 0 and (m["min_clearance_m"] or 0) > 0
print(f"demo: {'OK' if ok else 'CHECK'}: no prohibited-region entry = {m['prohibited_entries'] == 0}, "
      f"min clearance {m['min_clearance_m']:.3f} m; figure: {sys.argv[1].rsplit('/', 1)[0]}/figure.png")
PY
