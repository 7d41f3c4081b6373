#!/usr/bin/env bash
# Start every process of a simulated run and stop them all (by PID) on exit, Ctrl-C or TERM.
#
#   scripts/launch_sim.sh SCENARIO.yaml [--run-dir DIR] [--duration S] [--speed F] [--team K]
#                         [--control-nice N] [--control-rt P] [--live [PORT]] [--live-host HOST]
#                         [--camera FILE] [--multi-machine]
#
# Processes: formation_world (plant, emulated boards on ptys, synthetic camera), one formation_bridge
# and one formation_controller per robot (namespace robot_<id>), formation_tracker,
# formation_coordinator. --team K: instead of those two processes per robot, ceil(N/K)
# formation_team processes (logs team_0, team_1, ...; nodes /formation_team_0, ...), each hosting the bridge and controller nodes
# of K robots (same nodes and topics; fewer processes for many robots on one machine).
# --control-nice N: start the bridge/controller (or team) processes under `nice -n N` (-20..19;
# negative = before the world, tracker and coordinator, as a real-time control loop should be;
# needs root or CAP_SYS_NICE, otherwise nice warns and they run at the normal priority).
# --control-rt P (default $AF_CONTROL_RT_PRIORITY): the controllers' / teams' control loops under
# SCHED_FIFO priority P (1..98, parameter realtime_priority; needs root or CAP_SYS_NICE). --team 1 is
# the robot-process layout of a real robot (scripts/launch_robot.sh): one process per robot.
# --live [PORT]: also formation_live_view, the run live in Foxglove on ws://127.0.0.1:PORT (default
# 8765, 0 = any free port, see live_view.log); --live-host HOST (implies --live) binds it to HOST instead
# (e.g. the lab address; off by default: loopback only). See docs/live_view.md.
# --camera FILE: the camera the world renders and the tracker reads (a config/ name or a path; default
# camera.yaml). When it does not see every start and goal of the scenario, the world and the tracker
# get one fitted to the scenario instead, RUN_DIR/camera.yaml (same lens and height; launch_info.py).
# Logs and the PID list ("PID NAME" per line) go to RUN_DIR (default: a new temp folder).
# The run ends when the world finishes the scenario, when any process exits, or after --duration S.
# DDS stays on loopback unless --multi-machine (see scripts/launch_common.sh).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=launch_common.sh
source "$here/launch_common.sh"

usage() { sed -n '2,27p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
[ $# -ge 1 ] || usage
scenario="$(realpath "$1")"; shift
run_dir=""; duration=""; speed="1.0"; multi=""; team=""; team_given=""; control_nice=""; nice_given=""; control_rt=""
live=""; live_port="8765"; live_host="127.0.0.1"; camera="camera.yaml"
while [ $# -gt 0 ]; do
  case "$1" in
    --run-dir) run_dir="$2"; shift 2 ;;
    --duration) duration="$2"; shift 2 ;;
    --speed) speed="$2"; shift 2 ;;
    --team) team_given=1; team="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --control-nice) nice_given=1; control_nice="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --control-rt) control_rt="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --multi-machine) multi="--multi-machine"; shift ;;
    --camera) camera="${2-}"; shift; [ $# -gt 0 ] && shift
      [ -n "$camera" ] || { echo "launch_sim.sh: --camera: expected a camera file" >&2; exit 2; } ;;
    --live) live=1; shift; if [ $# -gt 0 ] && [[ "$1" =~ ^[0-9]+$ ]]; then live_port="$1"; shift; fi ;;
    --live-host) live=1; live_host="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    -h|--help) usage ;;
    *) echo "launch_sim.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
if [ -n "$team_given" ] && ! [[ "$team" =~ ^[1-9][0-9]{0,3}$ ]]; then
  echo "launch_sim.sh: --team: expected a positive integer K (robots per process), got '$team'" >&2; exit 2
fi
if [ -n "$nice_given" ] && ! { [[ "$control_nice" =~ ^-?[0-9]{1,2}$ ]] && [ "$control_nice" -ge -20 ] \
    && [ "$control_nice" -le 19 ]; }; then
  echo "launch_sim.sh: --control-nice: expected an integer in [-20, 19], got '$control_nice'" >&2; exit 2
fi
if [ -n "$live" ] && ! { [[ "$live_port" =~ ^[0-9]{1,5}$ ]] && [ "$live_port" -le 65535 ]; }; then
  echo "launch_sim.sh: --live: expected a TCP port in [0, 65535], got '$live_port'" >&2; exit 2
fi
[ -n "$live_host" ] || { echo "launch_sim.sh: --live-host: expected an address" >&2; exit 2; }
ctl=()   # prefix of the control-path processes (bridges, controllers, teams)
[ -n "$control_nice" ] && ctl=(nice -n "$control_nice")
# --control-rt P (default: $AF_CONTROL_RT_PRIORITY): the control loops under SCHED_FIFO priority P
control_rt="${control_rt:-${AF_CONTROL_RT_PRIORITY:-}}"
if [ -n "$control_rt" ] && ! { [[ "$control_rt" =~ ^[0-9]{1,2}$ ]] && [ "$control_rt" -ge 1 ] \
    && [ "$control_rt" -le 98 ]; }; then
  echo "launch_sim.sh: --control-rt: expected an integer in [1, 98], got '$control_rt'" >&2; exit 2
