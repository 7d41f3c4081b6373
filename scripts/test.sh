#!/usr/bin/env bash
# Run the whole test suite (creates .venv first when it is missing). Extra args go to pytest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/setup.sh"
logdir="$(mktemp -d -t ament_formation_test.XXXXXX)"
trap 'rm -rf "$logdir"' EXIT
# shellcheck source=ros_env.sh
source "$here/scripts/ros_env.sh" "$logdir/ros_log"
cd "$here"
exec_status=0
"$here/.venv/bin/python" -m pytest -p no:cacheprovider "$@" || exec_status=$?
exit "$exec_status"
