"""
Lidars whose range noise grows with the range: one noise scale against ``smemsf.range_noise``.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/range_noise.py [--seeds 1 2 3]

Two simulated lidars with range noise 1.5 cm plus 1 % of the range (as new-user audits measured
a TurtleBot3 LDS-01 and an RPLidar-class bag, 2026-11-29), spinning (beams taken over the scan
time), 1 % dropouts:

- ``lds01``: 360 beams over the full circle, 0.12-3.5 m, 5 Hz (``cheap_lidar.py``'s);
- ``rplidar``: 720 beams over the full circle, 0.15-12 m, 7.5 Hz.

Each drives through the office (its first 12 waypoints) and round a 10 m corridor loop (2 m
wide) at 0.2 m/s, turning at 1 rad/s, once per range-noise seed (``LaserSpec.noise_share``), and
is mapped through the session (``replay_records``) with its true poses (TF), four ways: the
noise scale estimated (the default), fixed at 2.5 cm (``config/lds01.yaml``), fixed at 5 cm, and
estimated with ``range_noise`` 0.01 (each point's noise scale hypot(sigma, 0.01 x its range)).
The rplidar drives are also mapped with scan matching from drifting odometry
(``OdometryDrift`` seed = the noise seed), estimated against range_noise, with the chords'
knots 'arc' (the default before 2026-11-30) and 'median' (the default since). Scores,
both ways: segments (shorter than 0.5 m), the map against the true points (mean distance,
coverage within 0.10 m), the share of the map's length its own beams contradict
(``free_space_stats``), and the walls' F1
(``baselines.walls.wall_scores``); with scan matching also the trajectory's RMS.

Writes the table into benchmarks/README.md (between the ``range-noise`` markers) and the rows to
results/range_noise.json.
"""

import argparse
import dataclasses
import json
import sys

from baselines.walls import wall_scores
from cheap_lidar import world
from common import contradicted, drive_truth, stamp, table_header, write_readme, write_results
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.recordings import drive_messages, flat_records
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions
from polyline_mapper.sim import LaserSpec
from polyline_mapper.sim.laser import simulate_drive

SPEED, TURN_RATE = 0.2, 1.0
"""m/s and rad/s of the drives."""
NOISE, NOISE_SHARE = 0.015, 0.01
"""Range noise: metres, plus this share of the range."""
LIDARS = {
    'lds01': (LaserSpec(beams=360, fov=2 * np.pi, range_min=0.12, range_max=3.5, noise=NOISE,
                        noise_share=NOISE_SHARE, dropout=0.01), 5.0),
    'rplidar': (LaserSpec(beams=720, fov=2 * np.pi, range_min=0.15, range_max=12.0,
                          noise=NOISE, noise_share=NOISE_SHARE, dropout=0.01), 7.5),
}
"""Name: (laser, scans a second)."""
SETTINGS = (('estimated', None, 0.0), ('fixed 2.5 cm', 0.025, 0.0), ('fixed 5 cm', 0.05, 0.0),
            ('range_noise 0.01', None, NOISE_SHARE))
"""Label, smemsf.sigma (None: estimated), smemsf.range_noise."""


def make(lidar: str, name: str, seed: int):
    """Return the drive of ``lidar`` through world ``name`` (range noise seeded ``seed``)."""
    spec, rate = LIDARS[lidar]
    return simulate_drive(world(name), spec, step=SPEED / rate, rate=rate, rng=seed,
                          turn=TURN_RATE / rate, scan_time=1.0 / rate)


