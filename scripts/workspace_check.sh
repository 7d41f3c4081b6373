#!/usr/bin/env bash
# Build and test this package in a ROS 2 workspace the way a lab does, with no .venv in the source:
#   source /opt/ros/jazzy/setup.bash      # here: an emulated system ROS (below)
#   mkdir -p ws/src && git clone <repo> ws/src/ament_formation && cd ws
#   colcon build && source install/setup.bash && colcon test && colcon test-result --verbose
#
# Usage: scripts/workspace_check.sh [--work DIR] [--keep] [--from-worktree] [--build-only]
#                                   [--subset] [--pin NAME==VERSION]... [-- PYTEST ARGS...]
#   --work DIR       workspace folder (default: a new folder under /tmp, removed at the end
#                    unless --keep)
#   --from-worktree  src/ament_formation is a copy of the working tree's files (tracked and
#                    untracked, not ignored; no .venv), not a clone of the committed HEAD
#   --build-only     stop after colcon build (test/test_workspace.py then starts the programs)
#   --subset         every test but the five files that run whole missions over and over
#                    (SLOW_TESTS below)
#   --pin NAME==VER  install this version in the emulated system instead of requirements.txt's
#                    (e.g. --pin numpy==1.26.4: the NumPy of Ubuntu 24.04); repeatable
#   PYTEST ARGS      passed to colcon test --pytest-args (default: the whole suite), e.g.
#                    -- test/test_params_files.py (an option needs a leading space: -- " -k x")
#
# The emulated system ROS: there is no /opt/ros on this project's machines, so a venv OUTSIDE the
# source tree holds what `rosdep install` and a Jazzy install would provide: the ros-jazzy-*
# wheels (rclpy, the message packages, ament_index_python), the package.xml dependencies at the
# versions of requirements.txt (or --pin), and colcon from PyPI. Its setup.bash plays
# /opt/ros/jazzy/setup.bash: PATH and the ROS libraries on LD_LIBRARY_PATH. It is kept in
# $AF_SYSTEM_ROS (default ~/.cache/ament_formation/system-ros-<hash of its inputs>) and made
# once. Everything else runs in a clean environment (env -i): nothing of the caller's .venv,
# PYTHONPATH or LD_LIBRARY_PATH reaches the workspace.
# Numba's kernels compile into WORK/numba_cache and pytest's temporary folders go to WORK/pytest.
# Exit status: that of colcon test-result (0: every test passed), of colcon build with
# --build-only, 2 for bad usage.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
work=""
keep=0
from_worktree=0
build_only=0
subset=0
pins=()
pytest_args=()
SLOW_TESTS=(test_run_cmd.py test_live_view.py test_multihost.py test_tracker_source.py test_system.py)
COLCON_PINS=(colcon-common-extensions==0.3.0 colcon-ros==0.5.0 colcon-core==0.21.3)
usage='usage: --work DIR, --keep, --from-worktree, --build-only, --subset, --pin NAME==VER, -- PYTEST ARGS'
while [ $# -gt 0 ]; do
  case "$1" in
    --work) [ $# -ge 2 ] || { echo "workspace_check: --work needs a folder ($usage)" >&2; exit 2; }
      work="$2"; shift 2 ;;
    --keep) keep=1; shift ;;
    --from-worktree) from_worktree=1; shift ;;
    --build-only) build_only=1; shift ;;
    --subset) subset=1; shift ;;
    --pin)
      [[ "${2:-}" =~ ^[A-Za-z0-9._-]+==[A-Za-z0-9.+!-]+$ ]] || {
        echo "workspace_check: --pin: expected NAME==VERSION, got '${2:-}'" >&2; exit 2; }
      pins+=("$2"); shift 2 ;;
    --) shift; pytest_args=("$@"); break ;;
    *) echo "workspace_check: unknown argument $1 ($usage)" >&2; exit 2 ;;
  esac
done
if [ -z "$work" ]; then
  work="$(mktemp -d /tmp/af_ws_XXXXXX)"
  [ "$keep" = 1 ] || trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
work="$(cd "$work" && pwd)"

# 1. the emulated system ROS (once per set of inputs; a lock keeps concurrent runs from racing)
requirements="$work/system_requirements.txt"
cp "$here/requirements.txt" "$requirements"
for pin in "${pins[@]}"; do
  name="${pin%%==*}"
  key="$(tr 'A-Z_.' 'a-z--' <<<"$name")"
  # drop requirements.txt's pin of that name (PyPI names compare case- and -_.-insensitively)
  awk -v k="$key" '{ n = $0; sub(/[=<>!~ ;#].*/, "", n); n = tolower(n); gsub(/[_.]/, "-", n);
                     if (n != k) print }' "$requirements" >"$requirements.new"
  mv "$requirements.new" "$requirements"
  echo "$pin" >>"$requirements"
done
printf '%s\n' "${COLCON_PINS[@]}" >>"$requirements"
hash="$( { cat "$requirements"; python3 -c 'import sys; print(sys.version)'; } | sha256sum | cut -c1-16)"
cache_root="${XDG_CACHE_HOME:-$HOME/.cache}/ament_formation"
system_ros="${AF_SYSTEM_ROS:-$cache_root/system-ros-$hash}"
mkdir -p "$(dirname "$system_ros")"
exec {lock_fd}>"$system_ros.lock"
flock "$lock_fd"
if [ ! -f "$system_ros/setup.bash" ]; then   # written last: a venv without it is incomplete
  echo "workspace_check: creating the emulated system ROS in $system_ros (a few minutes, once)" >&2
  rm -rf "$system_ros"
  python3 -m venv "$system_ros"
  env -u PYTHONPATH -u _ROS_WHEELS_BOOTSTRAP_COMPLETE -u LD_LIBRARY_PATH \
    "$system_ros/bin/python" -m pip install --quiet --disable-pip-version-check -r "$requirements"
  site="$("$system_ros/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
  cp "$requirements" "$system_ros/requirements.txt"
  cat >"$system_ros/setup.bash" <<EOF
