"""
Live play against offline replay: each shared Radish log, as a bag, played into the live node.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/live_play.py [--datasets DIR] [--only NAME ...] [--scan-hz HZ]
        [--domain-id ID]

Per log: ``polyline-mapper convert`` to a rosbag2, then the real ``polyline_mapper_node``
(``use_sim_time:=true``, defaults otherwise) in its own process, ``polyline-mapper play BAG
--rate R`` (R chosen so scans arrive at ``--scan-hz``, default 25 Hz), ``polyline-mapper
record-map --idle 3``, all over DDS on a private domain; and ``replay`` of the same bag offline.
Both maps are scored on the offline replay's points (mean distance, coverage within 0.10 m) and
against its beams (``freespace.judge``: share of map length that >= 5 beams pass through, more
than end on it; every scan's beams, from the log's corrected laser pose).
Target (issue 5): live mean distance within 1.25x the offline one. The node's own summary gives
scans received / used / dropped and its update-time percentiles.

Writes a table into benchmarks/README.md (``live_play`` markers) and the raw numbers to
benchmarks/results/live_play.json.
"""

import argparse
import json
import os
import pathlib
import random
import re
import signal
import subprocess
import sys
import tempfile
import time

from common import (contradicted, CONTRADICTED_NOTE, datasets_argument, HERE, load_note,
                    notable_lines, stamp, write_readme)
from polyline_mapper.core import map_metrics
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.carmen_bag import carmen_to_bag
from polyline_mapper.formats.mapjson import read_map
from polyline_mapper.replay import run_replay

LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected']
CLI = [sys.executable, '-m', 'polyline_mapper.cli']


