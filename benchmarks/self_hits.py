"""
Readings of the robot itself: when ``self_hits`` warns, and what ``min_mapping_range`` saves.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/self_hits.py [--datasets DIR] [--quick]

A laser that sees its robot's posts reads them at the same range wherever the robot goes, and
the mapper draws each as a wall along the path. ``scan.SelfHits`` (README, "Running the
node") flags a reading that stays within 0.1 m while the laser drives 3 m and its heading
spans 90 deg with 90 deg turned in place. This script measures, with the laser poses the logs
and drives carry:

- detection: four posts of 6 deg at 0.25 m (45, 135, -45, -135 deg; 2 and 3 cm of noise) added
  to the simulated drives that turn in place gradually (``step=0.1,turn=0.1``): the first scan
  flagged, and the scans flagged of all;
- false alarms: the same drives without posts, and every scan of the five Radish logs: scans
  flagged (must be 0);
- the map: the first 200 scans of the office drive with the posts (2 cm), replayed in tf mode
  with the defaults and with ``min_mapping_range`` at the value the warning names, against
  the drive without posts (segments, segments on walls, walls found).

Writes (not with ``--quick``: the office and two logs, printed) the tables into
benchmarks/README.md (between the ``self-hits`` markers) and the raw numbers to
benchmarks/results/self_hits.json.
"""

import argparse
import dataclasses
import importlib
import json
import sys

from common import datasets_argument, publish, radish_logs, stamp
import numpy as np
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.records import Scan
from polyline_mapper.recordings import drive_messages, flat_records, make_drive
from polyline_mapper.replay import replay_records
from polyline_mapper.scan import SelfHits
from polyline_mapper.session import SessionOptions

B = importlib.import_module('baselines')
DRIVES = ('office', 'hall', 'corridors', 'office_dynamic')
LOGS = ('intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected')
POSTS = (45.0, 135.0, -45.0, -135.0)


def posts_mask(angles: np.ndarray) -> np.ndarray:
    """Return which beams (angles, rad) the posts cover."""
    on = np.zeros(len(angles), dtype=bool)
    for post in np.radians(POSTS):
        on |= np.abs(np.angle(np.exp(1j * (angles - post)))) <= np.radians(3.0)
    return on


def flagged(ranges, poses) -> tuple:
    """Feed scans to a SelfHits; return (first scan flagged or None, scans flagged)."""
    hits, first, count = SelfHits(), None, 0
    for k, (r, pose) in enumerate(zip(ranges, poses)):
        if hits.add(r, pose, 0.0).any():
            count += 1
            first = k if first is None else first
    return first, count


def detection(name: str, noise: float) -> dict:
    """Return a drive's first scan flagged with posts, and its scans flagged without them."""
    drive = make_drive(f'sim:{name},step=0.1,turn=0.1', 1)
    spec = drive.spec
    on = posts_mask(spec.angle_min + spec.angle_increment * np.arange(drive.ranges.shape[1]))
    rng = np.random.default_rng(0)
    posted = np.array(drive.ranges, dtype=np.float64)
    posted[:, on] = 0.25 + rng.normal(0.0, noise, (len(posted), on.sum()))
    first, count = flagged(posted, drive.poses)
    _, clean = flagged(np.asarray(drive.ranges, dtype=np.float64), drive.poses)
    return {'input': f'sim:{name},step=0.1,turn=0.1', 'noise_m': noise,
            'scans': int(len(drive.poses)), 'first_flagged': first, 'flagged': count,
            'flagged_without_posts': clean}


