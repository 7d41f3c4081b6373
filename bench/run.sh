#!/usr/bin/env bash
# Run one benchmark with the project's environment and clean up after it:
#
#   bench/run.sh bench_system.py [ARGS...]      (any bench/*.py)
#
# Creates .venv when missing (scripts/setup.sh), keeps DDS on loopback with a run-unique domain
# and log folder (scripts/ros_env.sh), and removes the shared memory the benchmark's ROS processes
# leave in /dev/shm (lttng-ust-wait-*, Fast DDS segments) once they are gone.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
[ $# -ge 1 ] || { sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
bench="$here/$(basename "$1")"; shift
[ -f "$bench" ] || { echo "bench/run.sh: $bench: no such benchmark" >&2; exit 2; }
"$root/scripts/setup.sh"
logdir="$(mktemp -d -t ament_formation_bench_log.XXXXXX)"
# shellcheck source=../scripts/ros_env.sh
source "$root/scripts/ros_env.sh" "$logdir"
export AMENT_FORMATION_LOOPBACK_ONLY=1   # launch_robot.sh / launch_base.sh: --loopback or refused
af_shm_snapshot
trap 'af_shm_cleanup; rm -rf "$logdir"' EXIT
"$root/.venv/bin/python" "$bench" "$@"
