"""
A laser that sees nothing of the saved map for 3 s: localization only, and finding the map again.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/blocked_laser.py [--seeds 1] [--quick]
    .venv/bin/python benchmarks/blocked_laser.py --estimate 0.6 0.3 --block 100 200 --seeds 1 2 3

``sim:office`` is mapped with true poses; the same drive, with drifting odometry (issue 19's
model, ``drive_messages(odom_drift=seed)``), is localized on that map (``mapping: false``) with
30 of its scans (3 s, the odometry driving 6-9 m) replaced from scan 10, 20, ..., 310 by

- ``ring``: 0.4 m on every beam (the laser covered, people all round the robot), or
- ``none``: no return on any beam (each such scan is posed as a scan not matched, then skipped
  as unusable).

Per window: the largest error of the base pose from the 10th scan after the block to the end,
the error at the end, the first scan matched after the block, and for every scan not matched
NEES = e^T S^-1 e of its published covariance (3 on average, under 7.81 for 95 % of the scans
when S is the error's covariance). README "Localization on a saved map" states what the
session does (``ANCHOR_SHARE``, ``UNMATCHED_STREAK``, ``RECKONED_SEARCH``).

``--estimate M RAD``: a pose estimate at the true base pose with these standard deviations
comes before the first blocked scan (RViz's "2D Pose Estimate" given as the laser goes blind),
``--block``: how many scans are blocked (several: a run each; 30 without it), and the windows
start at scan 40 only; its table goes between the ``blocked-laser-estimate`` markers and
results/blocked_laser_estimate.json. An estimate wider than the match's reach is searched for
at the first scan that sees, its window widened by the odometry's error over the blind scans
(at most 3 m); a search that gives up leaves the session lost until the next pose estimate or
reset (a known limit: benchmarks/README.md, after the ``blocked-laser`` table).

Writes the table into benchmarks/README.md (between the ``blocked-laser`` markers) and the rows
to results/blocked_laser.json (not with ``--quick``: windows 30, 100, 190 only, printed).
"""

import argparse
import dataclasses
import json
import sys

from common import publish, stamp
from covariance import CHI2_95_3DOF, localize
import numpy as np
from polyline_mapper.formats.records import PoseEstimate, Scan
from polyline_mapper.poses import se2_compose, se2_inverse
from polyline_mapper.recordings import (drive_messages, flat_records, make_drive, SIM_MOUNT,
                                        SIM_START)
from polyline_mapper.replay import replay_records

BLOCK = 30
ESTIMATE_AT = 40
"""``--estimate``: the scan before which the estimate comes and the block begins."""
VALUES = {'ring': 0.4, 'none': float('inf')}


def blocked_scans(records, start: int, count: int, value: float, estimate=None) -> list:
    """
    Return ``records`` with the scans [start, start + count) reading ``value`` on every beam.

    ``estimate``: (base pose, 3x3 covariance) of a pose estimate put before scan ``start``.
    """
    blocked, n = [], 0
    for rec in records:
        if isinstance(rec, Scan):
            if n == start and estimate is not None:
                blocked.append(PoseEstimate(rec.stamp, 'map', *estimate))
            if start <= n < start + count:
                rec = dataclasses.replace(rec, ranges=np.full(len(rec.ranges), value,
                                                              dtype=np.float32))
            n += 1
        blocked.append(rec)
    return blocked


def office_on_true_poses() -> tuple:
    """Return ``sim:office`` mapped with true poses (MapValue) and its base poses (N, 3)."""
    office = make_drive('sim:office')
    saved = replay_records(flat_records(drive_messages(office))).map_value()
    return saved, se2_compose(np.asarray(office.poses), se2_inverse(np.asarray(SIM_MOUNT)))


def drifted_office(seed: int, base: np.ndarray) -> tuple:
    """
    Return ``sim:office`` with drifting odometry as records, and the truth to score it.

    Noise seed and drift seed ``seed`` (``odom_drift=seed``); ``base``: the true base poses.
    Returns (records, (stamps, base poses)).
    """
    drive = make_drive('sim:office', seed=seed)
    records = flat_records(drive_messages(drive, odom_drift=seed))
    return records, (SIM_START + np.asarray(drive.stamps), base)


