"""
Scan matching against the corrected poses, and against the scans themselves.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/consistency.py [--datasets DIR] [--only NAME ...]

``drift.py`` scores the trajectory that scan matching gives against the logs' corrected poses,
and the map against the points those poses place. That reference is itself the output of
someone's SLAM. This benchmark asks which of the two trajectories the scans agree with: for
each Radish log it replays (as ``drift.py`` does, ``polyline-mapper convert --odom-drift`` then
``replay --pose-source odom --scan-matching``)

- odometry that follows the corrected poses exactly (``OdometryDrift`` with every noise 0):
  what scan matching does where the odometry is perfect;
- the drifted odometry of issue 19, seed 0;

and reports, for those and for the corrected poses themselves:

- scan consistency (``core.metrics.scan_consistency``): each scan placed by the trajectory's
  step onto the previous scan's own polyline: mean distance of its points within 0.10 m, and
  their share; no ground truth involved;
- each step's disagreement with the corrected poses' step (translation and heading, median
  and 90th percentile) and the ATE (``core.metrics.trajectory_error``).

Writes the table into benchmarks/README.md (between the ``consistency`` markers) and the raw
numbers to benchmarks/results/consistency.json.
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile

from common import datasets_argument, stamp, table_header, write_readme, write_results
import numpy as np
from polyline_mapper.core.geometry import se2_compose, se2_inverse, wrap_angle
from polyline_mapper.core.metrics import scan_consistency, trajectory_error
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.carmen_bag import carmen_to_bag
from polyline_mapper.recordings import OdometryDrift
from polyline_mapper.replay import run_replay
from polyline_mapper.scan import scan_to_points
from polyline_mapper.session import SessionOptions

LOGS = ['intel-corrected', 'csail-corrected', 'freiburg-079-corrected']
RUNS = (('corrected poses', None), ('exact odometry + scan matching', 'exact'),
        ('drifted odometry (seed 0) + scan matching', 0))


def matched_laser_poses(path: pathlib.Path, drift, mount: np.ndarray) -> np.ndarray:
    """Replay ``path`` with drifting (``drift``: a seed, or 'exact') odometry and matching."""
    exact = drift == 'exact'
    with tempfile.TemporaryDirectory() as tmp:
        bag = os.path.join(tmp, 'bag')
        carmen_to_bag(str(path), bag, drift_seed=0 if exact else drift,
                      drift_model=OdometryDrift(0.0, 0.0, 0.0) if exact else None)
        res = run_replay(bag, options=SessionOptions(pose_source='odom', scan_matching=True),
                         progress=True)
    base = np.asarray(res.map_value.trajectory)[:, 1:]
    return se2_compose(base, mount)


def step_disagreement(poses: np.ndarray, reference: np.ndarray) -> dict:
    """Each step of ``poses`` seen from the same step of ``reference``: percentiles."""
    a = se2_compose(se2_inverse(poses[:-1]), poses[1:])
    b = se2_compose(se2_inverse(reference[:-1]), reference[1:])
    d = se2_compose(se2_inverse(b), a)
    t, h = np.hypot(d[:, 0], d[:, 1]), np.degrees(np.abs(wrap_angle(d[:, 2])))
    return {'translation_cm': [float(100 * np.percentile(t, q)) for q in (50, 90)],
            'heading_deg': [float(np.percentile(h, q)) for q in (50, 90)]}


def one_log(name: str, datasets: str) -> list:
    """Return the rows of one log."""
    path = pathlib.Path(datasets) / 'radish' / f'{name}.log.gz'
    log = read_carmen(str(path))
    scans = [scan_to_points(np.asarray(r.ranges), np.asarray(r.angles), np.zeros(3), 0.0,
                            log.usable_range(r)) for r in log.records]
    truth = np.array([r.pose for r in log.records])          # laser poses
    mount = np.asarray(log.laser_offset, dtype=np.float64)
    rows = []
    for label, drift in RUNS:
        print(f'{name}: {label}', file=sys.stderr, flush=True)
        poses = truth if drift is None else matched_laser_poses(path, drift, mount)
        if len(poses) != len(truth):
            raise RuntimeError(f'{len(poses)} poses used for {len(truth)} scans')
        c = scan_consistency(scans, poses)
        row = {'log': name, 'poses': label, 'consistency_cm': 100 * c['mean'],
               'consistency_share': 100 * c['share'], 'pairs': c['pairs'],
               'ate_m': trajectory_error(poses, truth)['ate']}
        if drift is not None:
            row.update(step_disagreement(poses, truth))
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main() -> int:
    """Run the logs; write the table and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='+', choices=LOGS)
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/consistency.py ' + ' '.join(sys.argv[1:]))
    rows = [row for name in args.only or LOGS for row in one_log(name, args.datasets)]
    write_results('consistency', meta, rows)
    lines = table_header(meta, [
        'log', 'poses', 'scan on previous scan: mean (cm) / within 0.10 m (%)',
        'step vs corrected step: translation p50 / p90 (cm)', 'heading p50 / p90 (deg)',
        'ATE against the corrected poses (m)'])
    for r in rows:
        t, h = r.get('translation_cm'), r.get('heading_deg')
        lines.append(f"| {r['log']} | {r['poses']} | {r['consistency_cm']:.2f} / "
                     f"{r['consistency_share']:.1f} | "
                     f"{'-' if t is None else f'{t[0]:.2f} / {t[1]:.2f}'} | "
                     f"{'-' if h is None else f'{h[0]:.3f} / {h[1]:.3f}'} | "
                     f"{r['ate_m']:.3f} |")
    write_readme('consistency', '\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
