"""Bad scenario files against `formation sim` (issue "Safe on scenarios nobody picked", bounded
inputs): run with `bench/run.sh bench_scenario_fuzz.py [--count 1000] [--seed S] [--workers 2]`.

Seeded mutants of the shipped scenarios (test/scenario_mutants.py: huge, tiny, non-finite and
wrongly typed values, 10^5-character strings, lists multiplied to 1,000 robots or 600 obstacles,
alias bombs, nesting up to 100,000 levels, truncated files, flipped characters; a quarter of them
byte-level damage: control characters, NUL, ESC sequences, a BOM, CRLF, invalid UTF-8, UTF-16,
flipped bits, zeroed blocks) are written to files and each is given to `formation sim` (its own
``main``, with the figure) in a forked process of its own, with a 60 s limit. Counted:

  traceback   the command ended with an exception other than a one-line refusal, or its stderr
              holds a Python traceback
  crash       the process died without a result (a signal, os._exit)
  slow        over 30 s of wall time (killed at 60 s: counted as killed too)
  big         peak RSS over 1 GB
  long line   a refusal of 300 characters or more, or on more than one line
  refused     exit 2 with one line; ran: exit 0 or 1 (a run that fails its checks is a result)

Exit status 1 when any of the first four is not zero. Timing is wall time on a shared machine:
the load average is printed.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
import contextlib
import io
import multiprocessing
import os
from pathlib import Path
import resource
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))

from scenario_mutants import mutants  # noqa: E402

LIMIT_S = 60.0
# byte-level damage in a mutant's label -> its kind in the report
_BYTE_KINDS = (
    ('control characters', 'control characters (NUL, BEL, ESC, DEL, C1, ...)'),
    ('invalid UTF-8', 'invalid UTF-8 sequence'),
    ('Latin-1', 'Latin-1 comment'),
    ('cut inside', 'cut inside a UTF-8 character'),
    ('zero bytes appended', 'zero bytes appended'),
    ('zeroed', 'block of zero bytes'),
    ('flipped bits', 'flipped bits'),
    ('UTF-16 without', 'UTF-16 without BOM'),
    ('UTF-16 with', 'UTF-16 with BOM (valid)'),
    ('UTF-8 BOM', 'UTF-8 BOM (valid)'),
    ('line ends', 'CRLF or CR line ends (valid)'),
    ('BOM inside a key', 'BOM inside a key'),
)


def _child(path: str, out: str, conn) -> None:
    from ament_formation.tools import cli

    err = io.StringIO()
    t0 = time.monotonic()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(['sim', path, '--out', out, '--quiet'])
        kind = None
    except BaseException as exc:  # noqa: BLE001 - what the bench counts
        rc, kind = 99, f'{type(exc).__name__}: {str(exc)[:200]}'
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    conn.send((rc, kind, err.getvalue(), time.monotonic() - t0, rss_mb))
    conn.close()


def _valid(data: bytes) -> bool:
    """Whether the validator accepts the mutant (then a kill at the limit is a slow run)."""
    from ament_formation.core.config_files import decode_user_bytes
    from ament_formation.core.errors import ConfigError
    from ament_formation.core.scenario.loader import parse_scenario_text

    try:
        parse_scenario_text(decode_user_bytes(data, 'mutant', 'scenario'), 'mutant')
    except ConfigError:
        return False
    except Exception:  # noqa: BLE001 - counted as a traceback by its own run
        return False
    return True


def run_one(item) -> dict:
    label, text, workdir = item
    fd, path = tempfile.mkstemp(suffix='.yaml', dir=workdir)
    with os.fdopen(fd, 'wb') as fh:
        fh.write(text)
    out = path[:-5] + '_run'
    ctx = multiprocessing.get_context('fork')
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(path, out, child))
    t0 = time.monotonic()
    proc.start()
    child.close()
    result = None
    if parent.poll(LIMIT_S):
        try:
            result = parent.recv()
        except EOFError:
            result = None
    proc.join(timeout=5.0)
    if proc.is_alive():
        proc.kill()
        proc.join()
    wall = time.monotonic() - t0
    row = {'label': label, 'wall_s': wall}
    if result is None:
        row.update(rc=None, kind='killed' if wall >= LIMIT_S else f'died ({proc.exitcode})')
        row.update(stderr='', rss_mb=float('nan'))
    else:
        rc, kind, stderr, _elapsed, rss_mb = result
        row.update(rc=rc, kind=kind, stderr=stderr, rss_mb=rss_mb)
    with contextlib.suppress(OSError):
        os.unlink(path)
    import shutil

    shutil.rmtree(out, ignore_errors=True)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--count', type=int, default=1000)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--workers', type=int, default=2)
    args = ap.parse_args()
    print(f'load average before: {os.getloadavg()}; {os.cpu_count()} cores')
    from ament_formation.core.sim import simulator  # noqa: F401 - compiled once, before forking

    rows = []
    wall0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix='ament_formation_fuzz_') as workdir:
        items = [(label, text, workdir) for label, text in mutants(args.seed, args.count)]
        with ProcessPoolExecutor(
            args.workers, mp_context=multiprocessing.get_context('fork')
        ) as ex:
            for i, row in enumerate(ex.map(run_one, items), 1):
                rows.append(row)
                if i % 100 == 0:
                    print(f'  {i} / {len(items)} ({time.monotonic() - wall0:.0f} s)', flush=True)
    refused = [r for r in rows if r['rc'] == 2]
    ran = [r for r in rows if r['rc'] in (0, 1)]
    tracebacks = [
        r for r in rows if r['rc'] not in (0, 1, 2, None) or 'Traceback' in (r['stderr'] or '')
    ]
    killed = [r for r in rows if r['rc'] is None and r['kind'] == 'killed']
    texts = {label: text for label, text, _ in items}
    killed_valid = sum(_valid(texts[r['label']]) for r in killed)
    crashes = [r for r in rows if r['rc'] is None and r['kind'] != 'killed']
    slow = [r for r in rows if r['wall_s'] > 30.0]
    big = [r for r in rows if r['rss_mb'] > 1024.0]
    long_lines = [
        r
        for r in refused
        if len(r['stderr'].strip().splitlines()) != 1 or len(r['stderr'].strip()) >= 300
    ]
    print(
        f'{len(rows)} mutants in {time.monotonic() - wall0:.0f} s: {len(refused)} refused in one '
        f'line, {len(ran)} ran ({sum(r["rc"] == 1 for r in ran)} failed their checks)'
    )
    print(
        f'tracebacks {len(tracebacks)}, crashes {len(crashes)}, over 30 s {len(slow)} (killed at '
        f'{LIMIT_S:g} s {len(killed)}: {killed_valid} of them valid files), over 1 GB '
        f'{len(big)}, refusals not one line under 300 chars {len(long_lines)}'
    )
    damaged = [r for r in rows if ': bytes: ' in r['label']]
    kinds: dict[str, list[int]] = {}
    for r in damaged:
        kind = r['label'].split(': bytes: ', 1)[1]
        for prefix, words in _BYTE_KINDS:
            if prefix in kind:
                kind = words
                break
        counts = kinds.setdefault(kind, [0, 0, 0])
        counts[0 if r['rc'] == 2 else 1 if r['rc'] in (0, 1) or r in killed else 2] += 1
    print(
        f'byte-level damage: {len(damaged)} mutants, '
        f'{sum(r["rc"] == 2 for r in damaged)} refused in one line, '
        f'{sum(r["rc"] in (0, 1) or r in killed for r in damaged)} read correctly and ran '
        f'({sum(r in killed for r in damaged)} of them killed at {LIMIT_S:g} s), '
        f'{sum(r in tracebacks or r in crashes for r in damaged)} tracebacks or crashes'
    )
    for kind, (n_refused, n_ran, n_other) in sorted(kinds.items()):
        print(f'  {kind}: {n_refused} refused, {n_ran} ran, {n_other} traceback or crash')
    examples = {}
    for r in damaged:
        if r['rc'] == 2:
            examples.setdefault(r['stderr'].split(': ', 3)[-1][:40], r['stderr'].strip())
    for line in list(examples.values())[:6]:
        print(f'  e.g. {line}')
    walls = sorted(r['wall_s'] for r in rows)
    rss = sorted(r['rss_mb'] for r in rows if r['rss_mb'] == r['rss_mb'])
    print(
        f'wall s: median {walls[len(walls) // 2]:.2f}, max {walls[-1]:.2f}; '
        f'peak RSS MB: median {rss[len(rss) // 2]:.0f}, max {rss[-1]:.0f}; '
        f'longest refusal {max((len(r["stderr"].strip()) for r in refused), default=0)} chars'
    )
    for r in (tracebacks + crashes + slow + big + long_lines)[:20]:
        print(
            f'  {r["label"]}: rc {r["rc"]} {r.get("kind")} {r["wall_s"]:.1f} s '
            f'{r["rss_mb"]:.0f} MB'
        )
    print(f'load average after: {os.getloadavg()}')
    return 1 if tracebacks or crashes or slow or big or long_lines else 0


if __name__ == '__main__':
    sys.exit(main())