def the_map(scans: int = 200) -> list:
    """Map the office's first ``scans`` scans without posts, with them, and with the setting."""
    drive = make_drive('sim:office,step=0.1,turn=0.1', 1)
    out, n = [], 0
    for rec in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0))):
        n += isinstance(rec, Scan)
        if n > scans:
            break
        out.append(rec)
    rng = np.random.default_rng(0)

    def posted(rec):
        if not isinstance(rec, Scan):
            return rec
        ranges = np.array(rec.ranges, dtype=np.float32)
        on = posts_mask(rec.angle_min + rec.angle_increment * np.arange(len(ranges)))
        ranges[on] = 0.25 + rng.normal(0.0, 0.02, on.sum())
        return dataclasses.replace(rec, ranges=ranges)
    with_posts = [posted(rec) for rec in out]
    rows = []
    for label, recs, low in (('without posts', out, 0.0), ('posts', with_posts, 0.0),
                             ('posts, min_mapping_range', with_posts, None)):
        warned = []
        if low is None:                 # the value the warning of the run before named
            low = float(rows[-1]['advice'])
        session = replay_records(recs, config=IncrementalConfig(min_mapping_range=low),
                                 options=SessionOptions(keep_points=True),
                                 warn=lambda cause, text: warned.append((cause, text)))
        segments = session.map_value().segments
        walls = B.wall_scores(segments, drive.world.walls, drive.world.distance)
        texts = [t for c, t in warned if c == 'self_hits']
        advice = (texts[0].split('min_mapping_range to ')[1].split(' m')[0] if texts else '')
        rows.append({'map': label, 'min_mapping_range': low, 'segments': int(len(segments)),
                     'on_walls': int(round(walls['precision'] * len(segments))),
                     'walls_found': int(walls['found']), 'self_hits_warnings': len(texts),
                     'advice': advice})
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    return rows


def main() -> int:
    """Run the cases; write the tables and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    datasets_argument(ap)
    ap.add_argument('--quick', action='store_true',
                    help='the office and two logs, printed (nothing written)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/self_hits.py ' + ' '.join(sys.argv[1:]))
    drives = DRIVES[:1] if args.quick else DRIVES
    found = []
    for name in drives:
        for noise in (0.02, 0.03):
            found.append(detection(name, noise))
            print(json.dumps(found[-1]), file=sys.stderr, flush=True)
    logs = []
    for name, path in radish_logs(args.datasets, LOGS[:2] if args.quick else LOGS):
        log = read_carmen(str(path))
        _, count = flagged([rec.ranges for rec in log.records], [rec.pose for rec in log.records])
        logs.append({'input': name, 'scans': len(log.records), 'flagged': count})
        print(json.dumps(logs[-1]), file=sys.stderr, flush=True)
    maps = the_map()
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (laser poses as the drives and logs carry them).", '',
             '| input | posts (noise) | scans | first flagged | scans flagged | '
             'flagged without posts |', '|---|---|---:|---:|---:|---:|']
    for r in found:
        lines.append(f"| {r['input']} | 0.25 m ({100 * r['noise_m']:g} cm) | {r['scans']} | "
                     f"{r['first_flagged']} | {r['flagged']} | {r['flagged_without_posts']} |")
    for r in logs:
        lines.append(f"| {r['input']} | none | {r['scans']} | - | {r['flagged']} | - |")
    lines += ['', 'The first 200 scans of `sim:office,step=0.1,turn=0.1` (tf mode, true poses), '
              'posts with 2 cm of noise:', '',
              '| map | min_mapping_range (m) | segments | on walls | walls found | self_hits '
              'warnings |', '|---|---:|---:|---:|---:|---:|']
    for r in maps:
        lines.append(f"| {r['map']} | {r['min_mapping_range']:g} | {r['segments']} | "
                     f"{r['on_walls']} | {r['walls_found']} | {r['self_hits_warnings']} |")
    publish('self-hits', 'self_hits', meta, {'detection': found, 'logs': logs, 'maps': maps},
            lines, args.quick)
    alarms = sum(r['flagged_without_posts'] for r in found) + sum(r['flagged'] for r in logs)
    return 0 if alarms == 0 and all(r['first_flagged'] is not None for r in found) else 1


if __name__ == '__main__':
    sys.exit(main())
