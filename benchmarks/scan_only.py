"""
Scans alone: mapping a recording with no odometry and no TF (``replay --pose-source scan``).

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/scan_only.py [--datasets DIR] [--json FILE] [--drop-first N]

Each input is replayed as ``polyline-mapper replay INPUT --pose-source scan`` does
(``run_replay``): every scan is predicted at constant velocity from the last two matched poses
(with the robot stopped, or slowed to half the motion, as other starts: ``session.
SCAN_MOTION_SHARES``) and matched against the map built so far; the first scan is the origin
of the map frame. Inputs:

- freiburg-079 (the corrected CARMEN log: 4791 scans of 361 beams at 4.3 Hz with real
  stamps; its corrected laser poses are the reference and are not given to the mapper);
- the simulated drives of the scan-only tests (``sim:hall`` and ``sim:office``, 10 Hz, 1 m/s,
  turning in place at 1 rad/s; 1 cm noise; seed 1, as ``replay`` plays them).

Intel, CSAIL and the MIT corridor are left out: their corrected logs keep a scan every 0.7-1 m
and 20 deg (median) and have no usable stamps (made up 1 s apart), which no constant-velocity
prediction follows; with odometry they are in ``drift.py``.

``--drop-first N`` replays fr079 without its first N scans (a copy of the log, written to a
temporary folder; the drives are left out): a change of input as small as another CPU's
rounding, to see how much one run's result is luck (the replay is chaotic).

Scores, over the scans the session mapped: the trajectory against the reference (ATE after a
rigid alignment, ``core.metrics.trajectory_error``), the map against its own points and, laid
onto the reference frame by that alignment, against the true points (fr079: the log's points at
the corrected poses; the drives: the simulated points), the contradicted share of its own beams
and the update time. Writes the table into benchmarks/README.md (between the ``scan-only``
markers) and the raw numbers to benchmarks/results/scan-only.json.
"""

import argparse
import dataclasses
import gzip
import json
import pathlib
import sys
import tempfile

from common import (aligned_segments, datasets_argument, stamp, table_header, write_readme,
                    write_results)
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.core.metrics import trajectory_error
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.recordings import make_drive
from polyline_mapper.replay import run_replay
from polyline_mapper.session import SessionOptions

DRIVES = ('sim:hall,step=0.1,turn=0.1', 'sim:office,step=0.1,turn=0.1')
"""The drives of test_imperfect_poses.py's scan-only tests (here both with seed 1)."""


def drop_first(path: pathlib.Path, n: int, folder: str) -> pathlib.Path:
    """Write the CARMEN log ``path`` into ``folder`` without its first ``n`` FLASER and NEFF."""
    seen = {'FLASER': 0, 'NEFF': 0}
    out = pathlib.Path(folder) / path.name
    with gzip.open(path, 'rt') as src, gzip.open(out, 'wt') as dst:
        for line in src:
            kind = line.split(' ', 1)[0]
            if kind in seen:
                seen[kind] += 1
                if seen[kind] <= n:
                    continue
            dst.write(line)
    return out


def reference(name: str, datasets: str, drop: int = 0, folder: str = None) -> tuple:
    """
    Return (input path, stamps (S,), reference laser poses (S, 3), true points of).

    ``true points of``(scans): the true points of those scans (indices), (N, 2). ``drop``:
    the log without its first scans, written into ``folder`` (``drop_first``).
    """
    if name.startswith('sim:'):
        drive = make_drive(name)          # the drive ``replay`` plays (seed 1, 1 cm noise)
        # (every scan of a drive is mapped; were one not, its points would count too)
        return name, 1000.0 + drive.stamps, drive.poses, lambda scans: drive.points()
    path = pathlib.Path(datasets) / 'radish' / f'{name}.log.gz'
    if drop:
        path = drop_first(path, drop, folder)
    log = read_carmen(str(path))
    stamps, _ = log.stamps(1.0)

    def points_of(scans):
        return dataclasses.replace(log, records=[log.records[k] for k in scans]).points()
    return str(path), stamps, np.array([r.pose for r in log.records]), points_of


