#!/usr/bin/env bash
# On one robot's computer: the robot process (bridge to its motor board + its controller).
#
#   scripts/launch_robot.sh --id N --port /dev/ttyACM0 --scenario SCENARIO.yaml --domain D
#                           [--run-dir DIR] [--params FILE.yaml] [--split] [--nice N]
#                           [--rt-priority P] [--wait-for-port] [--loopback]
#
# Network: the lab network by default (DDS over UDP on this computer's interfaces, discovery on
# the subnet), in ROS domain D (0..101, ROS's safe range on Linux; the same on the camera PC and
# every robot; without --domain the exported ROS_DOMAIN_ID). --loopback: this machine only (a
# simulated board, the camera PC's launcher on the same machine with the same --domain).
# docs/multi-machine.md.
# Default: ONE process, formation_team hosting this robot's formation_bridge and formation_controller
# nodes (node /robot_N/formation_bridge and /robot_N/formation_controller, same topics and parameters;
# the controller hands torques to the bridge and takes wheel samples from it in process).
# --split: the two nodes as two processes (formation_bridge, formation_controller) instead.
# --nice N: start the robot's process(es) under `nice -n N` (-20..19; negative needs root).
# --rt-priority P: run the control loop (the controller's control thread) under SCHED_FIFO priority P
# (1..98; parameter realtime_priority; needs root or CAP_SYS_NICE, else a warning and normal priority).
# The bridge's torque limit (torque_limit_nm) is the robot's limit in the scenario; --params is
# passed to the node(s) as --params-file after it (node parameters; see each node's header).
# Bad input (missing option, an id that is not a robot of the scenario, a --port device that does
# not exist or that this user cannot read and write): one line, exit code 2. --wait-for-port: start
# anyway and let the bridge wait for the port to appear (parameter wait_for_port; a port lost while
# running is always reopened with backoff).
# Stops every process it started (by PID) on exit, Ctrl-C or TERM (exit status 143 after TERM, 130
# after Ctrl-C, else that of the first process to exit).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=launch_common.sh
source "$here/launch_common.sh"

usage() { sed -n '2,27p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
id=""; port=""; scenario=""; run_dir=""; params=(); params_file=""; loopback=""; domain=""; split=""
nice_n=""; nice_given=""; rt=""; rt_given=""; wait_port=()
while [ $# -gt 0 ]; do
  case "$1" in
    --id) id="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --port) port="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --scenario) scenario="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --run-dir) run_dir="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --params) params_file="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --split) split=1; shift ;;
    --nice) nice_given=1; nice_n="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --rt-priority) rt_given=1; rt="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --wait-for-port) wait_port=(-p wait_for_port:=true); shift ;;
    --domain) domain="${2-}"; shift; [ $# -gt 0 ] && shift
      [ -n "$domain" ] || { echo "launch_robot.sh: --domain: expected a ROS domain id in [0, 101]" >&2; exit 2; } ;;
    --loopback) loopback=1; shift ;;
    --multi-machine) shift ;;   # the lab network: the default (kept for older command lines)
    -h|--help) usage ;;
    *) echo "launch_robot.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[[ "$id" =~ ^[0-9]+$ ]] || { echo "launch_robot.sh: --id: expected a robot id (integer)" >&2; exit 2; }
