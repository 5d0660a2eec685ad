"""
Offline replay of every shared Radish log: the map ``polyline-mapper replay`` makes.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/replay.py [--datasets DIR] [--only NAME ...] [--via-bag]

Each log goes through ``polyline_mapper.replay.run_replay`` scan by scan, exactly as the
``replay`` command runs it (default IncrementalConfig, every scan, poses from the log through
TF). Reported per log: mean and 95th-percentile distance of that log's points to the final map,
coverage (share of points within 0.10 m), segments, polylines, and the time of each map update
(point conversion included; median and p99), and the share of map length contradicted by the
log's beams (``polyline_mapper.core.freespace``: >= 5 beams pass through a segment, more than
end on it; every mapped scan's beams, each from its laser pose). Targets (issue 5): mean
<= 0.06 m and coverage >= 90 % per log. With --via-bag every log is also converted to a rosbag2
(sqlite3) and replayed from the bag, and the two maps are compared (largest end-point
difference).

Writes the table into benchmarks/README.md (between the ``replay`` markers), the raw numbers to
benchmarks/results/replay.json and two PNGs per log to benchmarks/results/: replay-<log>.png
(map over points) and replay-free-space-<log>.png (beams, contradicted segments in red).
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

from common import datasets_argument, HERE, radish_logs, stamp, write_readme
import numpy as np
from polyline_mapper.core.freespace import judge
from polyline_mapper.formats.carmen_bag import carmen_to_bag
from polyline_mapper.plot import plot_free_space, plot_map
from polyline_mapper.replay import run_replay

LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected']
TARGET_MEAN = 0.06
TARGET_COVERAGE = 0.90


def replay_one(name: str, path: pathlib.Path, out_dir: pathlib.Path, via_bag: bool) -> dict:
    """Replay one log; return its row and write its PNG."""
    t0 = time.perf_counter()
    res = run_replay(str(path), progress=True)
    wall = time.perf_counter() - t0
    stats = res.stats()
    segments, polylines = res.map_value.segments, res.map_value.polylines
    row = {'dataset': name, 'scans': res.scans, 'scans_used': res.used,
           'skipped': dict(res.skipped), 'points': stats['points'],
           'segments': stats['segments'], 'polylines': stats['polylines'],
           'mean_cm': 100 * stats['mean_distance'], 'p95_cm': 100 * stats['p95_distance'],
           'coverage': 100 * stats['coverage_0_10m'],
           'median_ms': stats['update_ms_median'], 'p99_ms': stats['update_ms_p99'],
           'sigma_cm': 100 * stats['sigma'], 'seconds': wall,
           'contradicted_pct': 100 * stats['contradicted_share'],
           'contradicted_segments': stats['contradicted_segments'], 'beams': stats['beams']}
    row['meets'] = bool(stats['mean_distance'] <= TARGET_MEAN
                        and stats['coverage_0_10m'] >= TARGET_COVERAGE)
    plot_map(str(out_dir / f'replay-{name}.png'), res.points, segments, polylines,
             title=f"{name} replay: {row['segments']} segments, mean {row['mean_cm']:.2f} cm, "
                   f"coverage {row['coverage']:.1f}%")
    verdict = judge(segments, res.points, res.session.origins())
    plot_free_space(str(out_dir / f'replay-free-space-{name}.png'), res.points,
                    res.session.origins(), segments, verdict.contradicted,
                    title=f"{name} replay: {row['segments']} segments, "
                          f"{row['contradicted_pct']:.1f}% of map length contradicted "
                          f"({row['contradicted_segments']} segments)")
    if via_bag:
        with tempfile.TemporaryDirectory() as tmp:
            bag = os.path.join(tmp, name)
            carmen_to_bag(str(path), bag, 'sqlite3')
            other = run_replay(bag, progress=True)
        theirs = other.map_value.segments
        row['bag_max_diff_m'] = (float(np.abs(theirs - segments).max())
                                 if theirs.shape == segments.shape else float('inf'))
    print(f"{name}: {row['scans_used']}/{row['scans']} scans, {row['segments']} segments, "
          f"mean {row['mean_cm']:.2f} cm, p95 {row['p95_cm']:.2f} cm, coverage "
          f"{row['coverage']:.1f}%, contradicted {row['contradicted_pct']:.1f}% "
          f"({row['contradicted_segments']}), update median {row['median_ms']:.1f} ms p99 "
          f"{row['p99_ms']:.1f} ms, {wall:.0f} s"
          + (f", bag vs log {row['bag_max_diff_m']:.1e} m" if via_bag else ''), flush=True)
    return row


def table(rows: list, meta: dict, via_bag: bool) -> str:
    """Build the README block: when, where, how, and one row per log."""
    block = (f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}, with "
             f"`{meta['command']}` (default IncrementalConfig: 3-scan buffer, one SMEMSF "
             'iteration per scan; every scan, in log order; one process, no other load '
             'intended). Mean, p95 and coverage are over all points of the log; update times '
             'are per scan, point conversion included. Target: mean <= 6 cm and coverage >= '
             '90 % per log. "contradicted": share of map length (and segments) that >= 5 '
             "beams pass through, more than end on it (every mapped scan's beams).\n\n"
             '| log | scans | points | segments | polylines | mean (cm) | p95 (cm) | '
             'coverage 0.10 m | contradicted (segments) | update median / p99 (ms) | '
             'time (s) | target |'
             + (' bag = log |' if via_bag else '') + '\n'
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|'
             + ('---:|' if via_bag else '') + '\n')
    for r in rows:
        block += (f"| {r['dataset']} | {r['scans_used']} | {r['points']} | {r['segments']} | "
                  f"{r['polylines']} | {r['mean_cm']:.2f} | {r['p95_cm']:.2f} | "
                  f"{r['coverage']:.1f}% | {r['contradicted_pct']:.1f}% "
                  f"({r['contradicted_segments']}) | {r['median_ms']:.1f} / {r['p99_ms']:.1f} | "
                  f"{r['seconds']:.0f} | {'met' if r['meets'] else '**not met**'} |"
                  + (f" {r['bag_max_diff_m']:.0e} m |" if via_bag else '') + '\n')
    block += ('\nPlots: `results/replay-<log>.png`, `results/replay-free-space-<log>.png` '
              '(beams, contradicted segments in red). '
              + ('"bag = log": largest end-point difference between the map replayed from the '
                 'log and from its rosbag2 conversion (`polyline-mapper convert`).\n'
                 if via_bag else '\n'))
    return block


def main(argv=None) -> int:
    """Run the benchmark; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='*', default=[], help='log names to run')
    ap.add_argument('--via-bag', action='store_true',
                    help='also convert each log to a rosbag2 and compare the replayed maps')
    ap.add_argument('--no-readme', action='store_true', help='do not rewrite README.md')
    args = ap.parse_args(argv)
    out_dir = HERE / 'results'
    out_dir.mkdir(exist_ok=True)
    rows = []
    for name, path in radish_logs(args.datasets, LOGS, args.only):
        rows.append(replay_one(name, path, out_dir, args.via_bag))
    if not rows:
        print('no dataset found', file=sys.stderr)
        return 1
    command = ('python benchmarks/replay.py '
               + ' '.join(argv if argv is not None else sys.argv[1:])).strip()
    meta = stamp(command)
    (out_dir / 'replay.json').write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1))
    block = table(rows, meta, args.via_bag)
    if not args.no_readme:
        write_readme('replay', block)
    print(block)
    return 0


if __name__ == '__main__':
    sys.exit(main())
