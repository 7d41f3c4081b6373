#!/usr/bin/env bash
# Install the Debian packages `formation multihost --clock-shift` needs (idempotent).
#   libfaketime : LD_PRELOAD library that shifts a process's wall clock (CLOCK_REALTIME), used to
#                 give a robot host a clock that is off the camera PC's (docs/multi-machine.md)
#   gcc libc6-dev : builds the small clock_nanosleep fix preloaded with it (tools/clock_shift.py)
# Exit status: 0 when it is present afterwards; 3 when apt-get is not usable here (not root and
# no sudo, or no apt at all) so callers can skip the clock tests with a message.
set -euo pipefail
packages=(libfaketime gcc libc6-dev)
missing=()
for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
if [ "${#missing[@]}" -eq 0 ]; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "install_clock_deps: apt-get not available; missing: ${missing[*]}" >&2
    exit 3
fi
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        sudo_cmd=(sudo -n)
    else
        echo "install_clock_deps: not root and no passwordless sudo; missing: ${missing[*]}" >&2
        exit 3
    fi
fi
echo "install_clock_deps: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq >&2
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
