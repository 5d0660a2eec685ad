"""
Odometry slower than the scans: what interpolating sparse odometry costs a scan-matched map.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/odom_rate.py [--quick]

Each scan is posed, and each of its beams deskewed, at the odometry (or TF) interpolated at
its time. Wheel odometry usually comes at 20-50 Hz; a base that publishes it at a few hertz,
or a recording whose /odom was throttled, leaves the session to interpolate across the
changes of the turn rate. Each simulated drive (``make_drive(spec, 1)``: 0.5 m/s, turning in
place at 1 rad/s, 10 Hz scans whose beams are taken over the scan time) is recorded as a robot
without a localizer (odometry with the drift of ``recordings.OdometryDrift``, seed 1; laser at
the base, no map frame) whose odometry messages (/odom and the /tf odom -> base_link) are kept
one in ``every`` (every 1: 10 Hz; 10: 1 Hz), and mapped with ``scan_matching`` in odom mode
and in tf mode through the session (``replay_records``). Scores as ``scan_clock.py``: the base
poses of the scans used against the true ones (RMS and largest error, m), the walls (F1 and
precision of ``baselines.walls.wall_scores``), and any ``scan_clock`` warning (interpolated
odometry smooths the turns' onsets, which could read as a lag).

Writes (not with ``--quick``) the table into benchmarks/README.md (between the ``odom-rate``
markers) and the raw numbers to benchmarks/results/odom_rate.json.
"""

import json
import math
import sys

from common import case_run, drifting_drive, publish
import numpy as np
from polyline_mapper.recordings import thin_odometry
from scan_clock import CORRIDORS, OFFICE, one, records

CASES = ([(OFFICE, mode, every) for every in (1, 2, 5, 10) for mode in ('odom', 'tf')]
         + [(CORRIDORS, 'odom', every) for every in (1, 5)])
"""(drive, pose source, one odometry message kept in this many)."""


def main() -> int:
    args, meta = case_run(__doc__, 'odom_rate.py')
    rows, drives = [], {}
    for spec, mode, every in CASES[:3] if args.quick else CASES:
        drive, odometry = drifting_drive(drives, spec)
        recs = thin_odometry(records(drive, odometry, 0.0), every)
        rate = 1.0 / (every * float(np.median(np.diff(drive.stamps))))
        row = {'drive': spec, 'scans': len(drive.stamps), 'pose_source': mode, 'every': every,
               'odometry_hz': round(rate, 2), **one(drive, recs, 0.0, pose_source=mode)}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (drift seed 1; scan matching; 10 Hz scans, one odometry "
             'message in N kept).', '',
             '| drive (scans) | pose source | odometry (Hz) | RMS / max (m) | walls F1 / '
             'precision | scan_clock warnings |',
             '|---|---|---:|---|---|---:|']
    for r in rows:
        lines.append(f"| {r['drive']} ({r['scans']}) | {r['pose_source']} | "
                     f"{r['odometry_hz']:g} | {r['rms_m']:.3f} / {r['max_m']:.2f} | "
                     f"{r['f1']:.2f} / {r['precision']:.2f} | {r['warnings']} |")
    publish('odom-rate', 'odom_rate', meta, rows, lines, args.quick)
    return 0 if all(math.isfinite(r['rms_m']) for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
