"""
A person walking ahead of the robot: the transient chords' hold, and the chord length.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/walker_chords.py [--seeds 1 2 3 4 5 6 7 8] [--chord-knots arc]
        [--recent-scans 6]

The simulated dynamic office of ``walker_ahead.py`` (true poses, scan matching, the session as
``test_imperfect_poses`` drives it), every seed mapped with the chords of the last scans
(``register.scan_chords``, which the session matches each scan to beside G(t)) varied:

- ``length``: the chords' length, 0.14, 0.15 (the session's) or 0.16 m. A defence tuned on
  one seed set at one length is a coincidence if the next centimetre undoes it;
- ``min extent``: ``register.CHORD_MIN_EXTENT`` (chords along free-standing runs narrower
  than this are ``transient``: a weak direction they carry is held, ``TRANSIENT_SHARE``) or
  0 (no chord is transient: the session before the hold).

The two are set by replacing the session's ``scan_chords`` and ``CHORD_MIN_EXTENT`` for the
run; nothing else changes. Mapper settings: ``off`` (the free-space evidence off, as scan
matching runs by default) and ``evidence`` (the evidence per square alone), as the tests.
One row per setting, extent and length: the median, mean and largest RMS position error over
the seeds, how many of them keep the walls F1 >= 0.95, and the lowest F1. Writes the table
into benchmarks/README.md (between the ``walker-chords`` markers) and the rows to
results/walker_chords.json with ``--chord-knots arc --recent-scans 6`` (the session's defaults
before 2026-11-30); with the defaults (median knots, ``session.RECENT_SCANS`` recent scans)
between the ``walker-chords-median`` markers and to results/walker_chords_median.json. Other
combinations print their rows and write neither.
"""

import argparse
import functools
import json
import sys

from common import stamp, table_header, write_readme, write_results
import numpy as np
import polyline_mapper.core.register as register
from polyline_mapper.recordings import make_drive
import polyline_mapper.session as session
from tqdm import tqdm
from walker_ahead import one, SETTINGS

LENGTHS = (0.14, 0.15, 0.16)
"""Chord lengths (m) tried; the session's is ``scan_chords``'s default, 0.15."""


def main() -> int:
    """Map every seed at every chord length and extent; write the JSON and the README block."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--seeds', type=int, nargs='+', default=list(range(1, 9)),
                    help='drive seeds (default 1-8, the tests)')
    ap.add_argument('--chord-knots', choices=register.CHORD_KNOTS, default='median',
                    help="the session's chord_knots (default: the session's default, median; "
                    'arc writes the walker-chords block)')
    ap.add_argument('--recent-scans', type=int, default=session.RECENT_SCANS,
                    help='keyframes whose chords each scan is matched to beside the map '
                    f'(session.RECENT_SCANS, default {session.RECENT_SCANS}; 6 with arc writes '
                    'the walker-chords block)')
    args = ap.parse_args()
    if args.recent_scans < 1:
        ap.error(f'--recent-scans must be >= 1, got {args.recent_scans}')
    name = {('arc', 6): 'walker_chords', ('median', session.RECENT_SCANS): 'walker_chords_median'
            }.get((args.chord_knots, args.recent_scans))
    meta = stamp('.venv/bin/python benchmarks/walker_chords.py ' + ' '.join(sys.argv[1:]))
    drives = {seed: make_drive('sim:office_dynamic', seed) for seed in args.seeds}
    extents = (register.CHORD_MIN_EXTENT, 0.0)
    jobs = [(setting, extent, length) for setting in ('off', 'evidence') for extent in extents
            for length in LENGTHS]
    chords, extent0, recent0 = session.scan_chords, session.CHORD_MIN_EXTENT, session.RECENT_SCANS
    session.RECENT_SCANS = args.recent_scans
    rows = []
    bar = tqdm(total=len(jobs) * len(drives), unit='drive', file=sys.stderr)
    try:
        for setting, extent, length in jobs:
            session.scan_chords = functools.partial(register.scan_chords, length=length)
            session.CHORD_MIN_EXTENT = extent
            runs = []
            for seed, drive in drives.items():
                runs.append(one(drive, SETTINGS[setting], args.chord_knots))
                bar.update()
            rms = np.array([r['rms_m'] for r in runs])
            f1 = np.array([r['f1'] for r in runs])
            rows.append({'setting': setting, 'min_extent': extent, 'length': length,
                         'chord_knots': args.chord_knots, 'recent_scans': args.recent_scans,
                         'seeds': list(drives), 'rms_m': rms.tolist(), 'f1': f1.tolist(),
                         'median_m': round(float(np.median(rms)), 4),
                         'mean_m': round(float(rms.mean()), 4),
                         'max_m': round(float(rms.max()), 3),
                         'walls_095': int((f1 >= 0.95).sum()), 'f1_min': float(f1.min())})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    finally:
        session.scan_chords, session.CHORD_MIN_EXTENT = chords, extent0
        session.RECENT_SCANS = recent0
        bar.close()
    if name is None:
        print(f'{args.chord_knots} knots with {args.recent_scans} recent scans: no README block '
              'or results file is of this combination; the rows are above', file=sys.stderr)
        return 0
    write_results(name, meta, rows)
    lines = table_header(meta, ['setting', 'min extent (m)', 'chord length (m)',
                                'RMS median / mean / largest (m)',
                                f'drives with walls F1 >= 0.95 (of {len(drives)})',
                                'lowest F1'])
    for r in rows:
        lines.append(f"| {r['setting']} | {r['min_extent']:.2f} | {r['length']:.2f} "
                     f"| {r['median_m']:.3f} / {r['mean_m']:.3f} / {r['max_m']:.3f} "
                     f"| {r['walls_095']} | {r['f1_min']:.2f} |")
    write_readme(name.replace('_', '-'), '\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