[ -n "$port" ] || { echo "launch_robot.sh: --port: required (device path or pyserial URL)" >&2; exit 2; }
if [ ${#wait_port[@]} = 0 ] && [[ "$port" != *://* ]]; then   # a device path (not a pyserial URL)
  [ -e "$port" ] || {
    echo "launch_robot.sh: --port: no such device '$port' (board not plugged in? --wait-for-port waits for it)" >&2
    exit 2; }
  [ -r "$port" ] && [ -w "$port" ] || {
    echo "launch_robot.sh: --port: user $(id -un) cannot read and write '$port' (group $(stat -L -c %G "$port"))" >&2
    exit 2; }
fi
[ -n "$scenario" ] && [ -f "$scenario" ] || { echo "launch_robot.sh: --scenario: no such file '$scenario'" >&2; exit 2; }
if [ -n "$nice_given" ] && ! { [[ "$nice_n" =~ ^-?[0-9]{1,2}$ ]] && [ "$nice_n" -ge -20 ] && [ "$nice_n" -le 19 ]; }; then
  echo "launch_robot.sh: --nice: expected an integer in [-20, 19], got '$nice_n'" >&2; exit 2
fi
if [ -n "$rt_given" ] && ! { [[ "$rt" =~ ^[0-9]{1,2}$ ]] && [ "$rt" -ge 1 ] && [ "$rt" -le 98 ]; }; then
  echo "launch_robot.sh: --rt-priority: expected an integer in [1, 98], got '$rt'" >&2; exit 2
fi
scenario="$(realpath "$scenario")"
if [ -n "$params_file" ]; then
  [ -f "$params_file" ] || { echo "launch_robot.sh: --params: no such file '$params_file'" >&2; exit 2; }
  params=(--params-file "$(realpath "$params_file")")
fi
af_choose_network launch_robot.sh "$loopback" "$domain"   # sets AF_NETWORK
info="$("${AF_PYTHON[@]}" "$here/launch_info.py" "$scenario" ${params_file:+"$params_file"})" || exit 2
eval "$info"   # sets ids, robot_ids_list, marker_ids_list, torque_<id>
[[ " $ids " == *" $id "* ]] || {
  echo "launch_robot.sh: --id: robot $id is not in $scenario (ids: $ids)" >&2; exit 2; }
torque_limit_nm="$(eval echo "\$torque_$id")"
[ -n "$run_dir" ] || run_dir="$(mktemp -d -t ament_formation_robot.XXXXXX)"
ctl=()   # prefix of the robot's processes
[ -n "$nice_n" ] && ctl=(nice -n "$nice_n")
rtp=()
[ -n "$rt" ] && rtp=(-p realtime_priority:="$rt")

af_launch_init "$(realpath -m "$run_dir")" "${AF_NETWORK[@]}"
echo "network: $([ ${#AF_NETWORK[@]} = 0 ] && echo "loopback (this machine only)" || echo "lab (subnet discovery, profile $FASTRTPS_DEFAULT_PROFILES_FILE)"), ROS_DOMAIN_ID=$ROS_DOMAIN_ID"
if [ -z "$split" ]; then
  # the robot process: one formation_team hosting robot N's bridge and controller nodes
  af_start "robot_$id" "${ctl[@]}" "$AF_BIN/formation_team" --ros-args \
    --params-file "$AF_PARAMS_DIR/formation_team.yaml" \
    --params-file "$AF_PARAMS_DIR/formation_controller.yaml" \
    --params-file "$AF_PARAMS_DIR/formation_bridge.yaml" \
    -r formation_team:__node:="formation_robot_$id" -p scenario:="$scenario" -p robot_ids:="[$id]" \
    -p port_template:="$port" "${wait_port[@]}" "${rtp[@]}" "${params[@]}"
else
  af_start "bridge_$id" "${ctl[@]}" "$AF_BIN/formation_bridge" --ros-args -r __ns:="/robot_$id" \
    --params-file "$AF_PARAMS_DIR/formation_bridge.yaml" -p port:="$port" -p torque_limit_nm:="$torque_limit_nm" "${wait_port[@]}" "${params[@]}"
  af_start "controller_$id" "${ctl[@]}" "$AF_BIN/formation_controller" --ros-args -r __ns:="/robot_$id" \
    --params-file "$AF_PARAMS_DIR/formation_controller.yaml" \
    -p scenario:="$scenario" -p robot_id:="$id" "${rtp[@]}" "${params[@]}"
fi
af_wait_any
