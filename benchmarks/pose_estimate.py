"""
Pose estimates on real logs: localizing on a saved map when the odometry starts elsewhere.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/pose_estimate.py [--datasets DIR] [--only intel-corrected]

Per corrected Radish log (Intel, CSAIL): the map replayed from the corrected poses is the saved
map. The log is then given as a robot without a localizer records it: drifting wheel odometry
(issue 19's model, ``OdometryDrift``, seed 0) whose frame starts ``ODOM_ORIGIN`` away from the
map's origin, no map frame. Localized on the saved map (``pose_source odom``, ``mapping``
false, through the session):

- ``no start``: nothing says where the robot is (the node's default ``initial_pose``, the
  map's origin): the first scans are 2.6 m and 0.6 rad off;
- ``estimate``: as that, plus a pose estimate before scan ``--at`` (a ``PoseEstimate`` record,
  what the node's ``initialpose`` and a bag's /initialpose give) off the true base pose by
  each of ``OFFSETS`` (in the robot's frame), with RViz's covariance (0.5 m, 0.26 rad: searched
  within 1.5 m and 0.79 rad);
- ``true start``: ``initial_pose`` the true first base pose (the reference).

Scores: the trajectory (base poses of the scans used) against the corrected base poses from
``--at`` + 20 on: RMS, p95 and the share within 0.2 m; the scans not mapped; the match
outcomes. Writes the table into benchmarks/README.md (between the ``pose-estimate`` markers)
and the raw numbers to benchmarks/results/pose_estimate.json.
"""

import argparse
from collections import Counter
import json
import sys

from common import datasets_argument, radish_logs, stamp, write_readme, write_results
import numpy as np
from polyline_mapper.core.geometry import se2_compose, se2_inverse
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.records import PoseEstimate, Scan
from polyline_mapper.recordings import carmen_messages, flat_records, OdometryDrift, robot_messages
from polyline_mapper.replay import replay_records
from polyline_mapper.session import MappingSession, SessionOptions

LOGS = ('intel-corrected', 'csail-corrected')
ODOM_ORIGIN = (2.0, -1.5, 0.6)
"""Where the odometry frame starts in the map (x, y m, yaw rad): 2.5 m and 0.6 rad off."""
OFFSETS = [(0.3, 0.0, 0.1), (0.5, -0.5, 0.3), (-0.8, 0.6, -0.5)]
"""How far off the estimate is from the true base pose, in the robot's frame (m, m, rad)."""
RVIZ = np.diag([0.25, 0.25, 0.06853892326654787])
"""The covariance RViz's "2D Pose Estimate" gives (x, y, yaw)."""


def localize(records: list, saved, initial=None, estimate=None, at: int = 0) -> tuple:
    """
    Localize ``records`` on the saved map value; a PoseEstimate before scan ``at``.

    Returns (session, Counter of the warnings' causes).
    """
    warned = Counter()
    session = MappingSession(None, SessionOptions(pose_source='odom', keep_points=True,
                                                  mapping=False),
                             warn=lambda cause, text: warned.update([cause]))
    session.load_map(saved, initial)
    n = 0
    for record in records:
        if isinstance(record, Scan):
            if n == at and estimate is not None:
                session.add(estimate)
            n += 1
        session.add(record)
        session.step()
    session.flush()
    return session, warned


def score(run: tuple, stamps: np.ndarray, base: np.ndarray, start: int) -> dict:
    """Errors of the trajectory's base poses from scan ``start`` on, outcomes and warnings."""
    session, warned = run
    rows = np.asarray(session.map_value().trajectory)
    scan = np.searchsorted(stamps, rows[:, 0] - 1e-6)
    late = scan >= start
    err = np.hypot(*(rows[late, 1:3] - base[scan[late], :2]).T)
    out = {'not_mapped': int(len(stamps) - len(rows)), 'matches': dict(session.matches),
           'warnings': dict(warned), 'wrong_start_at_end': session.wrong_start is not None}
    if len(err):
        out.update(rms_m=round(float(np.sqrt(np.mean(err ** 2))), 3),
                   p95_m=round(float(np.percentile(err, 95)), 3),
                   within_02=round(float(np.mean(err <= 0.2)), 3))
    return out


def one_log(name: str, path: str, at: int) -> list:
    """Rows of one log: no start, each estimate offset, true start."""
    log = read_carmen(path)
    stamps, _ = log.stamps(1.0)
    saved = replay_records(flat_records(carmen_messages(log, stamps))).map_value()
    mount = np.asarray(log.laser_offset, dtype=np.float64)
    laser = np.array([r.pose for r in log.records])
    base = se2_compose(laser, se2_inverse(mount))
    odom = se2_compose(se2_inverse(np.asarray(ODOM_ORIGIN)), OdometryDrift().apply(base, 0))
    scans = log.scans(stamps, frame_id='laser', with_pose=False)
    records = flat_records(robot_messages(stamps, se2_compose(odom, mount), scans, mount=mount))
    stamps = np.asarray(stamps, dtype=np.float64)
    rows = []

    def row(case, run):
        rows.append({'log': name, 'scans': len(stamps), 'case': case,
                     **score(run, stamps, base, at + 20)})
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)

    row('no start', localize(records, saved))
    for offset in OFFSETS:
        guess = se2_compose(base[at], np.asarray(offset, dtype=np.float64))
        estimate = PoseEstimate(float(stamps[at]), saved.frame_id, guess, RVIZ)
        row(f'estimate {offset[0]:+.1f}, {offset[1]:+.1f} m, {offset[2]:+.1f} rad off',
            localize(records, saved, estimate=estimate, at=at))
    row('true start', localize(records, saved, initial=base[0]))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    datasets_argument(ap)
    ap.add_argument('--only', nargs='+', choices=LOGS, help='logs to run (default: all)')
    ap.add_argument('--at', type=int, default=10,
                    help='scan before which the estimate is given (default 10)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/pose_estimate.py ' + ' '.join(sys.argv[1:]))
    rows = []
    for name, path in radish_logs(args.datasets, LOGS, args.only):
        rows += one_log(name, str(path), args.at)
    write_results('pose_estimate', meta, rows)
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (odometry frame {ODOM_ORIGIN} from the map's origin, drift "
             f'seed 0; estimate before scan {args.at}; scored from scan {args.at + 20} on).',
             '', '| log (scans) | case | RMS / p95 (m) | within 0.2 m | scans not mapped | '
             'match outcomes | warnings |', '|---|---|---|---|---|---|---|']
    for r in rows:
        err = (f"{r['rms_m']:.3f} / {r['p95_m']:.3f} | {100 * r['within_02']:.1f} %"
               if 'rms_m' in r else '- | -')
        outcomes, warned = (', '.join(f'{k} {v}' for k, v in sorted(r[key].items()))
                            for key in ('matches', 'warnings'))
        lines.append(f"| {r['log']} ({r['scans']}) | {r['case']} | {err} | {r['not_mapped']} "
                     f"| {outcomes} | {warned or '-'} |")
    write_readme('pose-estimate', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
