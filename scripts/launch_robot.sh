#!/usr/bin/env bash
# On one robot's computer: the bridge to its motor board and its controller.
#
#   scripts/launch_robot.sh --id N --port /dev/ttyACM0 --scenario SCENARIO.yaml [--run-dir DIR]
#                           [--params FILE.yaml] [--multi-machine]
#
# The bridge's torque limit (torque_limit_nm) is the robot's limit in the scenario; --params is
# passed to both nodes as --params-file after it (node parameters; see each node's header).
# Bad input (missing option, an id that is not a robot of the scenario): one line, exit code 2.
# Stops both processes (by PID) on exit, Ctrl-C or TERM (exit status 143 after TERM, 130 after
# Ctrl-C, else that of the first process to exit). DDS stays on loopback unless --multi-machine
# (then export the same ROS_DOMAIN_ID on the robots and the camera PC).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=launch_common.sh
source "$here/launch_common.sh"

usage() { sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
id=""; port=""; scenario=""; run_dir=""; params=(); params_file=""; multi=""
while [ $# -gt 0 ]; do
  case "$1" in
    --id) id="$2"; shift 2 ;;
    --port) port="$2"; shift 2 ;;
    --scenario) scenario="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --run-dir) run_dir="$2"; shift 2 ;;
    --params) params_file="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --multi-machine) multi="--multi-machine"; shift ;;
    -h|--help) usage ;;
    *) echo "launch_robot.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[[ "$id" =~ ^[0-9]+$ ]] || { echo "launch_robot.sh: --id: expected a robot id (integer)" >&2; exit 2; }
[ -n "$port" ] || { echo "launch_robot.sh: --port: required (device path or pyserial URL)" >&2; exit 2; }
[ -n "$scenario" ] && [ -f "$scenario" ] || { echo "launch_robot.sh: --scenario: no such file '$scenario'" >&2; exit 2; }
scenario="$(realpath "$scenario")"
if [ -n "$params_file" ]; then
  [ -f "$params_file" ] || { echo "launch_robot.sh: --params: no such file '$params_file'" >&2; exit 2; }
  params=(--params-file "$(realpath "$params_file")")
fi
info="$("$AF_BIN/python" "$here/launch_info.py" "$scenario")" || exit 2
eval "$info"   # sets ids, robot_ids_list, marker_ids_list, torque_<id>
[[ " $ids " == *" $id "* ]] || {
  echo "launch_robot.sh: --id: robot $id is not in $scenario (ids: $ids)" >&2; exit 2; }
torque_limit_nm="$(eval echo "\$torque_$id")"
[ -n "$run_dir" ] || run_dir="$(mktemp -d -t ament_formation_robot.XXXXXX)"

af_launch_init "$(realpath -m "$run_dir")" $multi
af_start "bridge_$id" "$AF_BIN/formation_bridge" --ros-args -r __ns:="/robot_$id" -p port:="$port" \
  -p torque_limit_nm:="$torque_limit_nm" "${params[@]}"
af_start "controller_$id" "$AF_BIN/formation_controller" --ros-args -r __ns:="/robot_$id" \
  -p scenario:="$scenario" -p robot_id:="$id" "${params[@]}"
af_wait_any
