# Sourced by scripts/launch_*.sh: start processes, remember their PIDs, stop exactly those on exit.
#
#   af_launch_init RUN_DIR [--multi-machine]   environment (loopback DDS unless --multi-machine), traps
#   af_start NAME CMD ARGS...                  start CMD in the background, log to RUN_DIR/NAME.log
#   af_wait_any [TIMEOUT_S]                    wait until one started process exits (or the timeout)
#
# A launcher's exit status: 143 when stopped by SIGTERM, 130 by Ctrl-C (SIGINT), else the status of
# the first started process that exited (0 when --duration ran out); 2 for bad input.
#
# Several machines: --multi-machine (the default of launch_robot.sh and launch_base.sh, see
# af_choose_network) with the same ROS_DOMAIN_ID on every machine. That sets
# ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET and replaces the loopback-only Fast DDS profile by the
# project's UDP profile (config/fastdds_udp.xml), so DDS uses every interface of the machine; use
# it only on a trusted robot network. A lab's own Fast DDS profile is kept: export
# FASTRTPS_DEFAULT_PROFILES_FILE=/path/lab_profile.xml before launching (e.g. to pin DDS to the
# robot network's interface); a file that does not exist is bad input (exit code 2).
# docs/multi-machine.md.
AF_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# The programs (af_find_programs): $AF_BIN when the caller sets it; for the launchers colcon build
# installs (<prefix>/share/ament_formation/scripts, what `formation run` of an installed package
# starts) the console scripts of that install, <prefix>/lib/ament_formation; else formation_world
# on PATH; else <prefix>/lib/ament_formation of a prefix in AMENT_PREFIX_PATH (a sourced
# install/setup.bash: ros2 run's place); else the checkout's own environment (scripts/setup.sh's
# .venv, the project's own set-up). AF_PYTHON runs launch_info.py: the interpreter of the programs
# (their #! line), which imports the same package.
af_find_programs() {
  local d prefix
  if [ -n "${AF_BIN:-}" ]; then
    d="$AF_BIN"
  elif [ -x "$AF_ROOT/../../lib/ament_formation/formation_world" ]; then
    d="$AF_ROOT/../../lib/ament_formation"
  elif command -v formation_world >/dev/null 2>&1; then
    d="$(dirname "$(command -v formation_world)")"
  else
    d=""
    while IFS= read -r prefix; do
      if [ -n "$prefix" ] && [ -x "$prefix/lib/ament_formation/formation_world" ]; then
        d="$prefix/lib/ament_formation"; break
      fi
    done < <(tr ':' '\n' <<<"${AMENT_PREFIX_PATH:-}")
    [ -n "$d" ] || { [ -x "$AF_ROOT/.venv/bin/formation_world" ] && d="$AF_ROOT/.venv/bin"; }
  fi
  if [ -z "$d" ] || [ ! -x "$d/formation_world" ]; then
    echo "$(basename "$0"): the ament_formation programs (formation_world, ...) are not installed:" \
      "run scripts/setup.sh in a checkout, or colcon build and source install/setup.bash" >&2
    exit 2
  fi
  AF_BIN="$(cd "$d" && pwd)"
  local shebang=""
  read -r shebang <"$AF_BIN/formation_world" || true
  read -r -a AF_PYTHON <<<"${shebang#\#!}"
  case "$(basename "${AF_PYTHON[0]:-sh}")" in
    python*|env) ;;
    *) AF_PYTHON=(python3) ;;   # e.g. setuptools' /bin/sh wrapper for a very long interpreter path
  esac
}
af_find_programs
# every node's params file (every parameter with its default; installed by colcon build to
# share/ament_formation/config/params): launchers pass it first, then their -p overrides
AF_PARAMS_DIR="$AF_ROOT/config/params"
AF_PIDS=()
AF_NAMES=()

af_launch_init() {
  AF_RUN_DIR="$1"; shift
  local multi=0
  [ "${1:-}" = "--multi-machine" ] && multi=1
  if [ "$multi" = 1 ] && [ -z "${ROS_DOMAIN_ID:-}" ]; then
    echo "--multi-machine: export the same ROS_DOMAIN_ID (0..101) on every machine first" >&2
    exit 2
  fi
  # a lab's own Fast DDS profile (anything but the project's two one-machine profiles) survives
  # --multi-machine
  local lab_profile="${FASTRTPS_DEFAULT_PROFILES_FILE:-}"
  case "$lab_profile" in
    "$AF_ROOT/config/fastdds_localhost.xml" | "$AF_ROOT/config/fastdds_localhost_shm.xml")
      lab_profile="" ;;
  esac
  if [ "$multi" = 1 ] && [ -n "$lab_profile" ] && [ ! -f "$lab_profile" ]; then
    echo "$(basename "$0"): FASTRTPS_DEFAULT_PROFILES_FILE (the lab network's Fast DDS profile): no such file '$lab_profile'" >&2
    exit 2
  fi
  mkdir -p "$AF_RUN_DIR"
  # shellcheck source=ros_env.sh
  source "$AF_ROOT/scripts/ros_env.sh" "$AF_RUN_DIR/ros_log"
  if [ "$multi" = 1 ]; then
    export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
    # a lab's own profile, else the project's UDP one (no shared memory, non-blocking sends)
    export FASTRTPS_DEFAULT_PROFILES_FILE="${lab_profile:-$AF_ROOT/config/fastdds_udp.xml}"
  fi
  af_shm_snapshot
  : >"$AF_RUN_DIR/pids"
  trap af_stop_all EXIT
  trap 'exit 130' INT
  trap 'exit 143' TERM
}

