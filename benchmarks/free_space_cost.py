"""
Free-space evidence (issue 18): its cost on fr079 in the incremental.py harness.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/free_space_cost.py [--datasets DIR] [--window 10] [--repeat 3] \
        [--ghosts N] [--hit-margin M] [--memory CELL]

The fr079 log (361 beams, 4791 scans, corrected poses) is fed to ``IncrementalMapper`` scan by
scan exactly as ``incremental.py`` does (``run_mapper``, ``log_scans``), with
``free_space_window`` 0 (the evidence off: clearing of short segments, the default before
2026-11-27) and ``--window`` (the evidence per LSS square; with ``--ghosts``, ``--hit-margin``
and ``--memory``: ``free_space_ghosts``, ``free_space_hit_margin`` and ``free_space_memory``,
default 0; the mapper's default since 2026-11-27 is ``--ghosts 20000 --hit-margin 0.03
--memory 0.1``), alternately ``--repeat`` times in one process so a drift
of this machine's speed hits both alike. Reported per setting: the update median of each run, the
final map's segments, mean distance and coverage of all the log's points (``map_metrics``),
its contradicted share of length (``freespace.judge``, every scan's beams), and, each
in a fresh process, the resident set size after the first 500 scans and after all of them
with the mapper's own ``nbytes()`` (the evidence lives beside the segments: bounded by the
map, not by the scans).

Writes the table into benchmarks/README.md (between the ``free-space-cost`` markers) and the
raw numbers to benchmarks/results/free_space_cost.json.
"""

import argparse
import dataclasses
import json
import pathlib
import subprocess
import sys

from common import datasets_argument, HERE, stamp, write_readme
from incremental import log_scans, rss_bytes, run_mapper
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.core.freespace import judge
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.formats.carmen import read_carmen

LOG = 'freiburg-079-corrected'


def mapper_for(setting: tuple) -> IncrementalMapper:
    """
    Return a default mapper with the evidence set as ``setting`` says.

    ``setting``: (``free_space_window``, ``_ghosts``, ``_hit_margin``, ``_memory``); memory 0
    (no beams' memory) measures the evidence per square alone.
    """
    window, ghosts, margin, cell = setting
    return IncrementalMapper(dataclasses.replace(
        IncrementalConfig(), free_space_window=window, free_space_ghosts=ghosts,
        free_space_hit_margin=margin, free_space_memory=cell))


def memory_child(path: str, setting: tuple) -> None:
    """Map the log in this (fresh) process; print RSS and map bytes after 500 and all scans."""
    scans = log_scans(pathlib.Path(path))[0]
    marks = {}

    def on_scan(i, mapper):
        if i == 499 or i == len(scans) - 1:
            marks[i] = (rss_bytes(), mapper.nbytes(), len(mapper.segments))
    run_mapper(scans, mapper_for(setting), on_scan=on_scan)
    (r500, b500, k500), (rend, bend, kend) = marks[499], marks[len(scans) - 1]
    print(json.dumps({'rss_500_mb': r500 / 2 ** 20, 'rss_end_mb': rend / 2 ** 20,
                      'map_500_kb': b500 / 1024, 'map_end_kb': bend / 1024,
                      'segments_500': k500, 'segments_end': kend}))


def memory(path: pathlib.Path, setting: tuple) -> dict:
    """Run ``memory_child`` in a fresh interpreter (so one setting's heap is not the other's)."""
    out = subprocess.run([sys.executable, __file__, '--memory-child', str(path),
                          *(repr(v) for v in setting)],
                         check=True, capture_output=True, text=True, cwd=str(HERE))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    """Time and score both settings; write the table and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--window', type=int, default=10, help='free_space_window when on')
    ap.add_argument('--ghosts', type=int, default=0, help='free_space_ghosts when on')
    ap.add_argument('--hit-margin', type=float, default=0.0,
                    help='free_space_hit_margin when on')
    ap.add_argument('--memory', type=float, default=0.0,
                    help='free_space_memory (cell, m) when on; 0: none')
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('--memory-child', nargs=5,
                    metavar=('LOG', 'WINDOW', 'GHOSTS', 'MARGIN', 'CELL'), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.memory_child:
        log, window, ghosts, margin, cell = args.memory_child
        memory_child(log, (int(window), int(ghosts), float(margin), float(cell)))
        return 0
    path = pathlib.Path(args.datasets) / 'radish' / f'{LOG}.log.gz'
    if not path.is_file():
        print(f'free_space_cost.py: error: {path} not found', file=sys.stderr)
        return 2
    meta = stamp('.venv/bin/python benchmarks/free_space_cost.py ' + ' '.join(sys.argv[1:]))
    scans, points, _ = log_scans(path)
    beam_points, origins = read_carmen(str(path)).beams()
    windows = ((0, 0, 0.0, 0.0), (args.window, args.ghosts, args.hit_margin, args.memory))
    medians = {w: [] for w in windows}
    maps = {}
    for k in range(max(1, args.repeat)):
        for w in windows:
            mapper, times = run_mapper(scans, mapper_for(w))
            medians[w].append(float(np.median(times)))
            maps[w] = mapper.polylines().segments
            print(f'run {k + 1}: window, ghosts, hit margin, memory {w}: update median '
                  f'{medians[w][-1]:.2f} ms', file=sys.stderr, flush=True)
    rows = []
    for w in windows:
        m = map_metrics(points, maps[w])
        share = judge(maps[w], beam_points, origins).share
        row = {'window': w[0], 'ghosts': w[1], 'hit_margin': w[2], 'memory': w[3],
               'run_medians_ms': medians[w],
               'median_ms': float(np.median(medians[w])), 'segments': int(len(maps[w])),
               'mean_cm': 100 * m['mean_distance'], 'coverage': 100 * m['coverage_0_10m'],
               'contradicted_share': share, **memory(path, w)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    out = HERE / 'results'
    out.mkdir(exist_ok=True)
    (out / 'free_space_cost.json').write_text(json.dumps({'meta': meta, 'rows': rows},
                                                         indent=1) + '\n')
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}`.", '',
             '| free_space_window / _ghosts / _hit_margin / _memory | update median (ms), runs '
             '| segments '
             '| mean (cm) | coverage (%) | contradicted (% of length) | RSS after 500 / all '
             'scans (MiB) | map after 500 / all (kB) |', '|---|---|---|---|---|---|---|---|']
    for r in rows:
        share = f"{100 * r['contradicted_share']:.1f}"
        lines.append(
            f"| {r['window'] or '0 (off)'} / {r['ghosts']} / {r['hit_margin']:g} / "
            f"{r['memory']:g} "
            f"| {r['median_ms']:.2f} "
            f"({', '.join(f'{v:.2f}' for v in r['run_medians_ms'])}) | {r['segments']} | "
            f"{r['mean_cm']:.2f} | {r['coverage']:.1f} | {share} | "
            f"{r['rss_500_mb']:.0f} / {r['rss_end_mb']:.0f} | "
            f"{r['map_500_kb']:.0f} / {r['map_end_kb']:.0f} |")
    write_readme('free-space-cost', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
