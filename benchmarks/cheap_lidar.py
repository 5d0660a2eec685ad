"""
A TurtleBot3-class lidar: scan matching with range-proportional noise, and the chords' knot bias.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/cheap_lidar.py [--seeds 1 2 3] [--trials 200]
    .venv/bin/python benchmarks/cheap_lidar.py --sigma 0.025 [--noise-seeds 1 2 3 4 5]

Cheap lidars (an LDS-01 on a TurtleBot3, an RPLidar A1) err by a share of the range, not by a
constant. The simulated drives here have such a laser: 360 beams over the full circle, 5 Hz,
the beams taken over the scan time (a spinning sensor), 0.12-3.5 m, 1 % dropouts, range noise
1.5 cm plus 1 % of the range (as a new-user audit with a simulated TurtleBot3 bag measured it,
2026-11-29). The robot drives at 0.2 m/s and turns at 1 rad/s through the office (its first 12
waypoints, 38 m) and round a 10 m corridor loop (2 m wide), the laser on the base, with true
odometry and with ``OdometryDrift`` seeds (issue 19's model), mapped through the session
(``replay_records``) without ``scan_matching`` and with it, its ``chord_knots`` 'arc' (the
default before 2026-11-30) and 'median' (the default since). Scores per run: RMS of the base
position and heading against the truth as the poses stand, ATE, the map against the true
points (mean distance, coverage within 0.10 m) and the walls' F1 as the map stands and after
the trajectory's alignment.

The second table isolates what turns the matched poses: ``register.match_scan`` of a scan
against the chords (``register.scan_chords``) of another scan taken at the same pose in a
straight 2 m corridor (walls 40 m long, so only the heading and the across-axis are
constrained), with the prediction exact, ``--trials`` times; the mean heading of the result,
with the beams in the laser's counter-clockwise order and reversed, and against the true walls
as a control, for each ``chord_knots`` rule. A bias that flips sign with the beam order comes
from the chords, not the matcher.

Writes both tables into benchmarks/README.md (between the ``cheap-lidar`` markers) and the rows
to results/cheap_lidar.json.

``--sigma S`` instead maps both drives with true odometry, one range-noise seed after another
(``--noise-seeds``), with the noise scale estimated from the scans (the default) and fixed at
S (``smemsf.sigma``), without scan matching and with it ('median' knots): the mapper's sigma,
the segments, how many are shorter than 0.5 m, the map against the true points and the walls'
F1 (block ``cheap-lidar-sigma``, results/cheap_lidar_sigma.json). With the noise growing with
the range, the estimate follows the near points, which are the many.
"""

import argparse
import dataclasses
import json
import sys

from baselines.walls import wall_scores
from common import (aligned_segments, drive_truth, stamp, table_header, write_readme,
                    write_results)
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.core.metrics import trajectory_error
from polyline_mapper.core.register import match_scan, scan_chords, spread
from polyline_mapper.recordings import drive_messages, flat_records
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions
from polyline_mapper.sim import LaserSpec
from polyline_mapper.sim.laser import simulate_drive
from polyline_mapper.sim.world import corridor_loop, office_floor

RATE = 5.0
"""Scans a second (an LDS-01 turns at 5 Hz)."""
SPEED, TURN_RATE = 0.2, 1.0
"""m/s and rad/s of the drives."""
NOISE, NOISE_SHARE = 0.015, 0.01
"""Range noise: metres, plus this share of the range."""
SPEC = LaserSpec(beams=360, fov=2 * np.pi, range_min=0.12, range_max=3.5, noise=NOISE,
                 dropout=0.01)


def world(name: str):
    """Return the office (its first 12 waypoints) or the 10 m corridor loop."""
    if name == 'office':
        w = office_floor()
        w.path = w.path[:12]
        return w
    return corridor_loop(width=2.0, side=10.0)


def make(name: str, seed: int = 1):
    """Return the drive through ``name`` with the cheap lidar (range noise seeded ``seed``)."""
    drive = simulate_drive(world(name), SPEC, step=SPEED / RATE, rate=RATE, rng=seed,
                           turn=TURN_RATE / RATE, scan_time=1.0 / RATE)
    rng = np.random.default_rng(1000 + seed)
    ranges = drive.ranges.copy()
    ok = np.isfinite(ranges)
    ranges[ok] += rng.normal(size=int(ok.sum())) * NOISE_SHARE * ranges[ok]
    drive.ranges = ranges
    return drive


