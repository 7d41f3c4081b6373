#!/usr/bin/env bash
# The main job: set up .venv if missing, then run the paper's experiment (spec S12 scenario 1)
# through the whole ROS 2 system on the simulated hardware twin (`formation run`: world with
# emulated motor boards on ptys and the synthetic overhead camera, tracker, a bridge and a
# controller per robot, coordinator) and write out/paper/ (run.mcap, metrics.json, figure.png,
# trajectories). The clock runs at DEMO_SPEED (default 1: real time; bench/bench_system.py shows
# two robots keep their 100 Hz control deadlines on a 2-core machine; 0.5 = /clock at half speed
# for a machine busy with other work).
# Extra args go to `formation run`. The ROS-free simulator: `formation sim` (see README).
# Exit status 0 only when the run completed and passed its checks (metrics.json "ok": true), with
# a line "demo: OK: ..."; otherwise non-zero and one line "demo: FAILED: <reason>" on stderr.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
# shellcheck source=ros_env.sh
source "$here/scripts/ros_env.sh" "$here/out/paper/ros_log"
af_shm_snapshot
trap af_shm_cleanup EXIT
cd "$here"
out="$here/out/paper"
# `formation run` exits 1 with one line naming the reason when the run did not complete (a process
# died, the world or the recorder stalled) or failed its checks (prohibited entry, contact, or the
# scenario's expect: block, e.g. settled formation RMS); metrics.json says the same ("ok", "checks").
status=0
rm -f "$out/metrics.json"      # judge this run only
"$here/.venv/bin/formation" run "$here/config/scenarios/paper.yaml" --out "$out" \
  --speed "${DEMO_SPEED:-1}" "$@" || status=$?
if [ ! -f "$out/metrics.json" ]; then
  echo "demo: FAILED: no $out/metrics.json (formation run exit status $status)" >&2
  exit "$(( status ? status : 1 ))"
fi
"$here/.venv/bin/python" - "$out/metrics.json" "$status" <<'PY'
import json, sys
m, status = json.load(open(sys.argv[1])), int(sys.argv[2])
rms = {rid: r["formation_rms_settled_m"] for rid, r in m.get("robots", {}).items()}
figures = ", ".join(f"R{k} {1e3 * v:.1f} mm" if v is not None else f"R{k} n/a" for k, v in rms.items())
if m.get("ok") and status == 0:
    print(f"demo: OK: {sum(c['ok'] for c in m['checks'])} checks passed; prohibited entries "
          f"{m['prohibited_entries']}, min clearance {m['min_clearance_m']:.3f} m, settled formation RMS "
          f"{figures}; figure: {sys.argv[1].rsplit('/', 1)[0]}/figure.png")
    sys.exit(0)
reason = m.get("failure") or f"formation run exit status {status}"
print(f"demo: FAILED: {reason}", file=sys.stderr)
sys.exit(status or 1)
PY
