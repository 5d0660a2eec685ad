"""
Mapping with drifting wheel odometry: the Radish logs as a robot without a localizer sees them.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/drift.py [--datasets DIR] [--only NAME ...] [--seeds 0 1 2 3 4]
        [--modes corrected odometry matching exact-matching loops] [--set KEY=VALUE ...]
        [--drop-first N] [--json FILE | --from-json FILE ...]

For each log and seed, ``polyline-mapper convert LOG --odom-drift SEED`` writes a bag whose
/odom and /tf odom -> base_link follow the corrected poses with wheel-odometry-like drift added
(``recordings.OdometryDrift``: each step's motion with Gaussian noise, 5 % of the step per axis,
0.02 rad + 1 deg per metre of heading; the first pose true; no map frame), and
``polyline-mapper replay BAG --pose-source odom`` maps it, as given (``odometry``) and with
``--scan-matching`` (``matching``). The same log replayed with its corrected poses is the
reference (``corrected``), and so is scan matching on odometry that follows the corrected poses
exactly (``exact-matching``: ``OdometryDrift`` with every noise 0, still no map frame): what
the matching does where the odometry is perfect. ``loops`` (not run unless asked):
``replay --scan-matching --loop-closure`` on the drifted bag (offline loop closure, README
"Poses from the scans"). Scores:

- the poses the mapper used (the map's trajectory, base frame) against the corrected ones: RMS
  as they stand (both start at the first true pose) and the absolute trajectory error (ATE:
  RMS after the best rigid alignment, ``core.metrics.trajectory_error``); and the relative
  pose error (RPE, ``core.metrics.relative_error``: RMS of each motion's error over 1 and over
  10 scans, the drift per step whatever came before; less chaotic across seeds than the ATE,
  in which one early heading error dominates);
- the map against the log's true points (mean distance, coverage within 0.10 m), as it stands
  and laid onto the true frame by that alignment;
- the map against its own points (as the mapper placed them): the self-consistency a user sees;
- the update time per scan (scan conversion, matching and map update, the session's clock).

``--drop-first N`` maps each log without its first N scans (``scan_only.drop_first``: a
copy written to a temporary folder, its corrected poses the reference), a change of input as
small as another CPU's rounding, to see how much one run is luck (one replay is chaotic). The
drift is then drawn for the shorter log, so a drifted run is another odometry too; an
``exact-matching`` run is the same odometry without those scans. Needs ``--json``.

Writes the table into benchmarks/README.md (between the ``drift`` markers) and the raw numbers
to benchmarks/results/drift.json.
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile

from common import aligned_segments, datasets_argument, HERE, stamp, write_readme
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.core.metrics import relative_error, trajectory_error
from polyline_mapper.core.register import CHORD_KNOTS
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.carmen_bag import carmen_to_bag
from polyline_mapper.poses import se2_compose, se2_inverse
from polyline_mapper.recordings import OdometryDrift
from polyline_mapper.replay import run_replay
from polyline_mapper.session import SessionOptions
from scan_only import drop_first

LOGS = ['intel-corrected', 'csail-corrected', 'freiburg-079-corrected']


MODES = ('corrected', 'odometry', 'matching', 'exact-matching', 'loops')


def one(path: pathlib.Path, seed, truth: np.ndarray, log, mode: str, config=None,
        knots: str = SessionOptions.chord_knots) -> dict:
    """
    Map ``path`` in ``mode`` (drift ``seed``; None for the corrected poses); return its row.

    ``config``: the mapper's ``IncrementalConfig`` (None: the defaults); ``knots``: the
    session's ``chord_knots``.
    """
    with tempfile.TemporaryDirectory() as tmp:
        if mode == 'corrected':
            res = run_replay(str(path), config, options=SessionOptions(keep_points=True),
                             progress=True)
        else:
            bag = os.path.join(tmp, 'bag')
            exact = mode == 'exact-matching'
            carmen_to_bag(str(path), bag, drift_seed=0 if exact else seed,
                          drift_model=OdometryDrift(0.0, 0.0, 0.0) if exact else None)
            res = run_replay(bag, config, options=SessionOptions(
                pose_source='odom', keep_points=True, scan_matching=mode != 'odometry',
                chord_knots=knots),
                progress=True, loop_closure=mode == 'loops')
    segs = res.map_value.segments
    used = np.asarray(res.map_value.trajectory)[:, 1:]          # base poses, one per scan used
    mount = np.asarray(log.laser_offset, dtype=np.float64)
    true_base = se2_compose(np.array([r.pose for r in log.records]), se2_inverse(mount))
    if len(used) != len(true_base):
        raise RuntimeError(f'{len(used)} poses used for {len(true_base)} scans')
    err = trajectory_error(used, true_base)
    rpe, rpe10 = relative_error(used, true_base), relative_error(used, true_base, 10)
    aligned = aligned_segments(segs, err['alignment'])   # the map laid onto the true frame
    raw = map_metrics(truth, segs)
    lay = map_metrics(truth, aligned)
    own = map_metrics(res.points, segs)
    st = res.map_value.stats
    return {'mode': mode, 'seed': seed, 'segments': len(segs),
            'mean_cm': 100 * raw['mean_distance'], 'coverage': 100 * raw['coverage_0_10m'],
            'aligned_mean_cm': 100 * lay['mean_distance'],
            'aligned_coverage': 100 * lay['coverage_0_10m'],
            'self_mean_cm': 100 * own['mean_distance'],
            'self_coverage': 100 * own['coverage_0_10m'],
            'traj_rms_m': err['rms'], 'ate_m': err['ate'], 'traj_final_m': err['final'],
            'rpe_cm': 100 * rpe['translation'], 'rpe_deg': float(np.degrees(rpe['rotation'])),
            'rpe10_cm': 100 * rpe10['translation'],
            'update_ms_p50': st['update_ms']['p50'], 'update_ms_p95': st['update_ms']['p95'],
            'matches': st.get('scan_matching'), 'jumps': st.get('match_jumps'),
            'contradicted_pct': 100 * st['contradicted_share'],
            'contradicted_share': st.get('contradicted_share'),
            'loop_closure': st.get('loop_closure')}


def main() -> int:
    """Run the logs and seeds; write the table and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='+', choices=LOGS)
    ap.add_argument('--seeds', nargs='+', type=int, default=[0, 1, 2, 3, 4])
    ap.add_argument('--modes', nargs='+', choices=MODES, default=list(MODES[:4]))
    ap.add_argument('--json', help='write the raw rows here (default: results/drift.json, '
                    'and the README block); with --json the README is not touched')
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE',
                    help="the mapper's settings for every replay, as replay --set takes them "
                    '(e.g. free_space_window=10); each row records them')
    ap.add_argument('--chord-knots', choices=CHORD_KNOTS, default=SessionOptions.chord_knots,
                    help="the session's chord_knots (replay --chord-knots) for every replay "
                    'with scan matching (default: %(default)s)')
    ap.add_argument('--from-json', nargs='+', metavar='JSON', help='run nothing: join these '
                    'runs (e.g. two logs run side by side, each with --json) into '
                    'results/drift.json and the README block')
    ap.add_argument('--drop-first', type=int, default=0, metavar='N',
                    help='map each log without its first N scans (needs --json)')
    args = ap.parse_args()
    if args.drop_first < 0 or (args.drop_first and not args.json):
        ap.error('--drop-first takes N >= 0 and needs --json (its rows do not belong in the '
                 'table)')
    if args.from_json:
        runs = [json.loads(pathlib.Path(p).read_text()) for p in args.from_json]
        meta = dict(runs[0]['meta'], command=' ; '.join(r['meta']['command'] for r in runs),
                    date=' / '.join(r['meta']['date'] for r in runs))
        rows = [row for r in runs for row in r['rows']]
        args.only = [name for name in LOGS if any(row['log'] == name for row in rows)]
        return report(meta, rows, args.only, args.modes)
    from polyline_mapper.config import ConfigError, load_mapper_config
    try:
        config = load_mapper_config(None, args.set)
    except ConfigError as exc:
        print(f'drift.py: error: {exc}', file=sys.stderr)
        return 2
    meta = stamp('.venv/bin/python benchmarks/drift.py ' + ' '.join(sys.argv[1:]))
    rows = []
    runs = [(name, mode, seed) for name in args.only or LOGS for mode in args.modes
            for seed in ([None] if mode in ('corrected', 'exact-matching') else args.seeds)]
    logs = {}
    with tempfile.TemporaryDirectory() as folder:
        for k, (name, mode, seed) in enumerate(runs):
            print(f'[{k + 1}/{len(runs)}] {name} {mode} seed {seed}', file=sys.stderr,
                  flush=True)
            if name not in logs:
                logs.clear()
                path = pathlib.Path(args.datasets) / 'radish' / f'{name}.log.gz'
                if args.drop_first:
                    path = drop_first(path, args.drop_first, folder)
                log = read_carmen(str(path))
                logs[name] = (path, log, log.points())
            path, log, truth = logs[name]
            row = dict(one(path, seed, truth, log, mode, config, args.chord_knots), log=name,
                       set=args.set, chord_knots=args.chord_knots)
            if args.drop_first:
                row['drop_first'] = args.drop_first
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1)
                                           + '\n')
        return 0
    return report(meta, rows, args.only or LOGS, args.modes)