af_start() {
  local name="$1"; shift
  "$@" >"$AF_RUN_DIR/$name.log" 2>&1 &
  AF_PIDS+=("$!")
  AF_NAMES+=("$name")
  echo "$! $name" >>"$AF_RUN_DIR/pids"
  echo "started $name (pid $!)"
}

af_alive() { kill -0 "$1" 2>/dev/null; }

# Stop every process we started, newest first: SIGTERM (rclpy shuts down cleanly on it; SIGINT is
# ignored by background jobs of a script), then SIGKILL for anything still there after 4 s.
# Only our own PIDs are signalled.
af_stop_all() {
  local status=$? i pid deadline
  trap - EXIT INT TERM
  af_shm_note_used "${AF_PIDS[@]}"
  for (( i=${#AF_PIDS[@]}-1; i>=0; i-- )); do
    pid="${AF_PIDS[$i]}"; af_alive "$pid" && kill -TERM "$pid" 2>/dev/null || true
  done
  for sig in KILL; do
    deadline=$(( $(date +%s%N) + 4000000000 ))
    while [ "$(date +%s%N)" -lt "$deadline" ]; do
      local any=0
      for pid in "${AF_PIDS[@]}"; do af_alive "$pid" && any=1; done
      [ "$any" = 0 ] && break
      sleep 0.05
    done
    for (( i=${#AF_PIDS[@]}-1; i>=0; i-- )); do
      pid="${AF_PIDS[$i]}"
      if af_alive "$pid"; then
        echo "stopping ${AF_NAMES[$i]} (pid $pid) with SIG$sig" >&2
        kill -"$sig" "$pid" 2>/dev/null || true
      fi
    done
  done
  for pid in "${AF_PIDS[@]}"; do wait "$pid" 2>/dev/null || true; done
  af_shm_cleanup
  echo "stopped ${#AF_PIDS[@]} processes"
  exit "$status"
}

# Wait until any started process exits (returns its status), or TIMEOUT_S passed (returns 0).
af_wait_any() {
  local timeout_s="${1:-}" i
  local deadline=""
  [ -n "$timeout_s" ] && deadline=$(( $(date +%s%N) + ${timeout_s%.*} * 1000000000 ))
  while true; do
    for i in "${!AF_PIDS[@]}"; do
      if ! af_alive "${AF_PIDS[$i]}"; then
        local rc=0
        wait "${AF_PIDS[$i]}" || rc=$?
        echo "${AF_NAMES[$i]} exited with status $rc"
        return "$rc"
      fi
    done
    if [ -n "$deadline" ] && [ "$(date +%s%N)" -ge "$deadline" ]; then return 0; fi
    sleep 0.1
  done
}

# The network of the real-robot launchers (launch_robot.sh, launch_base.sh):
#   af_choose_network PROG LOOPBACK DOMAIN      sets AF_NETWORK (the argument of af_launch_init)
# The lab network by default: ROS_DOMAIN_ID from --domain N (else the exported one), which must be
# in ROS's safe range on Linux (0..101) and the same on every machine; discovery on the subnet;
# the project's UDP profile (config/fastdds_udp.xml: no shared memory, non-blocking sends) unless
# the lab exported its own FASTRTPS_DEFAULT_PROFILES_FILE. LOOPBACK non-empty (--loopback): this
# machine only, as launch_sim.sh. AMENT_FORMATION_LOOPBACK_ONLY (set by the tests and benchmarks)
# refuses the lab network: nothing they start leaves loopback by a forgotten --loopback.
af_choose_network() {
  local prog="$1" loopback="$2" domain="$3"
  if [ -n "$domain" ]; then
    if ! [[ "$domain" =~ ^[0-9]{1,3}$ ]] || [ "$domain" -gt 101 ]; then
      echo "$prog: --domain: expected a ROS domain id in [0, 101] (ROS's safe range on Linux), got '$domain'" >&2
      exit 2
    fi
    export ROS_DOMAIN_ID="$domain"
  fi
  AF_NETWORK=()
  [ -n "$loopback" ] && return 0
  if [ -n "${AMENT_FORMATION_LOOPBACK_ONLY:-}" ]; then
    echo "$prog: the lab network is refused here (AMENT_FORMATION_LOOPBACK_ONLY is set: tests and benchmarks stay on loopback); add --loopback" >&2
    exit 2
  fi
  if [ -z "${ROS_DOMAIN_ID:-}" ]; then
    echo "$prog: the lab network needs the domain id all its machines use: --domain N (0..101) or export ROS_DOMAIN_ID (--loopback: this machine only)" >&2
    exit 2
  fi
  if ! [[ "$ROS_DOMAIN_ID" =~ ^[0-9]{1,3}$ ]] || [ "$ROS_DOMAIN_ID" -gt 101 ]; then
    echo "$prog: ROS_DOMAIN_ID: expected a ROS domain id in [0, 101] (ROS's safe range on Linux), got '$ROS_DOMAIN_ID'" >&2
    exit 2
  fi
  AF_NETWORK=(--multi-machine)
}