def one(drive, drift, matching: bool, knots: str = 'arc', sigma: float = None) -> dict:
    """
    Map ``drive`` with drift seed ``drift`` (None: true odometry); return its scores.

    ``sigma`` (m): the mapper's noise scale fixed (``smemsf.sigma``); None: estimated.
    """
    records = flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odom_drift=drift))
    config = IncrementalConfig()
    if sigma is not None:
        config = dataclasses.replace(config, smemsf=dataclasses.replace(config.smemsf,
                                                                        sigma=sigma))
    session = replay_records(records, config, options=SessionOptions(
        pose_source='tf', scan_matching=matching, keep_points=True, chord_knots=knots))
    value = session.map_value()
    traj = np.asarray(value.trajectory)
    truth = drive_truth(drive, traj)
    err = np.hypot(*(traj[:, 1:3] - truth[:, :2]).T)
    yaw = np.angle(np.exp(1j * (traj[:, 3] - truth[:, 2])))
    te = trajectory_error(traj[:, 1:], truth)
    segs = np.asarray(value.segments, dtype=np.float64)
    moved = aligned_segments(segs, te['alignment'])
    pts = drive.points()
    w = drive.world
    raw = map_metrics(pts, segs)
    return {'drift_seed': drift, 'matching': matching, 'chord_knots': knots,
            'scans': int(len(traj)),
            'rms_m': round(float(np.sqrt(np.mean(err ** 2))), 4),
            'ate_m': round(float(te['ate']), 4),
            'yaw_rms_deg': round(float(np.degrees(np.sqrt(np.mean(yaw ** 2)))), 3),
            'yaw_end_deg': round(float(np.degrees(yaw[-1])), 3),
            'mean_cm': round(100 * raw['mean_distance'], 2),
            'coverage': round(100 * raw['coverage_0_10m'], 1),
            'f1': round(wall_scores(segs, w.walls, w.distance, points=pts)['f1'], 3),
            'f1_aligned': round(wall_scores(moved, w.walls, w.distance, points=pts)['f1'], 3),
            'segments': int(len(segs)),
            'short': int(np.count_nonzero(np.hypot(*(segs[:, 1] - segs[:, 0]).T) < 0.5)),
            'sigma_m': round(float(session.mapper.sigma), 4)}


def corridor_scan(rng, share: float) -> np.ndarray:
    """One scan of the cheap lidar between walls at y = +-1 m, from the origin: (N, 2)."""
    ang = SPEC.angles()
    s = np.abs(np.sin(ang))
    with np.errstate(divide='ignore'):
        r = np.where(s > 1e-9, 1.0 / s, np.inf)
    r = np.where(r < SPEC.range_max, r, np.nan)
    r = r + rng.normal(size=r.shape) * (NOISE + share * np.nan_to_num(r))
    ok = np.isfinite(r) & (r < SPEC.range_max)
    return np.column_stack([r * np.cos(ang), r * np.sin(ang)])[ok]


def knot_bias(trials: int, share: float, reverse: bool, knots: str = 'arc') -> dict:
    """Mean heading (deg) of ``match_scan`` against another scan's chords and the true walls."""
    rng = np.random.default_rng(0)
    walls = np.array([[[-20.0, 1.0], [20.0, 1.0]], [[-20.0, -1.0], [20.0, -1.0]]])
    chords, true = [], []
    for _ in range(trials):
        a, b = (spread(corridor_scan(rng, share), 240) for _ in range(2))
        if reverse:
            a, b = a[::-1], b[::-1]
        chords.append(match_scan(b, np.zeros(3), scan_chords(a, knots=knots), 0.02).pose[2])
        true.append(match_scan(b, np.zeros(3), walls, 0.02).pose[2])
    chords, true = np.degrees(chords), np.degrees(true)
    return {'noise_share': share, 'reversed': reverse, 'trials': trials, 'chord_knots': knots,
            'chords_deg': round(float(chords.mean()), 4),
            'chords_se_deg': round(float(chords.std() / np.sqrt(trials)), 4),
            'walls_deg': round(float(true.mean()), 4),
            'walls_se_deg': round(float(true.std() / np.sqrt(trials)), 4)}