def report(meta: dict, rows: list, logs: list, modes: list) -> int:
    """Write results/drift.json and the README block of ``rows``."""
    out = HERE / 'results'
    out.mkdir(exist_ok=True)
    (out / 'drift.json').write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1) + '\n')
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}`.", '',
             'Drifted rows: mean (min-max) over the seeds. Map against the true points as it '
             'stands, and laid onto the true frame by the trajectory alignment (aligned); '
             '"own points": the points as the mapper placed them. ATE: RMS position error '
             'after that rigid alignment; RMS: as the poses stand (first pose true).', '',
             '| log | poses | seeds | map vs true points: mean (cm) / coverage (%) | aligned: '
             'mean (cm) / coverage (%) | own points: mean (cm) / coverage (%) | trajectory '
             'RMS (m) | ATE (m) | update median (ms) | segments |',
             '|---|---|---|---|---|---|---|---|---|---|']

    def cell(group, key, digits):
        v = [r[key] for r in group]
        if len(v) == 1:
            return f'{v[0]:.{digits}f}'
        return f'{np.mean(v):.{digits}f} ({min(v):.{digits}f}-{max(v):.{digits}f})'

    for name in logs:
        for mode in modes:
            group = [r for r in rows if r['log'] == name and r['mode'] == mode]
            if not group:
                continue
            seeds = ', '.join('-' if r['seed'] is None else str(r['seed']) for r in group)
            label = {'corrected': 'corrected', 'odometry': 'drifted odometry',
                     'matching': 'drifted odometry + scan matching',
                     'exact-matching': 'exact odometry + scan matching',
                     'loops': 'drifted odometry + scan matching + loop closure'}[mode]
            lines.append(
                f'| {name} | {label} | {seeds} | {cell(group, "mean_cm", 1)} / '
                f'{cell(group, "coverage", 1)} | {cell(group, "aligned_mean_cm", 1)} / '
                f'{cell(group, "aligned_coverage", 1)} | {cell(group, "self_mean_cm", 2)} / '
                f'{cell(group, "self_coverage", 1)} | {cell(group, "traj_rms_m", 2)} | '
                f'{cell(group, "ate_m", 3)} | {cell(group, "update_ms_p50", 1)} | '
                f'{cell(group, "segments", 0)} |')
    write_readme('drift', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
