#!/usr/bin/env bash
# The main job: set up .venv if missing, then run the paper's experiment (spec S12 scenario 1)
# through the whole ROS 2 system on the simulated hardware twin (`formation run`: world with
# emulated motor boards on ptys and the synthetic overhead camera, tracker, a bridge and a
# controller per robot, coordinator) and write out/paper/ (run.mcap, metrics.json, figure.png,
# trajectories). The clock runs at DEMO_SPEED (default 1: real time; bench/bench_system.py shows
# two robots keep their 100 Hz control deadlines on a 2-core machine; 0.5 = /clock at half speed
# for a machine busy with other work).
# Extra args go to `formation run`. The ROS-free simulator: `formation sim` (see README).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
# shellcheck source=ros_env.sh
source "$here/scripts/ros_env.sh" "$here/out/paper/ros_log"
af_shm_snapshot
trap af_shm_cleanup EXIT
cd "$here"
out="$here/out/paper"
"$here/.venv/bin/formation" run "$here/config/scenarios/paper.yaml" --out "$out" \
  --speed "${DEMO_SPEED:-1}" "$@"
"$here/.venv/bin/python" - "$out/metrics.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))
rms = {rid: r["formation_rms_settled_m"] for rid, r in m["robots"].items()}
ok = (m["prohibited_entries"] == 0 and (m["min_clearance_m"] or 0) > 0
      and all(v is not None and v <= 0.02 for v in rms.values()))
print(f"demo: {'OK' if ok else 'CHECK'}: prohibited entries {m['prohibited_entries']}, "
      f"min clearance {m['min_clearance_m']:.3f} m, settled formation RMS "
      + ", ".join(f"R{k} {1e3 * v:.1f} mm" if v is not None else f"R{k} n/a" for k, v in rms.items())
      + f"; figure: {sys.argv[1].rsplit('/', 1)[0]}/figure.png")
PY