def one(drive, sigma, range_noise: float, drift=None, knots: str = 'arc') -> dict:
    """Map ``drive`` (true poses, or scan matching from odometry drift seed ``drift``)."""
    config = IncrementalConfig()
    config = dataclasses.replace(config, smemsf=dataclasses.replace(
        config.smemsf, sigma=sigma, range_noise=range_noise))
    matching = drift is not None
    records = flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odom_drift=drift))
    session = replay_records(records, config, options=SessionOptions(
        pose_source='tf', scan_matching=matching, keep_points=True, chord_knots=knots))
    value = session.map_value()
    segs = np.asarray(value.segments, dtype=np.float64).reshape(-1, 2, 2)
    pts, w = drive.points(), drive.world
    raw = map_metrics(pts, segs)
    row = {'matching': matching, 'drift_seed': drift, 'chord_knots': knots,
           'sigma_m': round(float(
               session.mapper.sigma), 4), 'range_noise': range_noise,
           'segments': int(len(segs)),
           'short': int(np.count_nonzero(np.hypot(*(segs[:, 1] - segs[:, 0]).T) < 0.5)),
           'mean_cm': round(100 * raw['mean_distance'], 2),
           'coverage': round(100 * raw['coverage_0_10m'], 1),
           'contradicted': round(contradicted(segs, session.points(),
                                              session.origins())['contradicted_pct'], 2),
           'f1': round(wall_scores(segs, w.walls, w.distance, points=pts)['f1'], 3)}
    if matching:
        traj = np.asarray(value.trajectory)
        err = np.hypot(*(traj[:, 1:3] - drive_truth(drive, traj)[:, :2]).T)
        row['rms_m'] = round(float(np.sqrt(np.mean(err ** 2))), 4)
    return row


def main() -> int:
    """Map every drive every way; write the JSON and the README block."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3],
                    help='range-noise seeds of the drives (and drift seeds with matching)')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/range_noise.py ' + ' '.join(sys.argv[1:]))
    rows = []
    for lidar in LIDARS:
        for name in ('office', 'corridors'):
            for seed in args.seeds:
                drive = make(lidar, name, seed)
                runs = [(label, sigma, k, None, 'arc') for label, sigma, k in SETTINGS]
                if lidar == 'rplidar':
                    runs += [(label, None, k, seed, knots) for knots in ('arc', 'median')
                             for label, k in (('estimated', 0.0),
                                              ('range_noise 0.01', NOISE_SHARE))]
                for label, sigma, k, drift, knots in runs:
                    rows.append(dict(one(drive, sigma, k, drift, knots), lidar=lidar,
                                     world=name, noise_seed=seed, setting=label))
                    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    write_results('range_noise', meta, rows)
    lines = table_header(meta, ['lidar', 'drive', 'poses', 'noise scale', 'segments (< 0.5 m)',
                                'map vs true points: mean (cm) / coverage (%)',
                                'contradicted (% of length)', 'walls F1', 'trajectory RMS (m)'])
    for lidar in LIDARS:
        for name in ('office', 'corridors'):
            for matching, knots in ((False, 'arc'), (True, 'arc'), (True, 'median')):
                for label, _, _ in SETTINGS:
                    mine = [r for r in rows if r['lidar'] == lidar and r['world'] == name
                            and r['setting'] == label and r['matching'] == matching
                            and r['chord_knots'] == knots]
                    if not mine:
                        continue
                    lines.append(_line(lidar, name, knots if matching else None, label, mine))
    write_readme('range-noise', '\n'.join(lines) + '\n')
    return 0


def _line(lidar: str, name: str, knots, label: str, rows: list) -> str:
    """Return one table row: the means over the noise seeds (F1: and its range)."""
    def mean(key):
        return float(np.mean([r[key] for r in rows]))
    f1 = [r['f1'] for r in rows]
    rms = '-' if knots is None else f"{mean('rms_m'):.3f}"
    poses = 'true' if knots is None else f'odometry drift, scan matching ({knots} knots)'
    return (f'| {lidar} | {name} | {poses} | {label} | {mean("segments"):.1f} '
            f'({mean("short"):.1f}) | {mean("mean_cm"):.2f} / {mean("coverage"):.1f} | '
            f'{mean("contradicted"):.2f} | {np.mean(f1):.2f} ({min(f1):.2f}-{max(f1):.2f}) | '
            f'{rms} |')


if __name__ == '__main__':
    sys.exit(main())
