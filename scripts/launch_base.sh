#!/usr/bin/env bash
# On the camera PC: the marker tracker and the formation coordinator.
#
#   scripts/launch_base.sh --scenario SCENARIO.yaml [--camera DEVICE_OR_URL] [--run-dir DIR]
#                          [--params FILE.yaml] [--multi-machine]
#
# Without --camera the tracker subscribes /camera/image_raw (e.g. from a camera driver).
# Stops both processes (by PID) on exit, Ctrl-C or TERM. DDS stays on loopback unless --multi-machine.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=launch_common.sh
source "$here/launch_common.sh"

usage() { sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
scenario=""; camera=""; run_dir=""; params=(); params_file=""; multi=""
while [ $# -gt 0 ]; do
  case "$1" in
    --scenario) scenario="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --camera) camera="$2"; shift 2 ;;
    --run-dir) run_dir="$2"; shift 2 ;;
    --params) params_file="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --multi-machine) multi="--multi-machine"; shift ;;
    -h|--help) usage ;;
    *) echo "launch_base.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -n "$scenario" ] && [ -f "$scenario" ] || { echo "launch_base.sh: --scenario: no such file '$scenario'" >&2; exit 2; }
scenario="$(realpath "$scenario")"
if [ -n "$params_file" ]; then
  [ -f "$params_file" ] || { echo "launch_base.sh: --params: no such file '$params_file'" >&2; exit 2; }
  params=(--params-file "$(realpath "$params_file")")
fi
[ -n "$run_dir" ] || run_dir="$(mktemp -d -t ament_formation_base.XXXXXX)"
cam=()
[ -n "$camera" ] && cam=(-p source:="$camera")
info="$("$AF_BIN/python" "$here/launch_info.py" "$scenario")" || exit 2
eval "$info"   # sets ids, robot_ids_list, marker_ids_list

af_launch_init "$(realpath -m "$run_dir")" $multi
af_start tracker "$AF_BIN/formation_tracker" --ros-args -p robot_ids:="$robot_ids_list" \
  -p marker_ids:="$marker_ids_list" "${cam[@]}" "${params[@]}"
af_start coordinator "$AF_BIN/formation_coordinator" --ros-args -p scenario:="$scenario" "${params[@]}"
af_wait_any
