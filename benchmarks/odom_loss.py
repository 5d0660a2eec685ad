"""
Lost odometry messages (odom and tf mode): what the interpolated poses cost the map.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/odom_loss.py [--losses 0 0.05 0.2] [--seeds 0 1 2] \
        [--modes odom matching] [--gap-factors 1.5 0] [--sources odom tf] [--jobs 2]

The node's ``odom`` input is best effort by default (sensor-data QoS): a message lost leaves the
scans around it a pose interpolated between the odometry before and after the gap
(``poses.TransformBuffer2D``, as tf2), unless the session skips them: ``odom_gap_factor``
(default 1.5) skips a scan whose odometry interval is longer than that many times the typical
one (``--gap-factors``: each is run; 0 interpolates across every gap). Two simulated office
drives (seed 7), one odometry message per scan, true poses (no drift), the laser on the base
(mount 0), fed to the session in odom mode (``replay_records``, the node's code) with a share
of the odometry messages dropped at random (``--losses``, each of ``--seeds``; never the first
or the last), mapped at the odometry's poses (``odom``) and with ``scan_matching``
(``matching``: the odometry predicts, the scan is matched to the map). ``--sources``: the
odometry as /odom messages (``odom``, pose_source odom) or as the odom -> base_link transforms
on /tf (``tf``, pose_source tf, the default pose source; the map -> odom transforms beside them
are never dropped, and the map is in the map frame): the same drops, the same scores.

- ``sparse``: ``office_floor`` every 0.4 m, each corner turned from one message to the next
  (the drive of ``test_node_modes.py``, played there at 40 Hz);
- ``dense``: the same path every 0.05 m, turning in place at most 0.1 rad a message (a robot at
  0.5 m/s and 1 rad/s with odometry at 10 Hz; wheel odometry is usually faster).

Scores: the largest position and heading error of the scans' poses (the session's trajectory
against the drive's), the largest distance of the map from the world's walls (samples every
2 cm, as ``test/rosnode.wall_errors``), the walls' F1 (``baselines.walls.wall_scores``) and the
contradicted share (``freespace.judge``, the session's beams). Writes the table into
benchmarks/README.md (between the ``odom-loss`` markers) and the rows to results/odom_loss.json;
the rows also count the segments more than ``FAR`` from every wall (``far_segments``), those
of them whose middle lies within the walls' bounding box (``far_inside``), and the beams that
pass through and end on each of those (``far_inside_passes``, ``far_inside_ends``).
"""

import argparse
import dataclasses
import json
from multiprocessing import Pool
import sys

from baselines.walls import wall_scores
from common import drive_truth, stamp, table_header, write_readme, write_results
import numpy as np
from polyline_mapper.core.freespace import judge
from polyline_mapper.core.geometry import sample_segments, wrap_angle
from polyline_mapper.formats.records import Odometry, Transform
from polyline_mapper.recordings import drive_messages, flat_records, make_drive
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions

DRIVES = {'sparse': 'sim:office,step=0.4', 'dense': 'sim:office,step=0.05,turn=0.1'}
"""The drives (``make_drive`` names), seed 7 as test_node_modes' office drive."""
OPTIONS = {'odom': SessionOptions(pose_source='odom', fixed_frame='odom', mount=(0.0, 0.0, 0.0),
                                  keep_points=True, grid_resolution=None),
           'tf': SessionOptions(pose_source='tf', keep_points=True, grid_resolution=None)}
"""The session's options per odometry source (``--sources``)."""
FAR = 0.15
"""Metres: a segment farther than this from every wall is counted in the row's ``far_*``."""


def odometry_of(record, source: str) -> bool:
    """Whether ``record`` is the odometry of ``source``: an /odom message or odom -> base_link."""
    if source == 'odom':
        return isinstance(record, Odometry)
    return isinstance(record, Transform) and record.child == 'base_link' and not record.static


def drive_records(label: str) -> tuple:
    """Return (drive, records) of the ``DRIVES`` entry ``label``, as every row maps it."""
    drive = make_drive(DRIVES[label], 7)
    return drive, flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0),
                                              map_to_odom=(0.0, 0.0, 0.0)))


def mapped(records: list, loss: float, seed: int, matching: bool = False,
           gap_factor: float = 1.5, source: str = 'odom') -> tuple:
    """Map ``records`` with a share ``loss`` of the odometry dropped; (session, dropped)."""
    odom = [i for i, r in enumerate(records) if odometry_of(r, source)]
    inner = odom[1:-1]
    rng = np.random.default_rng(seed)
    drop = set(rng.choice(inner, size=int(round(loss * len(inner))), replace=False).tolist())
    session = replay_records([r for i, r in enumerate(records) if i not in drop],
                             options=dataclasses.replace(OPTIONS[source], scan_matching=matching,
                                                         odom_gap_factor=gap_factor))
    return session, len(drop)