# The emulated /opt/ros/jazzy/setup.bash (scripts/workspace_check.sh): the system's programs on
# PATH and the ROS libraries on LD_LIBRARY_PATH, as a ROS install's setup.bash sets them.
export PATH="$system_ros/bin:\$PATH"
_af_libs="$system_ros/lib\$(for d in "$site"/ros_*.libs; do [ -d "\$d" ] && printf ':%s' "\$d"; done)"
export LD_LIBRARY_PATH="\$_af_libs\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1   # the wheels' re-exec that sets the same is not needed
export ROS_DISTRO=jazzy ROS_VERSION=2 ROS_PYTHON_VERSION=3
unset _af_libs
EOF
fi
flock -u "$lock_fd"
echo "workspace_check: system ROS $system_ros" >&2

# 2. the workspace: src/ament_formation without .venv
src="$work/src/ament_formation"
rm -rf "$work/src" "$work/build" "$work/install" "$work/log"
mkdir -p "$work/src"
if [ "$from_worktree" = 1 ]; then
  mkdir -p "$src"
  if git -C "$here" rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    (cd "$here" && git ls-files -z --cached --others --exclude-standard \
      | while IFS= read -r -d '' f; do [ -e "$f" ] && printf '%s\0' "$f"; done \
      | xargs -0 cp -p --parents -t "$src")
  else   # a source tree without git (an archive): everything but environments and outputs
    tar -C "$here" --exclude=./.venv --exclude=./build --exclude=./install --exclude=./log \
      --exclude=./out --exclude='*.egg-info' --exclude=__pycache__ -cf - . | tar -C "$src" -xf -
  fi
  echo "workspace_check: workspace $work (the working tree of $here)" >&2
else
  git clone --quiet "$here" "$src"
  echo "workspace_check: workspace $work (clone of $(git -C "$here" rev-parse --short HEAD))" >&2
fi
if [ -e "$src/.venv" ]; then
  echo "workspace_check: $src/.venv exists; the workspace must not have one" >&2; exit 1
fi

# 3. build and test in a clean environment: the system ROS, then the workspace's install
clean_env=(env -i HOME="$HOME" USER="${USER:-$(id -un)}" LANG=C.UTF-8 TERM="${TERM:-dumb}"
  PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin TMPDIR="${TMPDIR:-/tmp}"
  AMENT_FORMATION_CACHE_DIR="$work/numba_cache" CI="${CI:-}")
[ -n "${AMENT_FORMATION_NO_FIRMWARE_TOOLCHAIN:-}" ] \
  && clean_env+=(AMENT_FORMATION_NO_FIRMWARE_TOOLCHAIN="$AMENT_FORMATION_NO_FIRMWARE_TOOLCHAIN")
build_cmd='source "$SYSTEM_ROS/setup.bash" && cd "$WS" && colcon build --event-handlers console_direct-'
"${clean_env[@]}" SYSTEM_ROS="$system_ros" WS="$work" bash -c "$build_cmd"
# WORK/env.bash: the environment of a lab's shell after the build (test/test_workspace.py uses it)
cat >"$work/env.bash" <<EOF
source "$system_ros/setup.bash"
source "$work/install/setup.bash"
export AMENT_FORMATION_CACHE_DIR="$work/numba_cache"
EOF
echo "workspace_check: colcon build done; source $work/env.bash for its environment" >&2
if [ "$build_only" = 1 ]; then
  exit 0
fi
test_args=(--event-handlers console_direct+ --return-code-on-test-failure
  --pytest-args " --basetemp=$work/pytest" "${pytest_args[@]}")
if [ "$subset" = 1 ]; then
  for f in "${SLOW_TESTS[@]}"; do test_args+=(" --ignore=test/$f"); done
fi
# DDS stays on loopback (the installed scripts/ros_env.sh; test/conftest.py sets the same).
# Numba's kernels are compiled first, as scripts/setup.sh does, for both copies the tests run (the
# source tree's, which pytest imports, and the installed one, which the programs run; from log/,
# a folder without the package, python imports the installed copy): outside pytest's 300 s
# per-test timeout, which the test session's own warm-up counts against its first test.
test_cmd='source "$SYSTEM_ROS/setup.bash" && cd "$WS" && source install/setup.bash &&
  source install/ament_formation/share/ament_formation/scripts/ros_env.sh "$WS/ros_log" >/dev/null &&
  af_shm_snapshot && trap af_shm_cleanup EXIT &&
  warm="import sys; from ament_formation.core.sim.jit_warm import main; sys.exit(main())" &&
  { (cd src/ament_formation && python3 -c "$warm") && (cd log && python3 -c "$warm") ||
    echo "workspace_check: warning: compiling the numba kernels failed" >&2; } &&
  status=0 && { colcon test "$@" || status=$?; } &&
  echo "workspace_check: colcon test exited $status" >&2 &&
  colcon test-result --verbose'
t0=$SECONDS
status=0
"${clean_env[@]}" SYSTEM_ROS="$system_ros" WS="$work" bash -c "$test_cmd" bash "${test_args[@]}" \
  || status=$?
echo "workspace_check: colcon test and test-result took $((SECONDS - t0)) s, exit $status" >&2
exit "$status"
