"""
The beams' memory (``incremental.free_space_memory``): incremental replay of the shared logs.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/free_space_memory.py [--datasets DIR] [--only NAME ...]
        [--jobs 2] [--no-readme]

Every log is replayed with ``polyline-mapper replay`` (the command a user runs, so the session
code of the node) three times:

- ``default``: ``--config config/no_free_space.yaml`` (the free-space evidence off: the default
  map before 2026-11-27, the one issue 18's bars are measured against; the row keeps its name);
- ``evidence``: ``--set free_space_memory=0`` (window 10, 20000 ghosts, hit margin 0.03: the
  preset before the memory);
- ``memory``: no option (the default since 2026-11-27: the same plus a memory of 0.1 m cells).

Reported per map (from its stats): the contradicted share of map length (``core/freespace.py``,
every scan's beams), mean distance and coverage within 0.10 m of all the log's points, segments,
the update median, and against the default map the bars of issue 18 (contradicted <= 2 %, mean
at most 15 % above, coverage at most 2 points below). Writes the table between the
``free-space-memory`` markers of benchmarks/README.md, the rows to
results/free_space_memory.json and, per log, results/replay-memory-free-space-<log>.png (the
memory map over its beams, contradicted segments in red; ``plot --free-space``).
"""

import argparse
from concurrent.futures import ThreadPoolExecutor
import json
import os
import pathlib
import subprocess
import sys
import tempfile

from common import (datasets_argument, HERE, load_note, radish_logs, REPO, stamp, table_header,
                    write_readme, write_results)

LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected']
OFF = str(REPO / 'config' / 'no_free_space.yaml')
SETTINGS = {'default': ['--config', OFF],
            'evidence': ['--set', 'free_space_memory=0'],
            'memory': []}
CLI = str(pathlib.Path(sys.executable).parent / 'polyline-mapper')


def replay(path: pathlib.Path, setting: str, out: pathlib.Path) -> dict:
    """Replay one log with one setting; return the map's stats."""
    subprocess.run([CLI, 'replay', str(path), '-o', str(out), '-q', *SETTINGS[setting]],
                   check=True)
    return json.loads(out.read_text())['stats']


def main(argv=None) -> int:
    """Run the replays, write the table, the JSON and the PNGs."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='*', help='log names (default: all five)')
    ap.add_argument('--jobs', type=int, default=2, help='replays run at once')
    ap.add_argument('--no-readme', action='store_true', help='do not rewrite README.md')
    args = ap.parse_args(argv)
    start = os.getloadavg()
    meta = stamp('python benchmarks/free_space_memory.py ' + ' '.join(argv or sys.argv[1:]))
    logs = list(radish_logs(args.datasets, LOGS, args.only))
    tmp = pathlib.Path(tempfile.mkdtemp(prefix='free_space_memory-'))
    jobs = [(name, path, s) for name, path in logs for s in SETTINGS]
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        stats = list(pool.map(lambda j: replay(j[1], j[2], tmp / f'{j[0]}-{j[2]}.json'), jobs))
    by = {(name, s): st for (name, _, s), st in zip(jobs, stats)}
    rows = []
    for name, path in logs:
        base = by[(name, 'default')]
        for s in SETTINGS:
            st = by[(name, s)]
            row = {'dataset': name, 'setting': s, 'segments': st['segments'],
                   'contradicted_pct': 100 * st['contradicted_share'],
                   'contradicted_segments': st['contradicted_segments'],
                   'mean_cm': 100 * st['mean_distance'],
                   'coverage': 100 * st['coverage_0_10m'],
                   'update_ms_median': st['update_ms_median']}
            row['mean_vs_default'] = st['mean_distance'] / base['mean_distance']
            row['coverage_vs_default'] = 100 * (st['coverage_0_10m'] - base['coverage_0_10m'])
            row['bars'] = (row['contradicted_pct'] <= 2.0 and row['mean_vs_default'] <= 1.15
                           and row['coverage_vs_default'] >= -2.0)
            rows.append(row)
        png = HERE / 'results' / f'replay-memory-free-space-{name}.png'
        subprocess.run([CLI, 'plot', str(tmp / f'{name}-memory.json'), '--points', str(path),
                        '--free-space', '-o', str(png)], check=True)
    meta['load'] = load_note(start)
    write_results('free_space_memory', meta, rows)
    lines = table_header(meta, ['log', 'setting', 'contradicted % (segments)',
                                'mean cm (x default)', 'coverage % (points vs default)',
                                'segments', 'update median ms', 'issue 18 bars'])
    for r in rows:
        lines.append(f"| {r['dataset']} | {r['setting']} | {r['contradicted_pct']:.2f} "
                     f"({r['contradicted_segments']}) | {r['mean_cm']:.2f} "
                     f"({r['mean_vs_default']:.2f}x) | {r['coverage']:.2f} "
                     f"({r['coverage_vs_default']:+.2f}) | {r['segments']} | "
                     f"{r['update_ms_median']:.1f} | {'met' if r['bars'] else 'not met'} |")
    lines += ['', meta['load'], '']
    block = '\n'.join(lines) + '\n'
    print(block)
    if not args.no_readme:
        write_readme('free-space-memory', block)
    return 0


if __name__ == '__main__':
    sys.exit(main())
