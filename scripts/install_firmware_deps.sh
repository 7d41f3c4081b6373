#!/usr/bin/env bash
# Install the Debian packages the firmware build and its emulator tests need (idempotent).
#   gcc-avr binutils-avr avr-libc : cross toolchain for the ATmega328P (make -C firmware)
#   simavr libsimavr-dev libsimavrparts1 libelf-dev : emulator library + headers for firmware/sim
#   avrdude : flashing a real board (make -C firmware flash PORT=...)
#   gcc make pkg-config : host build of the protocol tests and the simavr harness
# Exit status: 0 when everything is present afterwards; 3 when apt-get is not usable here
# (not root and no sudo, or no apt at all) so callers can skip the firmware tests with a message.
set -euo pipefail
packages=(gcc-avr binutils-avr avr-libc simavr libsimavr-dev libsimavrparts1 libelf-dev avrdude gcc make pkg-config)
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
    echo "install_firmware_deps: apt-get not available; missing: ${missing[*]}" >&2
    exit 3
fi
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        sudo_cmd=(sudo -n)
    else
        echo "install_firmware_deps: not root and no passwordless sudo; missing: ${missing[*]}" >&2
        exit 3
    fi
fi
echo "install_firmware_deps: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq >&2
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
