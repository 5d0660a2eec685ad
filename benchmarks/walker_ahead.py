"""
A person walking ahead of the robot: the matched poses with each part of the free-space evidence.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/walker_ahead.py [--seeds 1 3]

The simulated dynamic office (``make_drive('sim:office_dynamic', seed)``: a person walks up and
down the corridor ahead of the robot until 22 s, another in a room, a door opens, a box is
carried away), with true poses on /tf (the laser on the base), mapped with ``scan_matching``
through the session (``replay_records``), as ``test_imperfect_poses`` maps it. The corridor's
walls say nothing along its axis, so the person pulls the matches back; what the map holds of
the person's track and of the walls decides how far. One row per seed and mapper setting:

- ``off``: the free-space evidence off (``config/no_free_space.yaml``; short segments cleared);
- ``evidence``: the evidence per square alone (window 10; no ghosts, hit margin or memory);
- ``+ ghosts``, ``+ margin``, ``+ memory``: the evidence with one of the three;
- ``+ ghosts + margin``: the preset before the memory;
- ``all``: all of them (window 10, 20000 ghosts, margin 0.03, memory 0.1 m:
  ``config/free_space.yaml``; the defaults of f6242d4 / e4f6a53);
- ``default``: the defaults, whose window (-1) is 0 with scan matching: the same as ``off``.

Scores: RMS of the base position against the truth over every scan, the largest error, the
walls' F1 (``baselines.walls.wall_scores``), the scans whose correction was held
(``session.held``) and the contradicted share of the map (``freespace.judge``, the session's
own beams). Writes the table into benchmarks/README.md (between the ``walker-ahead`` markers)
and the rows to results/walker_ahead.json.
"""

import argparse
import json
import sys

from baselines.walls import wall_scores
from common import (contradicted, drive_truth, stamp, table_header, write_readme,
                    write_results)
import numpy as np
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.recordings import drive_messages, flat_records, make_drive
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions

NONE = {'free_space_window': 10, 'free_space_ghosts': 0, 'free_space_hit_margin': 0.0,
        'free_space_memory': 0.0}
SETTINGS = {
    'off': {'free_space_window': 0},
    'evidence': dict(NONE),
    '+ ghosts': dict(NONE, free_space_ghosts=20000),
    '+ margin': dict(NONE, free_space_hit_margin=0.03),
    '+ memory': dict(NONE, free_space_memory=0.1),
    '+ ghosts + margin': dict(NONE, free_space_ghosts=20000, free_space_hit_margin=0.03),
    'all': {'free_space_window': 10},
    'default': {},
}
"""IncrementalConfig fields of each row (over the defaults)."""


def one(drive, fields: dict, knots: str = SessionOptions.chord_knots) -> dict:
    """Map the drive with scan matching and the mapper ``fields``; return its scores."""
    records = flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0)))
    session = replay_records(records, IncrementalConfig(**fields),
                             SessionOptions(scan_matching=True, keep_points=True,
                                            chord_knots=knots))
    value = session.map_value()
    traj = np.asarray(value.trajectory)
    err = np.hypot(*(traj[:, 1:3] - drive_truth(drive, traj)[:, :2]).T)
    world = drive.world
    walls = wall_scores(value.segments, world.walls, world.distance, points=drive.points())
    free = contradicted(value.segments, session.points(), session.origins())
    return {'rms_m': round(float(np.sqrt(np.mean(err ** 2))), 4),
            'max_m': round(float(err.max()), 3), 'f1': round(walls['f1'], 3),
            'held': int(session.held), 'segments': int(len(value.segments)),
            'contradicted_pct': round(free['contradicted_pct'], 2)}


def main() -> int:
    """Map every seed with every setting; write the JSON and the README block."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 3],
                    help='drive seeds (default 1 3, the tests)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/walker_ahead.py ' + ' '.join(sys.argv[1:]))
    rows = []
    for seed in args.seeds:
        drive = make_drive('sim:office_dynamic', seed)
        for name, fields in SETTINGS.items():
            rows.append({'seed': seed, 'setting': name, **one(drive, fields)})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    write_results('walker_ahead', meta, rows)
    lines = table_header(meta, ['seed', 'setting', 'RMS / largest position error (m)',
                                'walls F1', 'held scans', 'segments', 'contradicted %'])
    for r in rows:
        lines.append(f"| {r['seed']} | {r['setting']} | {r['rms_m']:.3f} / {r['max_m']:.3f} "
                     f"| {r['f1']:.2f} | {r['held']} | {r['segments']} "
                     f"| {r['contradicted_pct']:.2f} |")
    write_readme('walker-ahead', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