def one(name: str, datasets: str, drop: int = 0, folder: str = None) -> dict:
    """Replay ``name`` from its scans alone, ``drop`` first scans left out; return its row."""
    path, stamps, truth, points_of = reference(name, datasets, drop, folder)
    res = run_replay(path, options=SessionOptions(pose_source='scan', keep_points=True),
                     progress=True)
    value = res.map_value
    traj = np.asarray(value.trajectory)
    i = np.clip(np.searchsorted(stamps, traj[:, 0] - 1e-6), 0, len(stamps) - 1)
    err = trajectory_error(traj[:, 1:], truth[i])
    segs = value.segments
    aligned = aligned_segments(segs, err['alignment'])
    lay = map_metrics(points_of(i), aligned)        # the true points of the scans mapped
    own = map_metrics(res.points, segs)
    st = value.stats
    lost = np.setdiff1d(np.arange(len(stamps)), i)
    label = name + (f' without its first {drop} scans' if drop else '')
    return {'input': label, 'scans': len(stamps), 'mapped': len(traj),
            'first_unmapped_s': float(stamps[lost[0]]) if len(lost) else None,
            'ate_m': err['ate'], 'segments': len(segs),
            'own_mean_cm': 100 * own['mean_distance'], 'own_coverage': 100 * own['coverage_0_10m'],
            'aligned_mean_cm': 100 * lay['mean_distance'],
            'aligned_coverage': 100 * lay['coverage_0_10m'],
            'contradicted_pct': None if st.get('contradicted_share') is None
            else 100 * st['contradicted_share'],
            'update_ms_p50': st['update_ms']['p50'] if st.get('update_ms') else None,
            'matches': st.get('scan_matching')}


def main() -> int:
    """Replay every input from its scans alone; write the table and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--json', help='write the raw rows here only (README and results/ '
                    'untouched)')
    ap.add_argument('--drop-first', type=int, default=0, metavar='N',
                    help='fr079 only, without its first N scans (with --json)')
    args = ap.parse_args()
    if args.drop_first and not args.json:
        ap.error('--drop-first needs --json (its rows do not belong in the table)')
    meta = stamp('.venv/bin/python benchmarks/scan_only.py ' + ' '.join(sys.argv[1:]))
    rows = []
    names = ('freiburg-079-corrected',) + (() if args.drop_first else DRIVES)
    with tempfile.TemporaryDirectory() as folder:
        for name in names:
            print(f'{name}', file=sys.stderr, flush=True)
            rows.append(one(name, args.datasets, args.drop_first, folder))
            print(json.dumps(rows[-1]), flush=True)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1)
                                           + '\n')
        return 0
    write_results('scan-only', meta, rows)
    lines = table_header(meta, [
        'input', 'scans mapped / all', 'first scan not mapped (s)', 'ATE (m)',
        'own points: mean (cm) / coverage (%)', 'aligned, true points: mean (cm) / coverage (%)',
        'contradicted (%)', 'segments', 'update median (ms)'])
    for r in rows:
        first = '-' if r['first_unmapped_s'] is None else f"{r['first_unmapped_s']:.1f}"
        contra = '-' if r['contradicted_pct'] is None else f"{r['contradicted_pct']:.1f}"
        upd = '-' if r['update_ms_p50'] is None else f"{r['update_ms_p50']:.1f}"
        lines.append(f"| {r['input']} | {r['mapped']} / {r['scans']} | {first} | "
                     f"{r['ate_m']:.3f} | {r['own_mean_cm']:.2f} / {r['own_coverage']:.1f} | "
                     f"{r['aligned_mean_cm']:.2f} / {r['aligned_coverage']:.1f} | {contra} | "
                     f"{r['segments']} | {upd} |")
    write_readme('scan-only', '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
