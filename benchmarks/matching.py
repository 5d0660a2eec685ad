"""
Scan matching speed: matching plus map update per scan, against the update alone.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/matching.py [--datasets DIR] [--runs 3] [--quick]

The harness of ``incremental.py`` (every scan fed in order in one process, the wall-clock time
of each scan's conversion and update, no grid, no bag), through the mapping session so that
the matching is the product's own code path:

- fr079 (361 beams, 4791 scans) with the drifting wheel odometry of issue 19
  (``recordings.OdometryDrift``, seed 0; ``carmen_messages`` as ``convert --odom-drift 0``
  writes it), mapped with ``pose_source odom`` with and without ``scan_matching``;
- the simulated office drive at 720 beams (full circle, 12 m, 1 cm noise), the same two ways.

Each is run ``--runs`` times (the speed of this virtual machine drifts); the table gives the
run with the median median, and every run's median. Writes the table into benchmarks/README.md
(between the ``matching`` markers) and the raw numbers to benchmarks/results/matching.json.
"""

import argparse
import json
import pathlib
import sys

from common import datasets_argument, stamp, table_header, write_readme, write_results
import numpy as np
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.recordings import (carmen_messages, drive_messages, flat_records,
                                        make_drive, OdometryDrift)
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions


def records_of(name: str, datasets: str, quick: bool) -> list:
    """Return the (already built) records of one input, so building them is not timed."""
    if name == 'freiburg-079 (drifted odometry, seed 0)':
        log = read_carmen(str(pathlib.Path(datasets) / 'radish' /
                              'freiburg-079-corrected.log.gz'))
        stamps, _ = log.stamps(1.0)
        if quick:
            log.records = log.records[:1000]
            stamps = stamps[:1000]
        return flat_records(carmen_messages(log, stamps, (OdometryDrift(), 0)))
    return flat_records(drive_messages(make_drive('office', seed=1, noise=0.01, beams=720)))


def one(records: list, matching: bool) -> dict:
    """Map ``records``; return the per-scan times and the outcome counts."""
    session = replay_records(records, options=SessionOptions(
        pose_source='odom', scan_matching=matching, grid_resolution=None))
    ms = 1e3 * np.asarray(session.update_seconds)
    convert = 1e3 * np.asarray(session.convert_seconds)
    stats = session.stats()
    return {'scans': int(stats['scans_used']), 'p50': float(np.median(ms)),
            'p95': float(np.percentile(ms, 95)), 'p99': float(np.percentile(ms, 99)),
            'convert_p50': float(np.median(convert)), 'update_p50': float(np.median(ms - convert)),
            'segments': len(session.mapper.segments), 'matches': stats.get('scan_matching')}


def main() -> int:
    """Time each input with and without matching; write the table and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--quick', action='store_true', help='first 1000 fr079 scans only')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/matching.py ' + ' '.join(sys.argv[1:]))
    rows = []
    for name in ('freiburg-079 (drifted odometry, seed 0)', 'sim office, 720 beams'):
        records = records_of(name, args.datasets, args.quick)
        for matching in (False, True):
            runs = []
            for k in range(args.runs):
                runs.append(one(records, matching))
                print(f'{name} matching={matching} run {k + 1}: '
                      f'{json.dumps(runs[-1])}', file=sys.stderr, flush=True)
            order = np.argsort([r['p50'] for r in runs])
            rows.append(dict(runs[order[len(order) // 2]], input=name, matching=matching,
                             medians=[r['p50'] for r in runs]))
    write_results('matching', meta, rows)
    lines = table_header(meta, [
        'input', 'scan matching', 'scans', 'per-scan time p50 / p95 / p99 (ms)',
        'of it, p50: conversion (+ matching) / map update (ms)',
        'medians of all runs (ms)', 'segments', 'match outcomes'])
    for r in rows:
        lines.append(f"| {r['input']} | {'on' if r['matching'] else 'off'} | {r['scans']} | "
                     f"{r['p50']:.1f} / {r['p95']:.1f} / {r['p99']:.1f} | "
                     f"{r['convert_p50']:.1f} / {r['update_p50']:.1f} | "
                     f"{' / '.join(f'{m:.1f}' for m in r['medians'])} | {r['segments']} | "
                     f"{r['matches'] or '-'} |")
    write_readme('matching', '\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
