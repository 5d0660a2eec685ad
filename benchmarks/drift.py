"""
Mapping with drifting wheel odometry: the Radish logs as a robot without a localizer sees them.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/drift.py [--datasets DIR] [--only NAME ...] [--seeds 0 1 2 3 4]

For each log and seed, ``polyline-mapper convert LOG --odom-drift SEED`` writes a bag whose
/odom and /tf odom -> base_link follow the corrected poses with wheel-odometry-like drift added
(``recordings.OdometryDrift``: each step's motion with Gaussian noise, 5 % of the step per axis,
0.02 rad + 1 deg per metre of heading; the first pose true; no map frame), and
``polyline-mapper replay BAG --pose-source odom`` maps it. The map is scored against the log's
true points (mean distance, coverage within 0.10 m) and the poses the mapper used against the
corrected ones (RMS position error of the laser). The same log replayed with its corrected poses
is the reference. This is the baseline issue 19 (poses from the scans) has to improve on.

Writes the table into benchmarks/README.md (between the ``drift`` markers) and the raw numbers
to benchmarks/results/drift.json.
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile

from common import HERE, REPO, stamp, write_readme
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.carmen_bag import carmen_to_bag
from polyline_mapper.poses import se2_compose, se2_inverse
from polyline_mapper.recordings import OdometryDrift
from polyline_mapper.replay import run_replay
from polyline_mapper.session import SessionOptions

LOGS = ['intel-corrected', 'csail-corrected', 'freiburg-079-corrected']


def drifted_laser_poses(log, seed: int) -> np.ndarray:
    """Return the laser poses the drifted bag of ``log`` implies (as carmen_messages makes)."""
    laser = np.array([r.pose for r in log.records])
    mount = np.asarray(log.laser_offset, dtype=np.float64)
    base = OdometryDrift().apply(se2_compose(laser, se2_inverse(mount)), seed)
    return se2_compose(base, mount)


def one(path: pathlib.Path, seed, truth: np.ndarray, log) -> dict:
    """Map ``path`` with drift ``seed`` (None: the corrected poses); return its row."""
    with tempfile.TemporaryDirectory() as tmp:
        if seed is None:
            res = run_replay(str(path))
        else:
            bag = os.path.join(tmp, 'bag')
            carmen_to_bag(str(path), bag, drift_seed=seed)
            res = run_replay(bag, options=SessionOptions(pose_source='odom'))
    m = map_metrics(truth, res.map_value.segments)
    true_xy = np.array([r.pose[:2] for r in log.records])
    used_xy = true_xy if seed is None else drifted_laser_poses(log, seed)[:, :2]
    rms = float(np.sqrt(np.mean(np.sum((used_xy - true_xy) ** 2, axis=1))))
    return {'seed': seed, 'segments': len(res.map_value), 'mean_cm': 100 * m['mean_distance'],
            'coverage': 100 * m['coverage_0_10m'], 'traj_rms_m': rms,
            'traj_final_m': float(np.hypot(*(used_xy[-1] - true_xy[-1])))}


def main() -> int:
    """Run the logs and seeds; write the table and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--datasets', default=os.environ.get(
        'POLYLINE_MAPPER_DATASETS', str(REPO.parent / 'shared' / 'datasets')))
    ap.add_argument('--only', nargs='+', choices=LOGS)
    ap.add_argument('--seeds', nargs='+', type=int, default=[0, 1, 2, 3, 4])
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/drift.py ' + ' '.join(sys.argv[1:]))
    rows = []
    for name in args.only or LOGS:
        path = pathlib.Path(args.datasets) / 'radish' / f'{name}.log.gz'
        log = read_carmen(str(path))
        truth = log.points()
        for seed in [None] + list(args.seeds):
            row = dict(one(path, seed, truth, log), log=name)
            rows.append(row)
            print(json.dumps(row), flush=True)
    out = HERE / 'results'
    out.mkdir(exist_ok=True)
    (out / 'drift.json').write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1) + '\n')
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}`.", '',
             '| log | poses | mean distance (cm) | coverage (%) | trajectory RMS (m) | '
             'final error (m) | segments |', '|---|---|---|---|---|---|---|']
    for name in args.only or LOGS:
        ref = [r for r in rows if r['log'] == name and r['seed'] is None][0]
        drift = [r for r in rows if r['log'] == name and r['seed'] is not None]
        lines.append(f"| {name} | corrected | {ref['mean_cm']:.1f} | {ref['coverage']:.1f} | 0 | "
                     f"0 | {ref['segments']} |")
        seeds = ', '.join(str(r['seed']) for r in drift)
        cells = []
        for key, digits in (('mean_cm', 1), ('coverage', 1), ('traj_rms_m', 2),
                            ('traj_final_m', 2), ('segments', 0)):
            v = [r[key] for r in drift]
            cells.append(f'{np.mean(v):.{digits}f} ({min(v):.{digits}f}-{max(v):.{digits}f})')
        lines.append(f'| {name} | odometry, seeds {seeds} (mean, min-max) | '
                     + ' | '.join(cells) + ' |')
    write_readme('drift', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
