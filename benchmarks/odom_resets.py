"""
Odometry driver restarts: the odometry silent for a while, then back at its origin.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/odom_resets.py [--quick]

A driver that restarts stops publishing (the scans of that time are refused, ``odom_gap``) and
comes back with its pose at the origin while the robot drove on. Each simulated drive
(``make_drive(spec, 1)``) is recorded as a robot without a localizer (/odom with the drift of
``recordings.OdometryDrift``, seed 1; laser at the base, no map frame) whose odometry is not
published for ``silence`` scans before scan ``k`` and is reset to the origin at ``k``; mapped
with ``pose_source odom`` and ``scan_matching`` through the session (``replay_records``), three
ways: *control*, the same silence without the reset; *judged*, the default
(``session._reset_after_gap``: the scan searched for on the map around where the last pace
leads); *not judged*, with ``session.ODOM_RESET_REACH`` set to -1 (no pose is near the origin:
the behaviour before 2026-11-30). Scores: the base poses of the scans used against the true
ones (RMS and largest error, m), the scans used, the walls (F1 and precision of
``baselines.walls.wall_scores``) and how the reset was handled (``odom_jump`` found or
searching, ``odom_reset_given_up``).

Writes (not with ``--quick``) the table into benchmarks/README.md (between the ``odom-resets``
markers) and the raw numbers to benchmarks/results/odom_resets.json.
"""

import json
import math
import sys

from baselines.walls import wall_scores
from common import case_run, drifting_drive, publish
import numpy as np
from polyline_mapper.core.geometry import se2_compose, se2_inverse
from polyline_mapper.formats.records import Odometry
from polyline_mapper.recordings import drive_messages, flat_records, SIM_START
from polyline_mapper.replay import replay_records
import polyline_mapper.session as session_module
from polyline_mapper.session import SessionOptions

CASES = ([('sim:office,step=0.05', share, silence) for share in (0.2, 0.5, 0.8)
          for silence in (12, 20)]
         + [('sim:corridors,step=0.05', 0.5, 12), ('sim:office', 0.42, 12)])
"""(drive, share of the drive where the reset comes, scans of silence before it)."""


def records(drive, odometry: np.ndarray, k: int, silence: int) -> list:
    """Return the drive's records with ``odometry``, none for the ``silence`` scans before k."""
    stamps = SIM_START + np.asarray(drive.stamps, dtype=np.float64)
    quiet = (stamps[k - silence] - 1e-6, stamps[k] - 1e-6)
    return [r for r in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0),
                                                   odometry=odometry))
            if not (isinstance(r, Odometry) and quiet[0] <= r.stamp < quiet[1])]


def one(drive, recs: list) -> dict:
    """Map ``recs``; return the scores."""
    warned = []
    session = replay_records(recs, options=SessionOptions(
        pose_source='odom', scan_matching=True, keep_points=True),
        warn=lambda cause, text: warned.append((cause, text)))
    value = session.map_value()
    rows = np.asarray(value.trajectory)
    scan = np.searchsorted(SIM_START + np.asarray(drive.stamps), rows[:, 0] - 1e-6)
    err = np.hypot(*(rows[:, 1:3] - np.asarray(drive.poses)[scan, :2]).T)
    walls = wall_scores(value.segments, drive.world.walls, drive.world.distance,
                        points=drive.points())
    jumps = [text for cause, text in warned if cause == 'odom_jump']
    handled = ('given up' if any(c == 'odom_reset_given_up' for c, _ in warned)
               else 'found' if any('found on the map' in t for t in jumps)
               else 'jump judged' if jumps else '-')
    return {'rms_m': round(float(np.sqrt(np.mean(err ** 2))), 3),
            'max_m': round(float(err.max()), 3), 'used': int(session.used),
            'f1': round(walls['f1'], 3), 'precision': round(walls['precision'], 3),
            'handled': handled}


def main() -> int:
    args, meta = case_run(__doc__, 'odom_resets.py')
    rows, drives = [], {}
    for spec, share, silence in CASES[:3] if args.quick else CASES:
        drive, odometry = drifting_drive(drives, spec)
        k = int(share * len(drive.stamps))
        reset = odometry.copy()
        reset[k:] = se2_compose(se2_inverse(odometry[k]), odometry[k:])
        row = {'drive': spec, 'scans': len(drive.stamps), 'reset_at': k, 'silence': silence,
               'speed_m_s': round(float(np.median(np.hypot(*np.diff(
                   np.asarray(drive.poses)[:, :2], axis=0).T) / np.diff(drive.stamps))), 2),
               'control': one(drive, records(drive, odometry, k, silence)),
               'judged': one(drive, records(drive, reset, k, silence))}
        saved = session_module.ODOM_RESET_REACH
        session_module.ODOM_RESET_REACH = -1.0
        try:
            row['not_judged'] = one(drive, records(drive, reset, k, silence))
        finally:
            session_module.ODOM_RESET_REACH = saved
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (drift seed 1; the odometry silent for the given scans "
             'before the reset; control: the same silence without the reset; not judged: '
             '`ODOM_RESET_REACH` -1).', '',
             '| drive (scans, m/s) | reset at scan, after a silence of | control: RMS / max '
             '(m), F1 | judged: RMS / max (m), scans used, F1 / precision, outcome | not judged: '
             'RMS / max (m), scans used, F1 / precision |',
             '|---|---|---|---|---|']
    for r in rows:
        c, j, n = r['control'], r['judged'], r['not_judged']
        lines.append(
            f"| {r['drive']} ({r['scans']}, {r['speed_m_s']:g}) "
            f"| {r['reset_at']}, {r['silence']} scans "
            f"| {c['rms_m']:.3f} / {c['max_m']:.2f}, {c['f1']:.2f} "
            f"| {j['rms_m']:.3f} / {j['max_m']:.2f}, {j['used']}, {j['f1']:.2f} / "
            f"{j['precision']:.2f}, {j['handled']} "
            f"| {n['rms_m']:.3f} / {n['max_m']:.2f}, {n['used']}, {n['f1']:.2f} / "
            f"{n['precision']:.2f} |")
    publish('odom-resets', 'odom_resets', meta, rows, lines, args.quick)
    return 0 if all(math.isfinite(r['judged']['rms_m']) for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
