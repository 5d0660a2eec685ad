"""
The incremental mapper's bridges between table legs on the cluttered room (drives.py's defect).

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/clutter_bridges.py [--drives 5] [--noise 0.05] [--json FILE]

``drives.py`` found ours-incremental contradicted on the cluttered room at 5 cm noise (drive 3:
4.1 %, segments from table leg to table leg across the 0.42 m gap between them). For each drive
(``compare.sim_dataset``, seeds 1..N) this maps the scans with the incremental mapper with the
free-space evidence off (``config/no_free_space.yaml``, the defaults before 2026-11-27: the
rows keep the name ``defaults``) and with the evidence of window 10, 20000 ghosts and hit
margin 0.03 without the beams' memory (``free_space.yaml`` before the memory), and reports per
drive the contradicted share of the published map against the drive's own beams
(``freespace.judge``), its contradicted segments, and the map's mean distance and coverage
against the points. With ``--trace K`` it also prints, for drive K with the evidence off, every
scan after which the map's segments near the contradicted ones change:
when a bridge forms, when the new scan's beams clear it, and when it forms again.
"""

import argparse
import json
import sys

from common import stamp
import compare
import numpy as np
from polyline_mapper.core import map_metrics
from polyline_mapper.core.freespace import judge
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper

PRESET = {'free_space_window': 10, 'free_space_ghosts': 20000, 'free_space_hit_margin': 0.03,
          'free_space_memory': 0.0}
"""config/free_space.yaml's evidence before the memory, as IncrementalConfig fields."""
OFF = {'free_space_window': 0}
"""The evidence off (config/no_free_space.yaml), the defaults before 2026-11-27."""


def run_drive(ds: dict, options: dict, watch: np.ndarray = None) -> tuple:
    """Map one drive; return its row and, with ``watch`` (M, 2) points, the trace near them."""
    mapper = IncrementalMapper(IncrementalConfig(**options))
    trace, last = [], None
    for k, scan in enumerate(ds['scans']):
        mapper.update_scan(*scan)
        if watch is not None:
            segs = mapper.segments
            mid = segs.mean(axis=1)
            near = np.min(np.hypot(*(mid[:, None] - watch[None]).transpose(2, 0, 1)), axis=1)
            now = np.round(segs[near < 0.3], 2).tolist()
            if now != last:
                trace.append({'scan': k, 'pose': np.round(scan[2], 2).tolist(), 'near': now})
                last = now
    segs = mapper.polylines().segments
    free = judge(segs, ds['points'], ds['origins'])
    m = map_metrics(ds['points'], segs)
    return {'segments': len(segs), 'contradicted_pct': 100 * free.share,
            'contradicted': np.round(segs[free.contradicted], 3).tolist(),
            'mean_cm': 100 * m['mean_distance'], 'coverage_pct': 100 * m['coverage_0_10m']}, trace


def main(argv=None) -> int:
    """Run the drives, print the table (and trace), write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--drives', type=int, default=5)
    ap.add_argument('--noise', type=float, default=0.05)
    ap.add_argument('--trace', type=int, default=3, help='drive to trace (0: none)')
    ap.add_argument('--json', default=None)
    args = ap.parse_args(argv)
    out = {'stamp': stamp(' '.join(['.venv/bin/python', 'benchmarks/clutter_bridges.py']
                                   + (argv if argv is not None else sys.argv[1:]))),
           'rows': [], 'trace': []}
    print(f'{out["stamp"]["date"]}, {out["stamp"]["machine"]}, commit {out["stamp"]["commit"]}')
    print('| drive | config | contradicted | segments contradicted | mean (cm) | coverage (%) |')
    print('| --- | --- | --- | --- | --- | --- |')
    for d in range(1, args.drives + 1):
        ds = compare.sim_dataset('clutter', args.noise, seed=d)
        for name, options in (('defaults', OFF), ('free_space.yaml', PRESET)):
            row, _ = run_drive(ds, options)
            if name == 'defaults' and d == args.trace and row['contradicted']:
                watch = np.array(row['contradicted']).mean(axis=1)
                _, out['trace'] = run_drive(ds, options, watch)
            row.update(drive=d, config=name)
            out['rows'].append(row)
            print(f'| {d} | {name} | {row["contradicted_pct"]:.2f} % | '
                  f'{len(row["contradicted"])} of {row["segments"]} | {row["mean_cm"]:.2f} | '
                  f'{row["coverage_pct"]:.1f} |')
    for step in out['trace']:
        print(f'scan {step["scan"]} at {step["pose"]}: {step["near"]}')
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
