#!/usr/bin/env bash
# On the camera PC: the marker tracker and the formation coordinator.
#
#   scripts/launch_base.sh --scenario SCENARIO.yaml --domain D [--camera SOURCE [--camera-wait S]]
#                          [--run-dir DIR] [--params FILE.yaml] [--live [PORT]] [--live-host HOST]
#                          [--loopback]
#
# Network: the lab network by default (DDS over UDP on this PC's interfaces, discovery on the
# subnet), in ROS domain D (0..101, ROS's safe range on Linux; the same on every robot; without
# --domain the exported ROS_DOMAIN_ID). --loopback: this machine only. docs/multi-machine.md.
# --camera SOURCE: the tracker captures frames itself from a device index (0), a device path
# (/dev/video0, /dev/v4l/by-id/...), a video file or a stream URL (http://..., rtsp://...); a camera
# that cannot be opened ends the run (tracker status 1, one line in RUN_DIR/tracker.log) unless
# --camera-wait S lets it retry for S seconds (inf: forever). docs/camera.md.
# Without --camera the tracker subscribes /camera/image_raw (e.g. from a camera driver).
# --live [PORT]: also formation_live_view (Foxglove on ws://127.0.0.1:PORT, default 8765); to watch
# from another lab machine add --live-host HOST (this PC's lab address; implies --live). docs/live_view.md
# Stops every process it started (by PID) on exit, Ctrl-C or TERM.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=launch_common.sh
source "$here/launch_common.sh"

usage() { sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
scenario=""; camera=""; camera_wait=""; run_dir=""; params=(); params_file=""; loopback=""; domain=""
live=""; live_port="8765"; live_host="127.0.0.1"
while [ $# -gt 0 ]; do
  case "$1" in
    --scenario) scenario="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --camera) camera="${2-}"; shift; [ $# -gt 0 ] && shift
      [ -n "$camera" ] || { echo "launch_base.sh: --camera: expected a device index, device path, video file or URL" >&2; exit 2; } ;;
    --camera-wait) camera_wait="${2-}"; shift; [ $# -gt 0 ] && shift
      [[ "$camera_wait" =~ ^([0-9]+(\.[0-9]*)?|inf)$ ]] || { echo "launch_base.sh: --camera-wait: expected seconds >= 0 or inf, got '$camera_wait'" >&2; exit 2; } ;;
    --run-dir) run_dir="$2"; shift 2 ;;
    --params) params_file="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    --domain) domain="${2-}"; shift; [ $# -gt 0 ] && shift
      [ -n "$domain" ] || { echo "launch_base.sh: --domain: expected a ROS domain id in [0, 101]" >&2; exit 2; } ;;
    --loopback) loopback=1; shift ;;
    --multi-machine) shift ;;   # the lab network: the default (kept for older command lines)
    --live) live=1; shift; if [ $# -gt 0 ] && [[ "$1" =~ ^[0-9]+$ ]]; then live_port="$1"; shift; fi ;;
    --live-host) live=1; live_host="${2-}"; shift; [ $# -gt 0 ] && shift ;;
    -h|--help) usage ;;
    *) echo "launch_base.sh: unknown option $1" >&2; exit 2 ;;
  esac
done
[ -n "$scenario" ] && [ -f "$scenario" ] || { echo "launch_base.sh: --scenario: no such file '$scenario'" >&2; exit 2; }
scenario="$(realpath "$scenario")"
if [ -n "$live" ] && ! { [[ "$live_port" =~ ^[0-9]{1,5}$ ]] && [ "$live_port" -le 65535 ]; }; then
  echo "launch_base.sh: --live: expected a TCP port in [0, 65535], got '$live_port'" >&2; exit 2
fi
[ -n "$live_host" ] || { echo "launch_base.sh: --live-host: expected an address" >&2; exit 2; }
if [ -n "$params_file" ]; then
  [ -f "$params_file" ] || { echo "launch_base.sh: --params: no such file '$params_file'" >&2; exit 2; }
  params=(--params-file "$(realpath "$params_file")")
fi
cam=()
[ -n "$camera" ] && cam=(-p source:="$camera")
[ -n "$camera_wait" ] && cam+=(-p source_wait_s:="$([ "$camera_wait" = inf ] && echo .inf || echo "$camera_wait")")
af_choose_network launch_base.sh "$loopback" "$domain"   # sets AF_NETWORK
info="$("${AF_PYTHON[@]}" "$here/launch_info.py" "$scenario" ${params_file:+"$params_file"} --camera-check)" || exit 2
eval "$info"   # sets ids, robot_ids_list, marker_ids_list
[ -n "$run_dir" ] || run_dir="$(mktemp -d -t ament_formation_base.XXXXXX)"   # after the checks: a refused
# launch leaves no empty run folder behind

af_launch_init "$(realpath -m "$run_dir")" "${AF_NETWORK[@]}"
echo "network: $([ ${#AF_NETWORK[@]} = 0 ] && echo "loopback (this machine only)" || echo "lab (subnet discovery, profile $FASTRTPS_DEFAULT_PROFILES_FILE)"), ROS_DOMAIN_ID=$ROS_DOMAIN_ID"
# the params file first: the last value of a parameter wins, and the scenario's robots and
# --camera must not be overridden by the file's defaults (config/params/formation_tracker.yaml)
af_start tracker "$AF_BIN/formation_tracker" --ros-args \
  --params-file "$AF_PARAMS_DIR/formation_tracker.yaml" "${params[@]}" -p robot_ids:="$robot_ids_list" \
  -p marker_ids:="$marker_ids_list" "${cam[@]}"
af_start coordinator "$AF_BIN/formation_coordinator" --ros-args \
  --params-file "$AF_PARAMS_DIR/formation_coordinator.yaml" -p scenario:="$scenario" "${params[@]}"
if [ -n "$live" ]; then
  af_start live_view "$AF_BIN/formation_live_view" --ros-args -p scenario:="$scenario" \
    -p host:="$live_host" -p port:="$live_port" "${params[@]}"
fi
af_wait_any