def play_one(name: str, path: pathlib.Path, scan_hz: float, env: dict, tmp: str) -> dict:
    log = read_carmen(str(path))
    stamps, _ = log.stamps(1.0)
    rate = scan_hz / (len(stamps) / max(stamps[-1] - stamps[0], 1e-9))
    bag = os.path.join(tmp, name)
    carmen_to_bag(str(path), bag)
    err_path = os.path.join(tmp, f'{name}.node.log')
    with open(err_path, 'w') as err:
        node = subprocess.Popen([sys.executable, '-m', 'polyline_mapper.ros.node', '--ros-args',
                                 '-p', 'use_sim_time:=true', '-p', 'stats_period:=0.0'],
                                env=env, stdout=subprocess.DEVNULL, stderr=err)
        try:
            t0 = time.monotonic()
            play = subprocess.run(CLI + ['play', bag, '--rate', f'{rate:.4f}', '-q',
                                         '--wait-for-subscriber', '30'],
                                  env=env, capture_output=True, text=True)
            play_s = time.monotonic() - t0
            if play.returncode != 0:
                raise RuntimeError(f'play failed: {play.stderr.strip()}')
            out = os.path.join(tmp, f'{name}.live.json')
            rec = subprocess.run(CLI + ['record-map', '-o', out, '--idle', '3', '-q'],
                                 env=env, capture_output=True, text=True)
            if rec.returncode != 0:
                raise RuntimeError(f'record-map failed: {rec.stderr.strip()}')
        finally:
            node.send_signal(signal.SIGINT)
            node.wait(30)
    summary = [ln for ln in open(err_path).read().splitlines() if 'summary:' in ln]
    counts = re.search(r'(\d+) scans received, (\d+) used in (\d+) updates, (\d+) dropped',
                       summary[-1] if summary else '')
    upd = re.search(r'update_ms p50 ([\d.]+) p95 ([\d.]+) p99 ([\d.]+)',
                    summary[-1] if summary else '')
    live = read_map(out)
    offline = run_replay(bag)
    segs_off = offline.map_value.segments
    m_off = map_metrics(offline.points, segs_off)
    m_live = map_metrics(offline.points, live['segments_array'])
    origins = offline.session.origins()
    c_off = contradicted(segs_off, offline.points, origins)
    c_live = contradicted(live['segments_array'], offline.points, origins)
    row = {'log': name, 'scans': int(len(stamps)), 'rate': round(rate, 2),
           'play_seconds': round(play_s, 1),
           'received': int(counts.group(1)) if counts else None,
           'used': int(counts.group(2)) if counts else None,
           'dropped': int(counts.group(4)) if counts else None,
           'update_ms_p50': float(upd.group(1)) if upd else None,
           'update_ms_p99': float(upd.group(3)) if upd else None,
           'live_segments': len(live['segments']), 'offline_segments': int(len(segs_off)),
           'live_mean': m_live['mean_distance'], 'offline_mean': m_off['mean_distance'],
           'live_coverage': m_live['coverage_0_10m'],
           'offline_coverage': m_off['coverage_0_10m'],
           'live_contradicted_pct': c_live['contradicted_pct'],
           'live_contradicted_segments': c_live['contradicted_segments'],
           'offline_contradicted_pct': c_off['contradicted_pct'],
           'offline_contradicted_segments': c_off['contradicted_segments']}
    row['ratio'] = row['live_mean'] / row['offline_mean']
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='+', choices=LOGS)
    ap.add_argument('--scan-hz', type=float, default=25.0,
                    help="scans per second the node gets (sets each log's play rate)")
    ap.add_argument('--domain-id', type=int, choices=range(0, 102), metavar='0..101',
                    help='ROS_DOMAIN_ID of the run (default: a random one, 1..101)')
    args = ap.parse_args()
    domain = (args.domain_id if args.domain_id is not None
              else random.SystemRandom().randrange(1, 102))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               RCUTILS_COLORIZED_OUTPUT='0')
    meta = stamp('.venv/bin/python benchmarks/live_play.py ' + ' '.join(sys.argv[1:]))
    load0 = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only or LOGS:
            path = pathlib.Path(args.datasets) / 'radish' / f'{name}.log.gz'
            if not path.is_file():
                print(f'skip {name}: {path} not present', file=sys.stderr)
                continue
            row = play_one(name, path, args.scan_hz, env, tmp)
            rows.append(row)
            print(json.dumps(row), flush=True)
    meta['load'] = load_note(load0)
    (HERE / 'results').mkdir(exist_ok=True)
    (HERE / 'results' / 'live_play.json').write_text(json.dumps({**meta, 'rows': rows},
                                                                indent=1))
    lines = [f"Measured {meta['date']} on {meta['machine']}; commit {meta['commit']}; "
             f"`{meta['command']}`; {meta['load']}. {CONTRADICTED_NOTE}; both maps against "
             "the offline replay's beams (every scan's, from the log's corrected laser pose).\n\n",
             '| log | scans | play rate | node: received / used / dropped | update p50 / p99 '
             '(ms) | segments live / offline | mean live / offline (cm) | ratio (<= 1.25) | '
             'coverage live / offline | contradicted live / offline (segments) |\n',
             '|---|---|---|---|---|---|---|---|---|---|\n']
    for r in rows:
        lines.append(
            f"| {r['log']} | {r['scans']} | {r['rate']:g}x | {r['received']} / {r['used']} / "
            f"{r['dropped']} | {r['update_ms_p50']} / {r['update_ms_p99']} | "
            f"{r['live_segments']} / {r['offline_segments']} | {100 * r['live_mean']:.2f} / "
            f"{100 * r['offline_mean']:.2f} | {r['ratio']:.3f} "
            f"{'✓' if r['ratio'] <= 1.25 else '✗'} | {100 * r['live_coverage']:.1f} / "
            f"{100 * r['offline_coverage']:.1f} % | {r['live_contradicted_pct']:.1f}% "
            f"({r['live_contradicted_segments']}) / {r['offline_contradicted_pct']:.1f}% "
            f"({r['offline_contradicted_segments']}) |\n")
    notes = notable_lines([(f"{r['log']} {kind}", r[f'{kind}_contradicted_pct'],
                            r[f'{kind}_contradicted_segments'])
                           for r in rows for kind in ('live', 'offline')])
    if notes:
        lines.append('\nMaps contradicted on more than 2 % of their length:\n\n'
                     + '\n'.join(notes) + '\n')
    write_readme('live_play', ''.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
