#!/usr/bin/env bash
# Create .venv from the pinned requirements when it is missing (idempotent), and install this
# package into it in editable mode. Every other script calls this first.
# Then compile numba's kernels once, into the cache folder of the current core sources
# (ament_formation/core/jit_cache.py), unless that folder is warm already: the processes of a run
# load them instead of all compiling at once.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$here/.venv"
stamp="$venv/.requirements.sha256"
want="$(sha256sum "$here/requirements.txt" "$here/setup.py" | sha256sum | cut -d' ' -f1)"

warm_numba() {
  # from the checkout's folder: `python -c` imports the package of its working folder first, and
  # the caller's may hold another checkout
  (cd "$here" && "$venv/bin/python" -c 'import sys; from ament_formation.core.sim.jit_warm import main; sys.exit(main())') \
    || echo "setup: warning: compiling the numba kernels failed; they compile on first use" >&2
}

if [ -x "$venv/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
  warm_numba
  exit 0
fi
command -v python3 >/dev/null || { echo "setup: python3 is required (Debian: apt-get install python3 python3-venv)" >&2; exit 1; }
if [ ! -x "$venv/bin/python" ]; then
  echo "setup: creating $venv" >&2
  python3 -m venv "$venv" || { echo "setup: python3 -m venv failed (Debian: apt-get install python3-venv)" >&2; exit 1; }
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements.txt"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e "$here"
# setup.cfg puts console scripts in lib/ament_formation (where `ros2 run` looks); link them
# into the venv's bin/ too so `.venv/bin/formation` works.
for exe in "$venv"/lib/ament_formation/*; do
  [ -f "$exe" ] && ln -sf "$exe" "$venv/bin/$(basename "$exe")"
done
echo "$want" > "$stamp"
echo "setup: .venv ready" >&2
warm_numba