def one(drive, records: list, loss: float, seed: int, matching: bool = False,
        gap_factor: float = 1.5, source: str = 'odom') -> dict:
    """Map ``records`` with a share ``loss`` of the odometry dropped; return the scores."""
    session, dropped = mapped(records, loss, seed, matching, gap_factor, source)
    value = session.map_value()
    traj = np.asarray(value.trajectory)
    truth = drive_truth(drive, traj)
    err = np.hypot(*(traj[:, 1:3] - truth[:, :2]).T)
    turn = np.abs(wrap_angle(traj[:, 3] - truth[:, 2]))
    world = drive.world
    samples, owner = sample_segments(value.segments, 0.02)
    off = world.distance(samples)
    walls = wall_scores(value.segments, world.walls, world.distance, points=drive.points())
    verdict = judge(value.segments, session.points(), session.origins())
    # The segments more than FAR off a wall; "inside": their middle within the walls' box.
    stray = np.zeros(len(value.segments))
    np.maximum.at(stray, owner, off)
    far = np.flatnonzero(stray > FAR)
    box = np.asarray(world.walls, dtype=np.float64).reshape(-1, 2)
    middle = value.segments[far].mean(axis=1)
    inside = far[np.all((middle > box.min(axis=0)) & (middle < box.max(axis=0)), axis=1)]
    return {'scans': int(len(traj)), 'dropped': dropped,
            'pose_max_cm': round(100 * float(err.max()), 2),
            'heading_max_deg': round(float(np.degrees(turn.max())), 2),
            'stray_m': round(float(off.max()), 3),
            'f1': round(walls['f1'], 3), 'segments': int(len(value.segments)),
            'contradicted_pct': round(100 * verdict.share, 2),
            'far_segments': int(len(far)), 'far_inside': int(len(inside)),
            'far_inside_passes': verdict.passes[inside].tolist(),
            'far_inside_ends': verdict.ends[inside].tolist()}


def run(job: dict) -> dict:
    """Map one row's drive as ``job`` says (a worker of ``main``); return the row."""
    drive, records = drive_records(job['drive'])
    row = {**job, **one(drive, records, job['loss'], job['seed'], job['mode'] == 'matching',
                        job['gap_factor'], job['source'])}
    print(json.dumps(row), file=sys.stderr, flush=True)
    return row


def main() -> int:
    """Map every drive with every loss and seed; write the JSON and the README block."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--losses', type=float, nargs='+', default=[0.0, 0.05, 0.2],
                    help='shares of the odometry messages dropped (default 0 0.05 0.2)')
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2],
                    help='seeds of the messages dropped (default 0 1 2)')
    ap.add_argument('--modes', nargs='+', choices=['odom', 'matching'],
                    default=['odom', 'matching'],
                    help='map at the odometry poses, with scan matching, or both (default)')
    ap.add_argument('--gap-factors', type=float, nargs='+', default=[1.5, 0.0],
                    help="the session's odom_gap_factor, each run (default 1.5, the default, "
                         'and 0: interpolate across every gap)')
    ap.add_argument('--sources', nargs='+', choices=['odom', 'tf'], default=['odom', 'tf'],
                    help='the odometry as /odom messages (pose_source odom), as odom -> '
                         'base_link on /tf (pose_source tf), or both (default)')
    ap.add_argument('--jobs', type=int, default=1, help='rows mapped at once (default 1)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/odom_loss.py ' + ' '.join(sys.argv[1:]))
    jobs = [{'source': source, 'drive': label, 'mode': mode, 'gap_factor': gap, 'loss': loss,
             'seed': seed}
            for source in args.sources for label in DRIVES for mode in args.modes
            for gap in args.gap_factors for loss in args.losses
            for seed in (args.seeds if loss > 0 else args.seeds[:1])]
    if args.jobs > 1:
        with Pool(args.jobs) as pool:
            rows = pool.map(run, jobs, chunksize=1)
    else:
        rows = [run(job) for job in jobs]
    write_results('odom_loss', meta, rows)
    lines = table_header(meta, ['source', 'drive', 'mode', 'odom_gap_factor', 'odometry lost',
                                'seed',
                                'scans mapped',
                                'messages dropped', 'largest pose error (cm, deg)',
                                'map farthest from a wall (m)', 'walls F1', 'segments',
                                'contradicted %'])
    for r in rows:
        lines.append(f"| {r['source']} | {r['drive']} | {r['mode']} | {r['gap_factor']:g} "
                     f"| {100 * r['loss']:g} % | {r['seed']} "
                     f"| {r['scans']} "
                     f"| {r['dropped']} | {r['pose_max_cm']:.1f}, {r['heading_max_deg']:.1f} "
                     f"| {r['stray_m']:.3f} | {r['f1']:.2f} | {r['segments']} "
                     f"| {r['contradicted_pct']:.2f} |")
    write_readme('odom-loss', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