def window(records, saved, truth, start: int, value: float, block: int = BLOCK,
           spread=None) -> dict:
    """
    Localize ``records`` on ``saved`` with scans [start, start + block) blocked.

    ``spread`` (m, rad): a pose estimate at the true base pose with these standard deviations
    before scan ``start``.
    """
    estimate = None if spread is None else (
        truth[1][start], np.diag([spread[0] ** 2, spread[0] ** 2, spread[1] ** 2]))
    blocked = blocked_scans(records, start, block, value, estimate)
    warned = []
    stamps, poses, covs, matched = localize(blocked, saved,
                                            warn=lambda cause, text: warned.append(cause))
    index = np.searchsorted(truth[0], stamps - 1e-6)
    err = poses - truth[1][index]
    err[:, 2] = np.angle(np.exp(1j * err[:, 2]))
    dist = np.hypot(err[:, 0], err[:, 1])
    nees = [float(e @ np.linalg.solve(c, e)) for e, c, m in zip(err, covs, matched) if not m]
    end = start + block
    after = np.flatnonzero(matched & (index >= end))
    return {'start': start, 'block': block, 'tail_m': float(dist[index >= end + 10].max()),
            'end_m': float(dist[-1]), 'found_after': int(index[after[0]] - end) if len(after)
            else None, 'nees': nees, 'not_localized': warned.count('not_localized'),
            'given_up': sum(cause.endswith('_given_up') for cause in warned)}


def main() -> int:
    """Run the windows; write the table and the raw rows."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=[1])
    ap.add_argument('--quick', action='store_true', help='three windows, printed')
    ap.add_argument('--estimate', type=float, nargs=2, metavar=('M', 'RAD'),
                    help='a pose estimate with these standard deviations before the block')
    ap.add_argument('--block', type=int, nargs='+', help='scans blocked (default 30)')
    args = ap.parse_args()
    if args.block is not None and args.estimate is None:
        ap.error('--block goes with --estimate (the table of 30-scan windows is the default)')
    meta = stamp('.venv/bin/python benchmarks/blocked_laser.py ' + ' '.join(sys.argv[1:]))
    saved, base = office_on_true_poses()
    starts = ([ESTIMATE_AT] if args.estimate is not None else [30, 100, 190] if args.quick
              else list(range(10, 320, 10)))
    rows = []
    for seed in args.seeds:
        records, truth = drifted_office(seed, base)
        for mode, value in VALUES.items():
            for block in args.block or [BLOCK]:
                for start in starts:
                    r = {'mode': mode, 'seed': seed, **window(records, saved, truth, start,
                                                              value, block, args.estimate)}
                    rows.append(r)
                    print(json.dumps({k: v for k, v in r.items() if k != 'nees'}),
                          file=sys.stderr, flush=True)
    if args.estimate is not None:
        return estimate_table(args, meta, rows)
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}`.", '',
             '| blocked | seed | windows | end within 6 cm | within 6 cm from 10 scans after | '
             'worst then (m) | found after (scans: median, max) | not matched: NEES mean / '
             'median, < 7.81 |', '|---|---:|---:|---:|---:|---:|---|---|']
    for seed in args.seeds:
        for mode in VALUES:
            sel = [r for r in rows if r['mode'] == mode and r['seed'] == seed]
            found = [r['found_after'] for r in sel if r['found_after'] is not None]
            nees = np.concatenate([r['nees'] for r in sel]) if sel else np.zeros(0)
            spread = (f'{nees.mean():.1f} / {np.median(nees):.2f}, '
                      f'{100 * np.mean(nees < CHI2_95_3DOF):.0f} % ({len(nees)})' if len(nees)
                      else 'none (the scans are skipped)')
            lines.append(
                f"| {mode} | {seed} | {len(sel)} | {sum(r['end_m'] <= 0.06 for r in sel)} | "
                f"{sum(r['tail_m'] <= 0.06 for r in sel)} | "
                f"{max(r['tail_m'] for r in sel):.2f} | "
                f"{int(np.median(found)) if found else '-'}, {max(found) if found else '-'} | "
                f'{spread} |')
    publish('blocked-laser', 'blocked_laser', meta, rows, lines, args.quick)
    return 0


def estimate_table(args, meta: dict, rows: list) -> int:
    """Write (or with ``--quick`` print) the table of the ``--estimate`` runs, one row each."""
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (a pose estimate at the true pose, {args.estimate[0]:g} m and "
             f'{args.estimate[1]:g} rad standard deviations, before scan {ESTIMATE_AT}; the '
             'block begins there).', '',
             '| blocked | seed | scans blocked | searches given up | first scan matched after '
             'the block | worst from 10 scans after (m) | error at the end (m) |',
             '|---|---:|---:|---:|---:|---:|---:|']
    for r in rows:
        lines.append(f"| {r['mode']} | {r['seed']} | {r['block']} | {r['given_up']} | "
                     f"{'-' if r['found_after'] is None else r['found_after']} | "
                     f"{r['tail_m']:.3f} | {r['end_m']:.3f} |")
    publish('blocked-laser-estimate', 'blocked_laser_estimate', meta, rows, lines, args.quick)
    return 0


if __name__ == '__main__':
    sys.exit(main())
