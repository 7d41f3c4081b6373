# Sourced by every script: keep DDS on loopback, give the run its own domain and log folder.
# Usage: source scripts/ros_env.sh [LOG_DIR]
_af_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# AMENT_FORMATION_DDS=udp: loopback UDP only, no Fast DDS shared memory (docs/executors.md "The
# frozen runs": with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps always adds its
# shared-memory transport, whatever the profile says, and a publish can then wait on another
# process's shared-memory port lock while holding the GIL). It leaves the range to the project's
# loopback profile (UDP bound to 127.0.0.1, 127.0.0.1 as the only peer) by setting it to SUBNET,
# which only happens when that profile is the one in use.
if [ "${AMENT_FORMATION_DDS:-}" = "udp" ] && [ -z "${ROS_AUTOMATIC_DISCOVERY_RANGE:-}" ] \
    && [ "${FASTRTPS_DEFAULT_PROFILES_FILE:-$_af_root/config/fastdds_localhost.xml}" \
         = "$_af_root/config/fastdds_localhost.xml" ]; then
  export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
fi
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_af_root/config/fastdds_localhost.xml}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# A run-unique domain (1..200) unless the caller chose one (e.g. a multi-machine deployment).
# Unique on this machine, not just random: concurrent runs in one domain see each other's nodes
# and topics (another run's world, graph or start), and share Fast DDS's shared-memory ports.
# The shell holds an exclusive lock on $AF_DOMAIN_LOCK_DIR/<id>.lock (flock, on an inherited file
# descriptor: held while this shell or any process it started is alive, released by the kernel
# when the last of them exits, even on SIGKILL); the next shell takes the next free id.
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  _af_first=$(( ( $$ + $(date +%N | sed 's/^0*//;s/^$/0/') ) % 200 ))
  if command -v flock >/dev/null 2>&1 \
      && mkdir -p "${AF_DOMAIN_LOCK_DIR:=${TMPDIR:-/tmp}/ament_formation_domains}" 2>/dev/null; then
    for _af_i in $(seq 0 199); do
      _af_d=$(( (_af_first + _af_i) % 200 + 1 ))
      exec {AF_DOMAIN_LOCK_FD}>>"$AF_DOMAIN_LOCK_DIR/$_af_d.lock" || continue
      if flock -n "$AF_DOMAIN_LOCK_FD"; then
        export ROS_DOMAIN_ID=$_af_d
        break
      fi
      exec {AF_DOMAIN_LOCK_FD}>&-
    done
    unset _af_i _af_d
  fi
  # no flock, or all 200 ids taken: a random one, as before
  [ -n "${ROS_DOMAIN_ID:-}" ] || export ROS_DOMAIN_ID=$(( _af_first + 1 ))
  unset _af_first
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
# af_shm_note_used PID...: also remove, at clean-up, the segments these processes map now (call it
# just before stopping them): a segment that existed before our snapshot but that our processes
# used is ours to remove too once nobody maps it. Without this, launchers started one after the
# other and stopped together left segments behind: the first one's segments were in the later
# ones' snapshots, and when the first one cleaned up, the later ones' processes still mapped them.
af_shm_snapshot() {
  _af_shm_before="$(ls /dev/shm 2>/dev/null | grep -E "$_af_shm_pattern" || true)"
  _af_shm_used=""
}
af_shm_note_used() {
  local pid
  for pid in "$@"; do
    _af_shm_used+="$(grep -o '/dev/shm/[^ ]*' "/proc/$pid/maps" 2>/dev/null | sed 's|^/dev/shm/||' | sort -u || true)"$'\n'
  done
}
af_shm_cleanup() {
  local f in_use
  in_use="$(cat /proc/[0-9]*/maps 2>/dev/null | grep -o '/dev/shm/[^ ]*' | sort -u || true)"
  for f in $(ls /dev/shm 2>/dev/null | grep -E "$_af_shm_pattern" || true); do
    if grep -qxF "/dev/shm/$f" <<<"$in_use"; then
      continue  # still mapped by a live process
    fi
    if ! grep -qxF "$f" <<<"${_af_shm_before:-}" || grep -qxF "$f" <<<"${_af_shm_used:-}"; then
      rm -f "/dev/shm/$f"
    fi
  done
}
