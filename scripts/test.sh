#!/usr/bin/env bash
# Run the whole test suite (creates .venv first when it is missing). Extra args go to pytest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
"$here/scripts/install_firmware_deps.sh" || { [ "$?" -eq 3 ] && export AMENT_FORMATION_NO_FIRMWARE_TOOLCHAIN=1; }  # exit 3: apt unusable -> firmware tests skip
logdir="$(mktemp -d -t ament_formation_test.XXXXXX)"
# shellcheck source=ros_env.sh
source "$here/scripts/ros_env.sh" "$logdir/ros_log"
af_shm_snapshot
trap 'af_shm_cleanup; rm -rf "$logdir"' EXIT
cd "$here"
# the tests find the programs on PATH (test/processes.py program()); in a ROS 2 workspace they are
# found in the sourced install prefix instead
export PATH="$here/.venv/bin:$PATH"
# two workers, one test module each at a time (module fixtures stay in one process); each module
# takes its own DDS domain (test/conftest.py), so the workers do not hear each other.
# AMENT_FORMATION_TEST_WORKERS=0 runs everything in this process.
workers="${AMENT_FORMATION_TEST_WORKERS:-2}"
status=0
"$here/.venv/bin/python" -m pytest -p no:cacheprovider -n "$workers" --dist loadfile "$@" || status=$?
exit "$status"
