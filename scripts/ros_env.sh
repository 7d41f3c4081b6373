# Sourced by every script: keep DDS on loopback, give the run its own domain and log folder.
# Usage: source scripts/ros_env.sh [LOG_DIR]
_af_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# DDS transport on one machine: discovery range LOCALHOST with the shared-memory profile
# (config/fastdds_localhost_shm.xml: 4 MB segments, so that a large camera frame arrives; with
# rmw_fastrtps's own 0.5 MB segments a 748 kB frame reached the tracker 1-6 times a second;
# docs/executors.md "Large frames"), or, on request, AMENT_FORMATION_DDS=udp for loopback UDP only
# (config/fastdds_localhost.xml: every socket on 127.0.0.1, 127.0.0.1 as the only peer, 4 MB socket
# buffers, no /dev/shm segments; docs/executors.md "The stall found"). UDP only leaves the range
# to that profile by setting it to SUBNET, which only happens when that profile is the one in use
# and the caller set no range. Both keep every packet on the host; a profile or range the caller
# set is kept.
_af_udp_profile="$_af_root/config/fastdds_localhost.xml"
if [ "${AMENT_FORMATION_DDS:-shm}" = "udp" ]; then
  if [ -z "${ROS_AUTOMATIC_DISCOVERY_RANGE:-}" ] \
      && [ "${FASTRTPS_DEFAULT_PROFILES_FILE:-$_af_udp_profile}" = "$_af_udp_profile" ]; then
    export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
  fi
  export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_af_udp_profile}"
fi
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_af_root/config/fastdds_localhost_shm.xml}"
unset _af_udp_profile
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# A run-unique domain unless the caller chose one (e.g. a multi-machine deployment): 1..101, ROS's
# safe range on Linux (0..101; a higher id's participant ports can fall in the kernel's ephemeral
# range; 0 is every ROS install's default domain, left to it).
# Unique on this machine, not just random: concurrent runs in one domain see each other's nodes
# and topics (another run's world, graph or start), and share Fast DDS's shared-memory ports.
# The shell holds an exclusive lock on $AF_DOMAIN_LOCK_DIR/<id>.lock (flock, on an inherited file
# descriptor: held while this shell or any process it started is alive, released by the kernel
# when the last of them exits, even on SIGKILL); the next shell takes the next free id.
if [ -z "${ROS_DOMAIN_ID:-}" ]; then
  _af_first=$(( ( $$ + $(date +%N | sed 's/^0*//;s/^$/0/') ) % 101 ))
  if command -v flock >/dev/null 2>&1 \
      && mkdir -p "${AF_DOMAIN_LOCK_DIR:=${TMPDIR:-/tmp}/ament_formation_domains}" 2>/dev/null; then
    for _af_i in $(seq 0 100); do
      _af_d=$(( (_af_first + _af_i) % 101 + 1 ))
      exec {AF_DOMAIN_LOCK_FD}>>"$AF_DOMAIN_LOCK_DIR/$_af_d.lock" || continue
      if flock -n "$AF_DOMAIN_LOCK_FD"; then
        export ROS_DOMAIN_ID=$_af_d
        break
      fi
      exec {AF_DOMAIN_LOCK_FD}>&-
    done
    unset _af_i _af_d
  fi
  # no flock, or all 101 ids taken: a random one, as before
  [ -n "${ROS_DOMAIN_ID:-}" ] || export ROS_DOMAIN_ID=$(( _af_first + 1 ))
  unset _af_first
fi
export ROS_LOG_DIR="${1:-${ROS_LOG_DIR:-$(mktemp -d -t ament_formation_log.XXXXXX)}}"
mkdir -p "$ROS_LOG_DIR"
export PYTHONUNBUFFERED=1
unset _af_root

# Shared memory the ROS processes of a run leave in /dev/shm: liblttng-ust (loaded by the ROS
# wheels) creates lttng-ust-wait-*, and Fast DDS's shared-memory transport leaves fastrtps_* and
# sem.fastrtps_* entries behind when a process is killed (a clean exit removes them; rmw_fastrtps
# keeps that same-host transport next to the loopback UDP one). af_shm_snapshot remembers what
# existed; af_shm_cleanup removes what appeared since (and what our processes used, below), once
# the run's processes are gone, and never an entry of a live participant: Fast DDS keeps a segment
# (fastrtps_<id>, fastrtps_port<N>) mapped, but its liveness lock file (<segment>_el, _sl) only
# open and its port mutex (sem.fastrtps_port<N>_mutex) neither mapped nor open between uses. So an
# entry is in use when any entry of its group (the name without sem. and _mutex/_el/_sl) is mapped
# or open by a live process. Removing a live participant's lock file or mutex (as the clean-up did
# before, for any entry not mapped) broke its shared-memory delivery: another run's world, recorder
# and controllers stopped hearing each other mid-run.
# af_shm_note_used PID...: also remove, at clean-up, the entries these processes map or hold open
# now (call it just before stopping them): an entry that existed before our snapshot but that our
# processes used is ours to remove too once nobody uses it. Without this, launchers started one
# after the other and stopped together left entries behind: the first one's were in the later
# ones' snapshots, and when the first one cleaned up, the later ones' processes still used them.
_af_shm_pattern='^(lttng-ust-wait|fastrtps_|sem\.fastrtps_)'
AF_SHM_DIR="${AF_SHM_DIR:-/dev/shm}"
af_shm_snapshot() {
  _af_shm_before="$(ls "$AF_SHM_DIR" 2>/dev/null | grep -E "$_af_shm_pattern" || true)"
  _af_shm_used=""
}
_af_shm_group() {  # stdin: names -> their groups
  sed -E 's/^sem\.//; s/_(mutex|el|sl)$//'
}
_af_shm_open_by() {  # PID... (none: every process): the names in AF_SHM_DIR they map or hold open
  local dirs=() pid
  if [ $# -eq 0 ]; then dirs=(/proc/[0-9]*); else for pid in "$@"; do dirs+=("/proc/$pid"); done; fi
  {
    for pid in "${dirs[@]}"; do cat "$pid/maps" 2>/dev/null; done | grep -o "$AF_SHM_DIR/[^ ]*"
    for pid in "${dirs[@]}"; do ls -l "$pid/fd" 2>/dev/null; done | grep -o "$AF_SHM_DIR/[^ ]*"
  } | sed "s|^$AF_SHM_DIR/||" | sort -u || true
}
af_shm_note_used() {
  [ $# -gt 0 ] || return 0
  _af_shm_used+="$(_af_shm_open_by "$@" | _af_shm_group)"$'\n'
}
af_shm_cleanup() {
  local f key busy names
  # the names first, then who uses them: an entry made after the scan of the processes (another
  # run starting) would otherwise count as unused, and its participant as dead (docs/executors.md)
  names="$(ls "$AF_SHM_DIR" 2>/dev/null | grep -E "$_af_shm_pattern" || true)"
  busy="$(_af_shm_open_by | _af_shm_group | sort -u)"
  for f in $names; do
    key="${f#sem.}"; key="${key%_mutex}"; key="${key%_el}"; key="${key%_sl}"
    if grep -qxF "$key" <<<"$busy"; then
      continue  # its group is in use by a live process
    fi
    if ! grep -qxF "$f" <<<"${_af_shm_before:-}" || grep -qxF "$key" <<<"${_af_shm_used:-}"; then
      rm -f "${AF_SHM_DIR:?}/$f"
    fi
  done
}
