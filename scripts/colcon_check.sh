#!/usr/bin/env bash
# Build and test a fresh clone of this repository the way a ROS 2 workspace does:
#   colcon build && colcon test && colcon test-result --verbose
#
# Usage: scripts/colcon_check.sh [--work DIR] [--keep] [--subset] [-- PYTEST ARGS...]
#   --work DIR   workspace folder (default: a new folder under /tmp, removed at the end unless --keep)
#   --subset     every test but the five files that run whole missions over and over (SLOW_TESTS
#                below: ~2/3 of the suite's time); lint, the params files, the programs' mission
#                (test_programs), the launchers and every unit and node test stay (docs/package.md)
#   PYTEST ARGS  passed to colcon test --pytest-args (default: the whole suite), e.g.
#                -- test/test_params_files.py test/test_scenario_validation.py
#                (an option needs a leading space for colcon's parser: -- " -k params")
#
# There is no ROS 2 install on this machine: rclpy and the messages come from the ros-jazzy-*
# wheels in the clone's own .venv (scripts/setup.sh), and colcon lives in a venv of its own
# ($COLCON_VENV, default /tmp/colcon_venv; created with pinned versions when missing). Two things
# connect them:
#   * a .pth file in colcon's venv adds the clone's .venv site-packages (after colcon's own), so
#     the python colcon runs pytest with imports rclpy, numpy, hypothesis, ...;
#   * LD_LIBRARY_PATH for the ROS libraries, as the wheels' bootstrapper sets it for .venv/bin/python
#     (_ROS_WHEELS_BOOTSTRAP_COMPLETE=1 tells it the environment is already set).
# The run is self-contained: numba's compiled kernels go to WORK/numba_cache
# (AMENT_FORMATION_CACHE_DIR; both copies of the package compile there once: the clone's, which
# pytest imports, and the installed one, which the programs run) and pytest's temporary folders to
# WORK/pytest (pytest --basetemp): other runs on the machine neither prune the cache during
# the run nor rotate away the logs of a failed test (kept with --keep).
# On a machine with ROS 2 Jazzy installed, none of this is needed:
#   source /opt/ros/jazzy/setup.bash && colcon build && colcon test && colcon test-result --verbose
# Exit status: that of colcon test-result (0 when every test passed), 2 for bad usage.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
work=""
keep=0
pytest_args=()
subset=0
# whole-system tests: formation run end to end (test_run_cmd, test_live_view), network namespaces
# (test_multihost), camera sources through the system (test_tracker_source), all nodes in one
# process (test_system)
SLOW_TESTS=(test_run_cmd.py test_live_view.py test_multihost.py test_tracker_source.py test_system.py)
while [ $# -gt 0 ]; do
  case "$1" in
    --work) work="$2"; shift 2 ;;
    --keep) keep=1; shift ;;
    --subset) subset=1; shift ;;
    --) shift; pytest_args=("$@"); break ;;
    *) echo "colcon_check: unknown argument $1 (usage: --work DIR, --keep, --subset, -- PYTEST ARGS)" >&2; exit 2 ;;
  esac
done
if [ -z "$work" ]; then
  work="$(mktemp -d /tmp/af_colcon_XXXXXX)"
  [ "$keep" = 1 ] || trap 'rm -rf "$work"' EXIT
fi
colcon_venv="${COLCON_VENV:-/tmp/colcon_venv}"

# 1. colcon, in its own venv
if [ ! -x "$colcon_venv/bin/colcon" ]; then
  echo "colcon_check: creating $colcon_venv" >&2
  python3 -m venv "$colcon_venv"
  "$colcon_venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    colcon-common-extensions==0.3.0 colcon-ros==0.5.0 colcon-core==0.21.3
fi

# 2. a workspace holding a fresh clone of the committed tree (HEAD)
src="$work/src/ament_formation"
rm -rf "$src" "$work/build" "$work/install" "$work/log"
mkdir -p "$work/src"
git clone --quiet "$here" "$src"
echo "colcon_check: workspace $work (clone of $(git -C "$here" rev-parse --short HEAD))" >&2

# 3. the clone's .venv: rclpy and the pinned dependencies (what /opt/ros/jazzy would provide)
export AMENT_FORMATION_CACHE_DIR="$work/numba_cache"
t0=$SECONDS
"$src/scripts/setup.sh"
echo "colcon_check: clone and .venv ready in $((SECONDS - t0)) s" >&2
venv_site="$("$src/.venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
colcon_site="$("$colcon_venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
echo "import site; site.addsitedir('$venv_site')" > "$colcon_site/ament_formation_venv.pth"
LD_LIBRARY_PATH="$("$src/.venv/bin/python" -c 'import os; print(os.environ.get("LD_LIBRARY_PATH", ""))')"
export LD_LIBRARY_PATH _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
# DDS stays on loopback (test/conftest.py sets the same for the tests)
# shellcheck source=ros_env.sh
source "$src/scripts/ros_env.sh" "$work/ros_log" >/dev/null
export PATH="$colcon_venv/bin:$PATH"

# 4. build, test, results
cd "$work"
t0=$SECONDS
colcon build --event-handlers console_direct-
echo "colcon_check: colcon build took $((SECONDS - t0)) s" >&2
# colcon sets PYTEST_ADDOPTS itself: pytest's own options go through --pytest-args (a leading
# space keeps colcon's parser from taking them for its own; colcon strips it)
test_args=(test --event-handlers console_direct+ --return-code-on-test-failure
  --pytest-args " --basetemp=$work/pytest" "${pytest_args[@]}")
if [ "$subset" = 1 ]; then
  for f in "${SLOW_TESTS[@]}"; do test_args+=(" --ignore=test/$f"); done
fi
test_status=0
t0=$SECONDS
colcon "${test_args[@]}" || test_status=$?
echo "colcon_check: colcon test exited $test_status after $((SECONDS - t0)) s" >&2
echo "colcon_check: installed params files:" \
  $(ls "$work/install/ament_formation/share/ament_formation/config/params") >&2
colcon test-result --verbose
