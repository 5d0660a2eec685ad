"""
Laser stamps off the odometry's clock: the lag estimate, its warning, and ``scan_time_offset``.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/scan_clock.py [--quick]

A laser driver that stamps a scan when it sends it rather than at its first beam (as
sensor_msgs/LaserScan asks), or that runs on another machine's clock, stamps every scan some
time off the odometry's. Each simulated drive (``make_drive(spec, 1)``: 0.5 m/s, turning in
place at 1 rad/s, beams taken over the scan time) is recorded as a robot without a localizer
(/odom with the drift of ``recordings.OdometryDrift``, seed 1; laser at the base, no map frame)
whose scans are stamped ``lag`` seconds late (negative: early), and mapped with ``pose_source
odom`` and ``scan_matching`` through the session (``replay_records``) twice: as recorded, and
with ``scan_time_offset`` set to the value the first ``scan_clock`` warning of that run gives
(what a user who reads it does). Scores: the base poses of the scans used against the true ones
at the time each scan was taken (RMS and largest error, m), the walls (F1 and precision of
``baselines.walls.wall_scores``), the lag the warning estimated, and the scans used.

Writes (not with ``--quick``) the table into benchmarks/README.md (between the ``scan-clock``
markers) and the raw numbers to benchmarks/results/scan_clock.json.
"""

from dataclasses import replace
import json
import math
import re
import sys

from baselines.walls import wall_scores
from common import case_run, drifting_drive, publish
import numpy as np
from polyline_mapper.formats.records import Scan
from polyline_mapper.recordings import drive_messages, flat_records, SIM_START
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions

OFFICE = 'sim:office,step=0.05,turn=0.1,moving_sensor=1'
CORRIDORS = 'sim:corridors,step=0.05,turn=0.1,moving_sensor=1'
CASES = ([(OFFICE, lag) for lag in (0.0, 0.05, 0.1, 0.3, -0.05, -0.1, -0.3)]
         + [(CORRIDORS, lag) for lag in (0.0, 0.1)])
"""(drive, seconds the scans are stamped late)."""


def records(drive, odometry: np.ndarray, lag: float) -> list:
    """Return the drive's records with ``odometry``, the scans stamped ``lag`` s late."""
    out = flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odometry=odometry))
    return [replace(r, stamp=r.stamp + lag) if isinstance(r, Scan) else r for r in out]


def one(drive, recs: list, lag: float, offset: float = 0.0, pose_source: str = 'odom') -> dict:
    """Map ``recs`` with ``scan_time_offset`` ``offset``; return the scores."""
    warned = []
    session = replay_records(recs, options=SessionOptions(
        pose_source=pose_source, scan_matching=True, keep_points=True,
        scan_time_offset=offset),
        warn=lambda cause, text: warned.append((cause, text)))
    value = session.map_value()
    rows = np.asarray(value.trajectory)
    taken = SIM_START + np.asarray(drive.stamps) + lag + offset   # the stamps as mapped
    i = np.clip(np.searchsorted(taken, rows[:, 0]), 1, len(taken) - 1)
    scan = np.where(np.abs(taken[i - 1] - rows[:, 0]) <= np.abs(taken[i] - rows[:, 0]), i - 1, i)
    err = np.hypot(*(rows[:, 1:3] - np.asarray(drive.poses)[scan, :2]).T)
    walls = wall_scores(value.segments, drive.world.walls, drive.world.distance,
                        points=drive.points())
    clock = [text for cause, text in warned if cause == 'scan_clock']
    fix = (float(re.search(r'scan_time_offset to (-?[0-9.]+)', clock[0]).group(1))
           if clock else None)
    return {'rms_m': round(float(np.sqrt(np.mean(err ** 2))), 3),
            'max_m': round(float(err.max()), 3), 'used': int(session.used),
            'f1': round(walls['f1'], 3), 'precision': round(walls['precision'], 3),
            'warnings': len(clock), 'offset_advised': fix,
            'lag_estimate': None if session.stamp_lag is None
            else round(session.stamp_lag.lag, 3)}


def main() -> int:
    args, meta = case_run(__doc__, 'scan_clock.py')
    rows, drives = [], {}
    for spec, lag in CASES[:3] if args.quick else CASES:
        drive, odometry = drifting_drive(drives, spec)
        recs = records(drive, odometry, lag)
        row = {'drive': spec, 'scans': len(drive.stamps), 'lag_s': lag,
               'as_recorded': one(drive, recs, lag)}
        advised = row['as_recorded']['offset_advised']
        row['offset_set'] = None if advised is None else one(drive, recs, lag, advised)
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (drift seed 1; scans stamped the given seconds late, "
             'negative: early; mapped as recorded, then with `scan_time_offset` set to the '
             "value of the run's first `scan_clock` warning).", '',
             '| drive (scans) | scans stamped late by (s) | as recorded: RMS / max (m), F1 / '
             'precision | first warning advises scan_time_offset | with it set: RMS / max '
             '(m), F1 / precision, warnings |',
             '|---|---|---|---|---|']
    for r in rows:
        a, f = r['as_recorded'], r['offset_set']
        fixed = ('not warned' if f is None else
                 f"{f['rms_m']:.3f} / {f['max_m']:.2f}, {f['f1']:.2f} / {f['precision']:.2f}, "
                 f"{f['warnings']}")
        lines.append(
            f"| {r['drive']} ({r['scans']}) | {r['lag_s']:+.2f} "
            f"| {a['rms_m']:.3f} / {a['max_m']:.2f}, {a['f1']:.2f} / {a['precision']:.2f} "
            f"| {'-' if a['offset_advised'] is None else format(a['offset_advised'], '+.3f')} "
            f'| {fixed} |')
    publish('scan-clock', 'scan_clock', meta, rows, lines, args.quick)
    return 0 if all(math.isfinite(r['as_recorded']['rms_m']) for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