fi
rtp=()   # parameter of the control-path processes that own a control loop (controllers, teams)
[ -n "$control_rt" ] && rtp=(-p realtime_priority:="$control_rt")
[ -f "$scenario" ] || { echo "launch_sim.sh: $scenario: no such scenario file" >&2; exit 2; }
[ -n "$run_dir" ] || run_dir="$(mktemp -d -t ament_formation_sim.XXXXXX)"
run_dir="$(realpath -m "$run_dir")"

# robot ids, marker ids (tracker lists) and torque limits (bridges) from the scenario
mkdir -p "$run_dir"
info="$("${AF_PYTHON[@]}" "$here/launch_info.py" "$scenario" --camera-fit "$run_dir" "$camera")" || exit 2
eval "$info"   # sets ids, robot_ids_list, marker_ids_list, torque_<id>, camera_file

af_launch_init "$run_dir" $multi
echo "run folder: $run_dir (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
pty_dir="$run_dir/pty"
use_sim_time=false
[ "$speed" != "1.0" ] && [ "$speed" != "1" ] && use_sim_time=true

af_start world "$AF_BIN/formation_world" --ros-args --params-file "$AF_PARAMS_DIR/formation_world.yaml" \
  -p scenario:="$scenario" -p pty_dir:="$pty_dir" \
  -p speed_factor:="$speed" -p camera_config:="$camera_file"
# the emulated boards' ptys appear as RUN_DIR/pty/robot_<id>
for _ in $(seq 1 1200); do   # up to 60 s: a busy machine imports slowly
  ready=1
  for id in $ids; do [ -e "$pty_dir/robot_$id" ] || ready=0; done
  [ "$ready" = 1 ] && break
  af_alive "${AF_PIDS[0]}" || { echo "formation_world exited early; see $run_dir/world.log" >&2; exit 1; }
  sleep 0.05
done
[ "$ready" = 1 ] || { echo "the world's ptys did not appear in 60 s" >&2; exit 1; }

if [ -n "$team" ]; then
  # ceil(N/K) formation_team processes, robots in scenario order, K per process
  set -- $ids
  k=0
  while [ $# -gt 0 ]; do
    members=()
    while [ $# -gt 0 ] && [ "${#members[@]}" -lt "$team" ]; do members+=("$1"); shift; done
    list="[$(IFS=,; echo "${members[*]}")]"
    af_start "team_$k" "${ctl[@]}" "$AF_BIN/formation_team" --ros-args -r formation_team:__node:="formation_team_$k" \
      --params-file "$AF_PARAMS_DIR/formation_team.yaml" \
      --params-file "$AF_PARAMS_DIR/formation_controller.yaml" \
      --params-file "$AF_PARAMS_DIR/formation_bridge.yaml" \
      -p scenario:="$scenario" \
      -p robot_ids:="$list" -p port_template:="$pty_dir/robot_{id}" -p poll_rate_hz:=200.0 \
      -p use_sim_time:=$use_sim_time "${rtp[@]}"
    k=$((k + 1))
  done
else
  for id in $ids; do
    af_start "bridge_$id" "${ctl[@]}" "$AF_BIN/formation_bridge" --ros-args -r __ns:="/robot_$id" \
      --params-file "$AF_PARAMS_DIR/formation_bridge.yaml" -p port:="$pty_dir/robot_$id" -p torque_limit_nm:="$(eval echo "\$torque_$id")" -p poll_rate_hz:=200.0 \
      -p use_sim_time:=$use_sim_time
    af_start "controller_$id" "${ctl[@]}" "$AF_BIN/formation_controller" --ros-args -r __ns:="/robot_$id" \
      --params-file "$AF_PARAMS_DIR/formation_controller.yaml" \
      -p scenario:="$scenario" -p robot_id:="$id" -p use_sim_time:=$use_sim_time "${rtp[@]}"
  done
fi
af_start tracker "$AF_BIN/formation_tracker" --ros-args \
  --params-file "$AF_PARAMS_DIR/formation_tracker.yaml" -p robot_ids:="$robot_ids_list" \
  -p marker_ids:="$marker_ids_list" -p use_sim_time:=$use_sim_time -p camera_config:="$camera_file"
af_start coordinator "$AF_BIN/formation_coordinator" --ros-args \
  --params-file "$AF_PARAMS_DIR/formation_coordinator.yaml" -p scenario:="$scenario" \
  -p use_sim_time:=$use_sim_time
if [ -n "$live" ]; then
  af_start live_view "$AF_BIN/formation_live_view" --ros-args -p scenario:="$scenario" \
    -p host:="$live_host" -p port:="$live_port" -p use_sim_time:=$use_sim_time
fi

af_wait_any "$duration"
