"""
A laser that sees nothing of the saved map for 3 s: localization only, and finding the map again.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/blocked_laser.py [--seeds 1] [--quick]

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
from polyline_mapper.formats.records import Scan
from polyline_mapper.poses import se2_compose, se2_inverse
from polyline_mapper.recordings import (drive_messages, flat_records, make_drive, SIM_MOUNT,
                                        SIM_START)
from polyline_mapper.replay import replay_records

BLOCK = 30
VALUES = {'ring': 0.4, 'none': float('inf')}


def blocked_scans(records, start: int, count: int, value: float) -> list:
    """Return ``records`` with the scans [start, start + count) reading ``value`` on every beam."""
    blocked, n = [], 0
    for rec in records:
        if isinstance(rec, Scan):
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


def window(records, saved, truth, start: int, value: float) -> dict:
    """Localize ``records`` on ``saved`` with scans [start, start + BLOCK) blocked."""
    blocked = blocked_scans(records, start, BLOCK, value)
    warned = []
    stamps, poses, covs, matched = localize(blocked, saved,
                                            warn=lambda cause, text: warned.append(cause))
    index = np.searchsorted(truth[0], stamps - 1e-6)
    err = poses - truth[1][index]
    err[:, 2] = np.angle(np.exp(1j * err[:, 2]))
    dist = np.hypot(err[:, 0], err[:, 1])
    nees = [float(e @ np.linalg.solve(c, e)) for e, c, m in zip(err, covs, matched) if not m]
    end = start + BLOCK
    after = np.flatnonzero(matched & (index >= end))
    return {'start': start, 'tail_m': float(dist[index >= end + 10].max()),
            'end_m': float(dist[-1]), 'found_after': int(index[after[0]] - end) if len(after)
            else None, 'nees': nees, 'not_localized': warned.count('not_localized')}


def main() -> int:
    """Run the windows; write the table and the raw rows."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=[1])
    ap.add_argument('--quick', action='store_true', help='three windows, printed')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/blocked_laser.py ' + ' '.join(sys.argv[1:]))
    saved, base = office_on_true_poses()
    starts = [30, 100, 190] if args.quick else list(range(10, 320, 10))
    rows = []
    for seed in args.seeds:
        records, truth = drifted_office(seed, base)
        for mode, value in VALUES.items():
            for start in starts:
                r = {'mode': mode, 'seed': seed, **window(records, saved, truth, start, value)}
                rows.append(r)
                print(json.dumps({k: v for k, v in r.items() if k != 'nees'}), file=sys.stderr,
                      flush=True)
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


if __name__ == '__main__':
    sys.exit(main())
