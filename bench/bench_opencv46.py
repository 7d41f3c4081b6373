"""The vision and tracker tests under OpenCV 4.6 (python3-opencv of Debian 12 / Ubuntu 24.04).

    bench/run.sh bench_opencv46.py [TEST_FILE ...] [--out FILE.json]

Installs opencv-contrib-python-headless 4.6.0.66 and numpy 1.26.4 with ``pip install --target``
into ~/.cache/ament_formation (test/opencv_overlay.py; reused offline afterwards), puts them in
front of the venv's packages (PYTHONPATH) and runs each test file with pytest; prints one line per
file (passed, failed, skipped, seconds) and the failures' names.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import re
import subprocess
import sys
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))
sys.path.insert(0, str(ROOT))

from opencv_overlay import env, overlay  # noqa: E402

FILES = (
    'test/test_synthetic_camera.py',
    'test/test_marker_tracking.py',
    'test/test_calibration.py',
    'test/test_markers.py',
    'test/test_ros_calibration.py',
    'test/test_tracker_node.py',
    'test/test_tracker_source.py',
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('files', nargs='*', default=list(FILES))
    ap.add_argument('--out', default='', help='also write the results as JSON')
    args = ap.parse_args()
    folder = overlay(contrib=True)
    if folder is None:
        print('bench_opencv46: cannot install opencv-contrib-python-headless 4.6.0.66',
              file=sys.stderr)
        return 1
    results = []
    for f in args.files:
        t0 = time.monotonic()
        res = subprocess.run(
            [sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '-rf', f],
            cwd=ROOT, env=env(folder), capture_output=True, text=True,
        )
        tail = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else res.stderr[-300:]
        counts = {k: int(n) for n, k in re.findall(r'(\d+) (passed|failed|skipped|error)', tail)}
        failed = re.findall(r'^FAILED (\S+)', res.stdout, re.M)
        results.append({'file': f, 'seconds': round(time.monotonic() - t0, 1), **counts,
                        'failures': failed})
        print(f'{f}: {tail}', flush=True)
        for name in failed:
            print(f'  FAILED {name}')
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
