# Sourced by every script: keep DDS on loopback, give the run its own domain and log folder.
# Usage: source scripts/ros_env.sh [LOG_DIR]
_af_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_af_root/config/fastdds_localhost.xml}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# A run-unique domain (1..200) unless the caller chose one (e.g. a multi-machine deployment).
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  export ROS_DOMAIN_ID=$(( ( $$ + $(date +%N | sed 's/^0*//;s/^$/0/') ) % 200 + 1 ))
fi
export ROS_LOG_DIR="${1:-${ROS_LOG_DIR:-$(mktemp -d -t ament_formation_log.XXXXXX)}}"
mkdir -p "$ROS_LOG_DIR"
export PYTHONUNBUFFERED=1
unset _af_root

# Shared memory the ROS processes of a run leave in /dev/shm: liblttng-ust (loaded by the ROS
# wheels) creates lttng-ust-wait-*, and Fast DDS's shared-memory transport leaves fastrtps_* and
# sem.fastrtps_* segments behind when a process is killed (a clean exit removes them; rmw_fastrtps
# keeps that same-host transport next to the loopback UDP one). af_shm_snapshot remembers what
# existed; af_shm_cleanup removes only what appeared since, once the run's processes are gone, and
# never a segment a live process still maps (another launcher's processes on the same machine,
# e.g. launch_base.sh next to launch_robot.sh, share Fast DDS port segments with ours).
_af_shm_pattern='^(lttng-ust-wait|fastrtps_|sem\.fastrtps_)'
af_shm_snapshot() {
  _af_shm_before="$(ls /dev/shm 2>/dev/null | grep -E "$_af_shm_pattern" || true)"
}
af_shm_cleanup() {
  local f in_use
  in_use="$(cat /proc/[0-9]*/maps 2>/dev/null | grep -o '/dev/shm/[^ ]*' | sort -u || true)"
  for f in $(ls /dev/shm 2>/dev/null | grep -E "$_af_shm_pattern" || true); do
    if ! grep -qxF "$f" <<<"${_af_shm_before:-}" && ! grep -qxF "/dev/shm/$f" <<<"$in_use"; then
      rm -f "/dev/shm/$f"
    fi
  done
}
