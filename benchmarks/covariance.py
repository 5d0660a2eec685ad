"""
The pose covariance the node publishes against the pose's error (scan matching).

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/covariance.py [--datasets DIR] [--seeds 0 1 2] [--no-logs]

The node publishes each matched pose with a covariance (``pose``,
geometry_msgs/PoseWithCovarianceStamped; ``Localization.covariance``). A consumer (an EKF
fusing it with odometry, a planner's recovery) trusts it as the spread of the pose's error.
Here the error is known: localization only (``mapping: false``) on a saved map, with drifting
wheel odometry (``OdometryDrift``, seeded), against the true poses:

- ``office``: ``sim:office`` mapped with true poses (drive noise seed 100 + seed), then the same
  path driven again with fresh range noise (noise seed ``seed``) and odometry drift seed
  ``seed``, localized on that map;
- a real log (Intel, CSAIL): the log replayed with its corrected poses makes the map; the same
  log with drifting odometry (drift seed ``seed``, no map frame: ``convert --odom-drift``'s
  messages) is localized on it; the truth is the corrected poses.

Per matched scan, the error e (x, y, yaw of the base frame) and the published covariance S:
NEES = e^T S^-1 e (its mean is 3 when S is the error's covariance), the share of scans with
NEES under the chi-square 95 % bound for 3 degrees of freedom (7.81; 95 % when calibrated),
and per axis the RMS of the error over its published standard deviation (1 when calibrated).
The largest share of the error is the map's own (the saved map is fixed): what a localizer's
covariance must cover.

Writes the table into benchmarks/README.md (between the ``covariance`` markers) and the rows to
results/covariance.json.
"""

import argparse
import sys

from common import datasets_argument, radish_logs, stamp, table_header, write_readme, \
    write_results
import numpy as np
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.poses import se2_compose, se2_inverse
from polyline_mapper.recordings import (carmen_messages, drive_messages, flat_records, make_drive,
                                        OdometryDrift, SIM_MOUNT)
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions

CHI2_95_3DOF = 7.815
"""The chi-square distribution's 95 % point for 3 degrees of freedom."""

LOGS = ['intel-corrected', 'csail-corrected']


def localize(records, saved, warn=None) -> tuple:
    """
    Localize ``records`` on the map ``saved``; return (stamps, poses, covariances, matched).

    ``warn``: the session's warnings, (cause, text), as ``replay_records`` takes them.
    """
    rows = []

    def keep(session):
        loc = session.localization
        if loc is not None and (not rows or rows[-1][0] != loc.stamp):
            rows.append((loc.stamp, loc.pose, loc.covariance, loc.matched))
    replay_records(records, options=SessionOptions(mapping=False), start_map=saved,
                   progress=keep, warn=warn)
    stamps, poses, covs, matched = zip(*rows)
    return (np.array(stamps), np.array(poses), np.array(covs), np.array(matched))


def scores(poses, covs, matched, truth) -> dict:
    """Return the calibration scores of matched poses (base frame) against ``truth``."""
    e = (poses - truth)[matched]
    e[:, 2] = np.angle(np.exp(1j * e[:, 2]))
    s = covs[matched]
    nees = np.einsum('ni,ni->n', e, np.linalg.solve(s, e[:, :, None])[:, :, 0])
    std = np.sqrt(np.einsum('nii->ni', s))
    ratio = np.sqrt(np.mean((e / std) ** 2, axis=0))
    return {'scans': int(len(matched)), 'matched': int(matched.sum()),
            'nees_mean': float(nees.mean()), 'nees_median': float(np.median(nees)),
            'within_95': float(np.mean(nees < CHI2_95_3DOF)),
            'ratio_x': float(ratio[0]), 'ratio_y': float(ratio[1]), 'ratio_yaw': float(ratio[2]),
            'error_cm': float(100 * np.median(np.hypot(e[:, 0], e[:, 1]))),
            'std_cm': float(100 * np.median(np.sqrt(std[:, 0] * std[:, 1]))),
            'error_yaw_mrad': float(1000 * np.median(np.abs(e[:, 2]))),
            'std_yaw_mrad': float(1000 * np.median(std[:, 2]))}


def office(seed: int) -> dict:
    """Localize the office drive (noise and drift seed ``seed``) on a map of another pass."""
    mapped = make_drive('sim:office', seed=100 + seed)
    saved = replay_records(flat_records(drive_messages(mapped))).map_value()
    drive = make_drive('sim:office', seed=seed)
    records = flat_records(drive_messages(drive, odom_drift=seed))
    stamps, poses, covs, matched = localize(records, saved)
    base = se2_compose(np.asarray(drive.poses), se2_inverse(np.asarray(SIM_MOUNT)))
    return scores(poses, covs, matched, base[:len(poses)])


def real_log(path, seed: int, saved) -> dict:
    """Localize a CARMEN log with drifting odometry (``seed``) on its corrected map ``saved``."""
    log = read_carmen(str(path))
    stamps, _ = log.stamps()
    records = flat_records(carmen_messages(log, stamps, (OdometryDrift(), seed)))
    got, poses, covs, matched = localize(records, saved)
    laser = np.array([r.pose for r in log.records])
    base = se2_compose(laser, se2_inverse(np.asarray(log.laser_offset, dtype=np.float64)))
    return scores(poses, covs, matched, base[np.searchsorted(stamps, got - 1e-6)])


def main() -> int:
    """Run every case; write the README block and the raw rows."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    datasets_argument(ap)
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    ap.add_argument('--no-logs', action='store_true', help='the simulated office only')
    ap.add_argument('--no-write', action='store_true', help='print only')
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        rows.append({'case': 'office', 'seed': seed, **office(seed)})
        print(rows[-1], flush=True)
    logs = [] if args.no_logs else list(radish_logs(args.datasets, LOGS))
    for name, path in logs:
        log = read_carmen(str(path))
        stamps, _ = log.stamps()
        saved = replay_records(flat_records(carmen_messages(log, stamps))).map_value()
        for seed in args.seeds:
            rows.append({'case': name, 'seed': seed, **real_log(path, seed, saved)})
            print(rows[-1], flush=True)
    if args.no_write:
        return 0
    meta = stamp('.venv/bin/python benchmarks/covariance.py ' + ' '.join(sys.argv[1:]))
    lines = table_header(meta, ['case', 'seed', 'matched / scans', 'NEES mean / median',
                                'NEES < 7.81', 'error / std RMS (x, y, yaw)',
                                'median error / std (cm)', 'median yaw error / std (mrad)'])
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['seed']} | {r['matched']} / {r['scans']} | "
            f"{r['nees_mean']:.1f} / {r['nees_median']:.1f} | {100 * r['within_95']:.0f} % | "
            f"{r['ratio_x']:.2f}, {r['ratio_y']:.2f}, {r['ratio_yaw']:.2f} | "
            f"{r['error_cm']:.2f} / {r['std_cm']:.2f} | "
            f"{r['error_yaw_mrad']:.1f} / {r['std_yaw_mrad']:.1f} |")
    write_readme('covariance', '\n'.join(lines) + '\n')
    write_results('covariance', meta, rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
