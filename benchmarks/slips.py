"""
Wheel slips: how far the odometry can jump before scan matching maps the scans wrong.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/slips.py [--seeds 1 7] [--at 30]

Each simulated office drive (``make_drive('office', seed)``, 541 beams, 1 cm noise) as a robot
without a localizer records it (/odom and /tf odom -> base_link, no map frame, the laser on
its mount), with perfect odometry except one slip: the step into scan ``--at`` gets an extra
motion (dx, dy, dyaw) in the robot's frame, and every later pose carries it (a wheel that
slipped, a bump, a kidnapped robot). Mapped with ``pose_source odom`` and ``scan_matching``
through the session (``replay_records``). Scores: the base poses of the scans used against the
true ones after the slip (largest and last position error), the match outcomes, the scans not
mapped (the session lost after a refused correction), the jumps the node would warn of, and
the map's walls (F1 and precision of ``baselines.walls.wall_scores``), and the share of the
map's length that its own beams contradict (``freespace.judge``: >= 5 beams pass through, more
than end on it; every mapped scan's beams, from the laser pose the session used, mount
included: ``session.points()`` and ``session.origins()``).

Writes the table into benchmarks/README.md (between the ``slips`` markers) and the raw numbers
to benchmarks/results/slips.json.
"""

import argparse
import json
import sys

from baselines.walls import wall_scores
from common import contradicted, CONTRADICTED_NOTE, HERE, notable_lines, stamp, write_readme
import numpy as np
from polyline_mapper.core.geometry import se2_compose, se2_inverse
from polyline_mapper.recordings import (drive_messages, flat_records, make_drive, SIM_MOUNT,
                                        SIM_START)
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions

SLIPS = [(0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.8, 0.0, 0.0), (1.2, 0.0, 0.0), (1.5, 0.0, 0.0),
         (2.0, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.2), (0.0, 0.0, 0.35), (0.0, 0.0, 0.5)]
"""(dx, dy, dyaw) of the slip in the robot's frame: metres, metres, radians."""


def slipped(base: np.ndarray, at: int, slip) -> np.ndarray:
    """Return odometry that follows ``base`` exactly except for ``slip`` added at step ``at``."""
    odom = base.copy()
    rel = se2_compose(se2_inverse(base[at - 1]), base[at:])     # true motion since at - 1
    odom[at:] = se2_compose(se2_compose(base[at - 1], np.asarray(slip, dtype=float)), rel)
    return odom


def one(drive, at: int, slip) -> dict:
    """Map the drive with one slip; return its row."""
    mount = np.asarray(SIM_MOUNT, dtype=np.float64)
    base = se2_compose(drive.poses, se2_inverse(mount))
    stamps = SIM_START + np.asarray(drive.stamps, dtype=np.float64)
    records = flat_records(drive_messages(drive, odometry=slipped(base, at, slip)))
    session = replay_records(records, options=SessionOptions(
        pose_source='odom', scan_matching=True, keep_points=True))
    rows = np.asarray(session.map_value().trajectory)           # one per scan used
    scan = np.searchsorted(stamps, rows[:, 0])
    after = scan >= at
    err = np.hypot(*(rows[after, 1:3] - base[scan[after], :2]).T)
    segs = session.map_value().segments
    walls = wall_scores(segs, drive.world.walls, drive.world.distance, points=drive.points())
    free = contradicted(segs, session.points(), session.origins())
    return {'slip': list(slip), 'not_mapped': len(stamps) - len(rows),
            'max_error_m': round(float(err.max()), 3),
            'final_error_m': round(float(err[-1]), 3), 'matches': dict(session.matches),
            'jumps': dict(session.jumps), 'f1': round(walls['f1'], 3),
            'precision': round(walls['precision'], 3), 'segments': int(len(segs)),
            'contradicted_pct': round(free['contradicted_pct'], 3),
            'contradicted_segments': free['contradicted_segments']}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 7],
                    help='drive seeds (default 1 7)')
    ap.add_argument('--at', type=int, default=30, help='scan index of the slip (default 30)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/slips.py ' + ' '.join(sys.argv[1:]))
    rows = []
    for seed in args.seeds:
        drive = make_drive('office', seed=seed)
        for slip in SLIPS:
            rows.append({'seed': seed, 'scans': len(drive.poses), **one(drive, args.at, slip)})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    (HERE / 'results' / 'slips.json').write_text(
        json.dumps({'meta': meta, 'rows': rows}, indent=1) + '\n')
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}` (the office drive, one slip at scan {args.at}). "
             f'{CONTRADICTED_NOTE}; beams of every mapped scan, from the laser pose the session '
             'used (odometry and matching, mount included) to its points.', '',
             '| drive seed (scans) | slip dx, dy (m), dyaw (rad) | largest / last pose error '
             '(m) | match outcomes | scans not mapped | jump warnings | walls F1 / precision | '
             'contradicted (segments) |',
             '|---|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f"| {r['seed']} ({r['scans']}) "
                     f"| {r['slip'][0]:.1f}, {r['slip'][1]:.1f}, {r['slip'][2]:.2f} "
                     f"| {r['max_error_m']:.3f} / {r['final_error_m']:.3f} "
                     f"| {', '.join(f'{k} {v}' for k, v in sorted(r['matches'].items()))} "
                     f"| {r['not_mapped']} "
                     f"| {', '.join(f'{k} {v}' for k, v in sorted(r['jumps'].items())) or '-'} "
                     f"| {r['f1']:.2f} / {r['precision']:.2f} "
                     f"| {r['contradicted_pct']:.1f}% ({r['contradicted_segments']}) |")
    notes = notable_lines([(f"seed {r['seed']}, slip {r['slip'][0]:.1f}, {r['slip'][1]:.1f}, "
                            f"{r['slip'][2]:.2f}", r['contradicted_pct'],
                            r['contradicted_segments']) for r in rows])
    if notes:
        lines += ['', 'Maps contradicted on more than 2 % of their length:', ''] + notes
    write_readme('slips', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
