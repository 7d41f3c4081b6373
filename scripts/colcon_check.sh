#!/usr/bin/env bash
# Former name of scripts/workspace_check.sh (same options): build and test a fresh clone in a ROS 2
# workspace with no .venv in the source, on the emulated system ROS. See that script.
exec "$(dirname "${BASH_SOURCE[0]}")/workspace_check.sh" "$@"
