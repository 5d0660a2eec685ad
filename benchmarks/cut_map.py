"""
A saved map that lacks part of the area, and a laser blocked there: finding the map again.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/cut_map.py [--cuts 10 12 14] [--seeds 0 1] [--quick]

``sim:office`` is mapped with true poses and the map cut at x = ``--cuts`` metres (the segments
with both ends at or below it kept): the drive spends scans 145-255 beyond x = 14 m, carried
there by the chords of the scans before (README "Localization on a saved map"). The same drive,
with drifting odometry (issue 19's model, ``drive_messages(odom_drift=seed)``, noise seed
``seed``), is localized on the cut map (``mapping: false``) with 15 of its scans (1.5 s) read
0.4 m on every beam (the laser covered) from scan 150, 170, ..., 230, and without any block.

Per window: how many scans after the block the first is matched, the largest error of a
matched scan from then on (a wrong place taken shows here), the error at the end, the RMS over
the whole drive, and the ``not_localized`` warnings. ``RECKONED_SEARCH`` (session.py) says
what the session does; review R's window (cut at 14 m, blocked from scan 190, seed 1) is never
found again (benchmarks/README.md says why, and what was tried).

Writes the table into benchmarks/README.md (between the ``cut-map`` markers) and the rows to
results/cut_map.json (not with ``--quick``: cut 14 m, seed 1, blocked from scan 190 only,
printed).
"""

import argparse
import dataclasses
import json
import sys

from blocked_laser import blocked_scans, drifted_office, office_on_true_poses
from common import publish, stamp
from covariance import localize
import numpy as np

BLOCK = 15
RING = 0.4


def cut_map(value, x: float):
    """Return the map ``value`` with only the segments whose both ends lie at x <= ``x``."""
    keep = (value.segments[:, :, 0] <= x).all(axis=1)
    return dataclasses.replace(value, segments=value.segments[keep],
                               support=value.support[keep], polylines=[], closed=[])


def window(records, saved, truth, start) -> dict:
    """Localize ``records`` on ``saved``, scans [start, start + BLOCK) blocked (None: none)."""
    blocked = records if start is None else blocked_scans(records, start, BLOCK, RING)
    warned = []
    stamps, poses, _, matched = localize(blocked, saved,
                                         warn=lambda cause, text: warned.append(cause))
    index = np.searchsorted(truth[0], stamps - 1e-6)
    dist = np.hypot(*(poses[:, :2] - truth[1][index, :2]).T)
    end = 0 if start is None else start + BLOCK
    after = np.flatnonzero(matched & (index >= end))
    return {'start': start, 'scans': int(len(stamps)), 'matched': int(matched.sum()),
            'found_after': int(index[after[0]] - end) if len(after) else None,
            'matched_max_m': float(dist[after].max()) if len(after) else None,
            'end_m': float(dist[-1]), 'rms_m': float(np.sqrt(np.mean(dist ** 2))),
            'not_localized': warned.count('not_localized')}


def main() -> int:
    """Run the windows; write the table and the raw rows."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    ap.add_argument('--cuts', type=float, nargs='+', default=[10.0, 12.0, 14.0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1])
    ap.add_argument('--quick', action='store_true', help='cut 14 m, seed 1, scan 190, printed')
    args = ap.parse_args()
    meta = stamp('.venv/bin/python benchmarks/cut_map.py ' + ' '.join(sys.argv[1:]))
    cuts, seeds = ([14.0], [1]) if args.quick else (args.cuts, args.seeds)
    starts = [190] if args.quick else [None, 150, 170, 190, 210, 230]
    full, base = office_on_true_poses()
    rows = []
    for seed in seeds:
        records, truth = drifted_office(seed, base)
        for x in cuts:
            saved = cut_map(full, x)
            for start in starts:
                r = {'cut_m': x, 'seed': seed, **window(records, saved, truth, start)}
                rows.append(r)
                print(json.dumps(r), file=sys.stderr, flush=True)
    lines = [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}`.", '',
             '| cut at x (m) | seed | blocked from scan | matched / scans | found after (scans) '
             '| largest error of a matched scan from then on (m) | error at the end (m) | '
             'RMS (m) | not_localized |', '|---:|---:|---:|---|---:|---:|---:|---:|---:|']
    for r in rows:
        found = '-' if r['found_after'] is None else r['found_after']
        worst = '-' if r['matched_max_m'] is None else f"{r['matched_max_m']:.3f}"
        lines.append(f"| {r['cut_m']:g} | {r['seed']} | "
                     f"{'none' if r['start'] is None else r['start']} | "
                     f"{r['matched']} / {r['scans']} | {found} | {worst} | {r['end_m']:.3f} | "
                     f"{r['rms_m']:.3f} | {r['not_localized']} |")
    publish('cut-map', 'cut_map', meta, rows, lines, args.quick)
    return 0


if __name__ == '__main__':
    sys.exit(main())
