"""Robot hosts whose wall clocks are off: `formation multihost --clock-shift ROBOT:SECONDS`
(issue 33, docs/multi-machine.md "Shifted clocks").

Every process of robot ROBOT's host (its ``scripts/launch_robot.sh`` and everything it starts)
runs with libfaketime preloaded and ``FAKETIME="+S"`` (a relative offset: the host's
CLOCK_REALTIME reads the true time + S, and keeps running at the true rate). ROS time stamps,
log lines and ``time.time()`` of that host are then S seconds ahead of the camera PC's.

The monotonic clock is left true (``FAKETIME_DONT_FAKE_MONOTONIC=1``), deliberately: a computer
whose wall clock is set wrong still has a true CLOCK_MONOTONIC (time since boot, untouched by
``date -s`` or an NTP step), and that is what a run should model. Without it libfaketime 0.9.10
makes CLOCK_MONOTONIC read the shifted *wall* clock (about 1.8e9 s, measured) and Python 3.11's
timed waits (``threading.Event.wait``, ``Lock.acquire(timeout=)``: sem_clockwait on the real
CLOCK_MONOTONIC) then never time out (libfaketime issue #390). With it, libfaketime 0.9.10 (Debian
12) has two faults. ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)``, which Python 3.11's
``time.sleep`` uses, is handed a negative time and fails with EINVAL (libfaketime issue #426, fixed
after 0.9.10). So a small library built for the run (:data:`FIX_SOURCE`, ``cc``) is preloaded
before libfaketime: its ``clock_nanosleep`` sends every clock but CLOCK_REALTIME straight to the
kernel (what a fixed libfaketime does when the monotonic clock is not faked) and CLOCK_REALTIME
on to libfaketime. And ``FAKETIME_FORCE_MONOTONIC_FIX=0``: on glibc >= 2.30 libfaketime 0.9.10
by default moves the deadline of a ``pthread_cond_timedwait`` on a CLOCK_MONOTONIC condition
variable by the difference between its faked and the real monotonic clock, which with the
monotonic clock not faked sends the deadline to about -1.8e9 s; CPython's GIL hand-off waits on
such a condition variable, and a thread that wakes up (the control loop after its select())
then got the GIL back late: measured, a thread sleeping 10 ms beside a busy thread ran 19-43
periods in 3 s instead of 230-270, and a robot process with libfaketime at a zero offset had
control-loop gaps of 4.6-10.8 s where the runs without it had 0.4-0.6 s. With the fix off the
deadline is passed on unchanged (right, as that clock is not faked): 260-272 periods.
``FAKETIME_NO_CACHE=1``: the offset is read from ``FAKETIME`` at every call (0.1 us more per
clock read, measured), never from a cache or an rc file.

libfaketime is the Debian package ``libfaketime`` (scripts/install_clock_deps.sh, which also
installs the C compiler). libfaketime makes a semaphore and shared memory named after the first
process of a host that loads it (``/dev/shm/sem.faketime_sem_<pid>``, ``faketime_shm_<pid>``) and
leaves them when that process is killed: :func:`remove_shm` removes those of the run's processes.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import re
import select
import shutil
import subprocess
import sys
import sysconfig
import time

from ament_formation.core.errors import ConfigError, MAX_MAGNITUDE

INSTALL_SCRIPT = 'scripts/install_clock_deps.sh'
OPTION = '--clock-shift'
LIBRARY = 'libfaketime.so.1'
# where Debian (multiarch), other distributions and `make install` put it
LIBRARY_DIRS = tuple(
    dict.fromkeys(
        d
        for d in (
            f'/usr/lib/{sysconfig.get_config_var("MULTIARCH") or ""}/faketime',
            '/usr/lib/x86_64-linux-gnu/faketime',
            '/usr/lib/aarch64-linux-gnu/faketime',
            '/usr/lib/faketime',
            '/usr/lib64/faketime',
            '/usr/local/lib/faketime',
        )
        if '//' not in d
    )
)
FIX_NAME = 'af_clock_nanosleep.so'
FIX_SOURCE = r"""/* formation multihost --clock-shift (ament_formation/tools/clock_shift.py):
 * preloaded before libfaketime. Only CLOCK_REALTIME is faked (FAKETIME_DONT_FAKE_MONOTONIC=1),
 * but libfaketime 0.9.10 converts an absolute CLOCK_MONOTONIC sleep as if that clock were faked
 * (its issue #426: EINVAL for Python 3.11's time.sleep). Every other clock goes straight to the
 * kernel. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

typedef int (*sleep_fn)(clockid_t, int, const struct timespec *, struct timespec *);

int clock_nanosleep(clockid_t clock_id, int flags, const struct timespec *req,
                    struct timespec *rem)
{
    static sleep_fn next;
    if (clock_id != CLOCK_REALTIME) {
        int saved = errno;
        long r = syscall(SYS_clock_nanosleep, clock_id, flags, req, rem);
        int err = r == 0 ? 0 : errno;
        errno = saved;
        return err;
    }
    if (next == NULL)
        next = (sleep_fn)dlsym(RTLD_NEXT, "clock_nanosleep");
    return next(clock_id, flags, req, rem);
}
"""
# the probe of a host's clock: one time.time() per line read (see measure_shift)
PROBE = (
    'import sys, time\n'
    'for _ in sys.stdin:\n'
    '    sys.stdout.write(repr(time.time()) + "\\n")\n'
    '    sys.stdout.flush()\n'
)
PROBE_EXCHANGES = 15
_LOG_LINE = re.compile(r'^\[(\w+)\] \[(\d+\.\d+)\] \[([^\]]*)\]: (.*)$')


# ------------------------------------------------------------------------------- input
def parse_clock_shift(text: str, ids) -> tuple[int, float]:
    """``ROBOT:SECONDS`` of ``--clock-shift`` -> (robot, seconds, to the microsecond)."""
    try:
        rid, seconds = text.split(':')
        rid, seconds = int(rid), float(seconds)
    except ValueError:
        raise ConfigError(f'expected ROBOT:SECONDS such as 1:+0.9 or 1:-5 (got {text!r})', OPTION)
    if rid not in ids:
        raise ConfigError(f'robot {rid} is not in the scenario (ids {list(ids)})', OPTION)
    if not (math.isfinite(seconds) and abs(seconds) <= MAX_MAGNITUDE):
        raise ConfigError(f'SECONDS must be a finite number of seconds, |SECONDS| <= '
                          f'{MAX_MAGNITUDE:g} (got {text!r})', OPTION)  # fmt: skip
    return rid, round(seconds, 6)


def parse_clock_shifts(texts, ids) -> dict[int, float]:
    """Every ``--clock-shift``: {robot: seconds}; at most one per robot."""
    shifts: dict[int, float] = {}
    for text in texts:
        rid, seconds = parse_clock_shift(text, ids)
        if rid in shifts:
            raise ConfigError(f'robot {rid} has more than one clock shift', OPTION)
        shifts[rid] = seconds
    return shifts


def library() -> Path | None:
    """libfaketime.so.1 of this machine, or None."""
    for d in LIBRARY_DIRS:
        path = Path(d) / LIBRARY
        if path.is_file():
            return path
    return None


def compiler() -> str | None:
    return shutil.which('cc') or shutil.which('gcc')


def missing_reason() -> str | None:
    """Why ``--clock-shift`` cannot run here (one line naming the install script), or None."""
    if library() is None:
        return (f'libfaketime is not installed (no {LIBRARY} in {", ".join(LIBRARY_DIRS[:2])}, '
                f'...): run {INSTALL_SCRIPT}')  # fmt: skip
    if compiler() is None:
        return (f'no C compiler (cc) to build the clock_nanosleep fix preloaded with libfaketime: '
                f'run {INSTALL_SCRIPT}')  # fmt: skip
    return None


# ------------------------------------------------------------------------------- the hosts
def build_fix(folder: Path) -> Path:
    """Compile :data:`FIX_SOURCE` into ``folder``; the library's path. ConfigError on failure."""
    folder.mkdir(parents=True, exist_ok=True)
    source = folder / 'af_clock_nanosleep.c'
    source.write_text(FIX_SOURCE)
    lib = folder / FIX_NAME
    argv = [compiler() or 'cc', '-O2', '-shared', '-fPIC', '-o', str(lib), str(source), '-ldl']
    proc = subprocess.run(argv, capture_output=True, text=True)
    if proc.returncode != 0 or not lib.is_file():
        text = ' '.join((proc.stderr or proc.stdout).split())[:150]
        raise ConfigError(f'building {source.name} failed ({text}); run {INSTALL_SCRIPT}', OPTION)
    return lib


def faketime_spec(seconds: float) -> str:
    """``FAKETIME`` for a wall clock ``seconds`` ahead (negative: behind): ``+0.900000``."""
    return f'{seconds:+.6f}'


def host_env(seconds: float, fix: Path, lib: Path | None = None) -> dict[str, str]:
    """The variables that shift a host's wall clock by ``seconds`` (module docstring)."""
    lib = lib or library()
    preload = ' '.join(p for p in (str(fix), str(lib), os.environ.get('LD_PRELOAD', '')) if p)
    return {
        'LD_PRELOAD': preload,
        'FAKETIME': faketime_spec(seconds),
        'FAKETIME_DONT_FAKE_MONOTONIC': '1',
        'FAKETIME_FORCE_MONOTONIC_FIX': '0',
        'FAKETIME_NO_CACHE': '1',
    }


def env_prefix(variables: dict[str, str]) -> list[str]:
    """``env K=V ...``: a command prefix that sets them for the program and its children only
    (not for ``ip netns exec`` before it).
    """
    return ['env', *(f'{k}={v}' for k, v in variables.items())]


def measure_shift(prefix: list[str], timeout_s: float = 60.0) -> dict:
    """How far a host's wall clock really is ahead of ours: a probe (``prefix`` + this Python)
    answers each line with its ``time.time()``; the exchange with the shortest round trip gives
    ``shift_s`` = its time - the middle of ours (within half that round trip, ``rtt_s``). Also
    ``pid`` of the probe (its libfaketime leftovers: :func:`remove_shm`).
    """
    out: dict = {'shift_s': None, 'rtt_s': None, 'pid': None}
    try:
        proc = subprocess.Popen([*prefix, sys.executable, '-c', PROBE], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                bufsize=1)  # fmt: skip
    except OSError as err:
        out['error'] = str(err)
        return out
    out['pid'] = proc.pid
    best = None
    deadline = time.monotonic() + timeout_s
    try:
        for _ in range(PROBE_EXCHANGES):
            t0 = time.time()
            proc.stdin.write('\n')
            proc.stdin.flush()
            left = max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([proc.stdout], [], [], left)
            if not ready:
                out['error'] = f'no answer within {timeout_s:g} s'
                break
            line = proc.stdout.readline()
            t1 = time.time()
            try:
                theirs = float(line)
            except ValueError:
                out['error'] = f'probe said {line.strip()!r}: {proc.stderr.read()[:200]}'
                break
            if best is None or t1 - t0 < best[0]:
                best = (t1 - t0, theirs - 0.5 * (t0 + t1))
    except (OSError, ValueError) as err:
        out['error'] = str(err)
    finally:
        try:
            proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if best is not None:
        out['rtt_s'], out['shift_s'] = round(best[0], 6), round(best[1], 6)
    return out


def remove_shm(pids, since_wall: float, shm: Path = Path('/dev/shm')) -> list[str]:
    """Remove libfaketime's semaphore and shared memory named after ``pids`` (processes of this run
    that loaded it first on their host) when that process is gone and the file was made after
    ``since_wall`` (``time.time()``; an older file of the same name is another process's). The
    names removed.
    """
    removed = []
    for pid in pids:
        if pid is None or _alive(pid):
            continue
        for name in (f'faketime_shm_{pid}', f'sem.faketime_sem_{pid}'):
            path = shm / name
            try:
                if path.stat().st_mtime >= since_wall - 1.0:
                    path.unlink()
                    removed.append(name)
            except OSError:
                pass
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# ------------------------------------------------------------------------------- the report
def true_offset_s(source: str, rid: int, shifts: dict) -> float | None:
    """How far ``source``'s clock truly runs ahead of robot ``rid``'s [s] (ClockOffsets' sign):
    camera PC sources (camera, coordinator) are on the true clock, ``robot_<k>`` on robot k's.
    """
    mine = shifts.get(rid, 0.0)
    if source in ('camera', 'coordinator'):
        return 0.0 - mine
    m = re.fullmatch(r'robot_(\d+)', source)
    return None if m is None else shifts.get(int(m.group(1)), 0.0) - mine


def controller_status(mcap: Path, ids) -> dict:
    """Per robot, its controller's "robot_<id> control" /diagnostics in the recording: [(log time
    [s, the camera PC's clock], {key: value})].
    """
    from ament_formation.ros.recorder import read_messages

    out: dict = {int(r): [] for r in ids}
    try:
        for _topic, t_ns, msg in read_messages(mcap, ['/diagnostics']):
            for st in msg.status:
                m = re.match(r'.*: robot_(\d+) control$', st.name)
                if m and int(m.group(1)) in out:
                    out[int(m.group(1))].append((t_ns * 1e-9, {kv.key: kv.value
                                                               for kv in st.values}))
    except (OSError, ValueError):
        pass
    return out


def clock_log(log: Path, shift_s: float) -> dict:
    """The controller's clock events in its log, on the true clock (the host's log times are
    ``shift_s`` ahead): ``errors`` [(wall, message)] of "the clock of <source> is ... off ours,
    beyond the bound" (logged when the bound is crossed, also while waiting for the mission
    start, where it stops nothing) and ``stops`` [wall] of its "safety: ... -> stopped_clock".
    """
    out: dict = {'errors': [], 'stops': []}
    try:
        text = log.read_text(errors='replace')
    except OSError:
        return out
    for line in text.splitlines():
        m = _LOG_LINE.match(line.strip())
        if not m or 'formation_controller' not in m.group(3):
            continue
        wall, message = float(m.group(2)) - shift_s, m.group(4)
        if message.startswith('the clock of'):
            out['errors'].append((wall, message))
        elif message.startswith('safety:') and '-> stopped_clock' in message:
            out['stops'].append(wall)
    return out


def robot_clock(rid: int, shifts: dict, statuses: list, start_s: float | None, log: Path) -> dict:
    """What robot ``rid``'s controller made of the clocks: per source it heard the true and the
    estimated offset (its last report during the mission, and the range) and the error; the
    safety states it reported (first scenario time of each); its clock stop (its diagnostics'
    ``safety`` or its log) and why (the last "the clock of ..." line of its log before it).
    """
    t0 = start_s if start_s is not None else -math.inf
    series: dict[str, list[float]] = {}
    safety: dict[str, float] = {}
    for t, values in statuses:
        for key, value in values.items():
            m = re.fullmatch(r'clock_offset_(.+)_s', key)
            if m and t >= t0:
                try:
                    series.setdefault(m.group(1), []).append(float(value))
                except ValueError:
                    pass
        state = values.get('safety')
        if state is not None and state not in safety:
            safety[state] = t
    estimates = {}
    for source, values in sorted(series.items()):
        truth = true_offset_s(source, rid, shifts)
        est = values[-1]
        estimates[source] = {
            'true_offset_s': None if truth is None else round(truth, 6),
            'estimated_offset_s': est,
            'error_s': None if truth is None else round(est - truth, 4),
            'min_s': min(values),
            'max_s': max(values),
            'reports': len(values),
        }
    events = clock_log(log, shifts.get(rid, 0.0))
    stop_walls = [w for w in events['stops'] if w >= t0]
    if safety.get('stopped_clock') is not None and safety['stopped_clock'] >= t0:
        stop_walls.append(safety['stopped_clock'])
    stop = None
    if stop_walls:
        at = min(stop_walls)
        before = [msg for w, msg in events['errors'] if w <= at + 0.05]
        reason = before[-1] if before else (events['errors'][0][1] if events['errors'] else None)
        stop = {'t_s': _rel(at, start_s), 'reason': reason}
    return {
        'shift_s': shifts.get(rid, 0.0),
        'estimates': estimates,
        'safety_first_t_s': {k: _rel(v, start_s) for k, v in safety.items()},
        'clock_stop': stop,
        'clock_errors_logged': [{'t_s': _rel(w, start_s), 'message': msg}
                                for w, msg in events['errors'][:5]],
    }


def _rel(t, t0):
    return None if t is None or t0 is None else round(t - t0, 3)