def main() -> int:
    """Map both drives, measure the knot bias; write the JSON and the README block."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3], help='drift seeds')
    ap.add_argument('--trials', type=int, default=200, help='matches per knot-bias row')
    ap.add_argument('--sigma', type=float, default=None,
                    help='instead: true odometry, the noise scale estimated and fixed at this')
    ap.add_argument('--noise-seeds', type=int, nargs='+', default=[1, 2, 3, 4, 5],
                    help='range-noise seeds of the drives (with --sigma)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/cheap_lidar.py ' + ' '.join(sys.argv[1:]))
    if args.sigma is not None:
        return sigma_sweep(meta, args.sigma, args.noise_seeds)
    rows, bias = [], []
    for name in ('office', 'corridors'):
        drive = make(name)
        runs = [(d, m, k) for d in [None] + list(args.seeds)
                for m, k in ((False, 'arc'), (True, 'arc'), (True, 'median'))]
        for drift, matching, knots in runs:
            rows.append(dict(one(drive, drift, matching, knots), world=name))
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    for knots in ('arc', 'median'):
        for share in (NOISE_SHARE, 0.0):
            for reverse in (False, True):
                bias.append(knot_bias(args.trials, share, reverse, knots))
                print(json.dumps(bias[-1]), file=sys.stderr, flush=True)
    write_results('cheap_lidar', meta, rows + bias)
    lines = table_header(meta, ['drive', 'odometry', 'scan matching (chord knots)',
                                'RMS / ATE (m)',
                                'heading RMS / at the end (deg)', 'map vs true points: mean '
                                '(cm) / coverage (%)', 'walls F1 (aligned)', 'segments'])
    for r in rows:
        odom = 'true' if r['drift_seed'] is None else f"drift seed {r['drift_seed']}"
        match = f"on ({r['chord_knots']})" if r['matching'] else 'off'
        lines.append(f"| {r['world']} | {odom} | {match} | "
                     f"{r['rms_m']:.3f} / {r['ate_m']:.3f} | {r['yaw_rms_deg']:.2f} / "
                     f"{r['yaw_end_deg']:+.2f} | {r['mean_cm']:.2f} / {r['coverage']:.1f} | "
                     f"{r['f1']:.2f} ({r['f1_aligned']:.2f}) | {r['segments']} |")
    lines += ['', '| chord knots | range noise | beams | mean heading of a match against the '
              "other scan's chords (deg, +- se) | against the true walls (deg, +- se) |",
              '|---|---|---|---|---|']
    for b in bias:
        lines.append(f"| {b['chord_knots']} | {NOISE * 100:g} cm + {b['noise_share'] * 100:g} "
                     '% of range | '
                     f"{'reversed' if b['reversed'] else 'counter-clockwise'} | "
                     f"{b['chords_deg']:+.3f} +- {b['chords_se_deg']:.3f} | "
                     f"{b['walls_deg']:+.3f} +- {b['walls_se_deg']:.3f} |")
    write_readme('cheap-lidar', '\n'.join(lines) + '\n')
    return 0


def sigma_sweep(meta: dict, sigma: float, seeds: list) -> int:
    """``--sigma``: true odometry, the noise scale estimated and fixed; write the block."""
    rows = []
    for name in ('office', 'corridors'):
        for seed in seeds:
            drive = make(name, seed)
            for matching in (False, True):
                for fixed in (None, sigma):
                    rows.append(dict(one(drive, None, matching, 'median' if matching else
                                         'arc', fixed), world=name, noise_seed=seed,
                                     sigma_fixed=fixed))
                    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    write_results('cheap_lidar_sigma', meta, rows)
    lines = table_header(meta, ['drive', 'range-noise seed', 'scan matching', 'sigma (m)',
                                'segments (shorter than 0.5 m)', 'RMS (m)',
                                'map vs true points: mean (cm) / coverage (%)', 'walls F1'])
    for r in rows:
        how = 'estimated' if r['sigma_fixed'] is None else 'fixed'
        lines.append(f"| {r['world']} | {r['noise_seed']} | "
                     f"{'on (median)' if r['matching'] else 'off'} | {how} {r['sigma_m']:.4f} | "
                     f"{r['segments']} ({r['short']}) | {r['rms_m']:.3f} | "
                     f"{r['mean_cm']:.2f} / {r['coverage']:.1f} | {r['f1']:.2f} |")
    write_readme('cheap-lidar-sigma', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
