#!/usr/bin/env bash
# On one robot's computer: the bridge to its motor board and its controller.
#
#   scripts/launch_robot.sh --id N --port /dev/ttyACM0 --scenario SCENARIO.yaml [--run-dir DIR]
#                           [--params FILE.yaml] [--multi-machine]
#
# --params is passed to both nodes as --params-file (node parameters; see each node's header).
# Stops both processes (by PID) on exit, Ctrl-C or TERM. DDS stays on loopback unless
# --multi-machine (then export the same ROS_DOMAIN_ID on the robots and the camera PC).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=launch_common.sh
source "$here/launch_common.sh"

usage() { sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
id=""; port=""; scenario=""; run_dir=""; params=(); multi=""
while [ $# -gt 0 ]; do
  case "$1" in
    --id) id="$2"; shift 2 ;;
    --port) port="$2"; shift 2 ;;
    --scenario) scenario="$(realpath "$2")"; shift 2 ;;
    --run-dir) run_dir="$2"; shift 2 ;;
    --params) params=(--params-file "$(realpath "$2")"); shift 2 ;;
    --multi-machine) multi="--multi-machine"; shift ;;
    -h|--help) usage ;;
    *) echo "launch_robot.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[[ "$id" =~ ^[0-9]+$ ]] || { echo "launch_robot.sh: --id: expected a robot id (integer)" >&2; exit 2; }
[ -n "$port" ] || { echo "launch_robot.sh: --port: required (device path or pyserial URL)" >&2; exit 2; }
[ -n "$scenario" ] && [ -f "$scenario" ] || { echo "launch_robot.sh: --scenario: no such file" >&2; exit 2; }
[ -n "$run_dir" ] || run_dir="$(mktemp -d -t ament_formation_robot.XXXXXX)"

af_launch_init "$(realpath -m "$run_dir")" $multi
af_start "bridge_$id" "$AF_BIN/formation_bridge" --ros-args -r __ns:="/robot_$id" -p port:="$port" "${params[@]}"
af_start "controller_$id" "$AF_BIN/formation_controller" --ros-args -r __ns:="/robot_$id" \
  -p scenario:="$scenario" -p robot_id:="$id" "${params[@]}"
af_wait_any
