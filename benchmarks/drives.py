"""
Wall F1 over several simulated drives: claim 2 of compare.py, beyond one noise draw.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/drives.py [--drives N] [--noises 0.005,0.02,0.05] [--no-readme]

``compare.py`` scores each simulated world on one drive (seed 1). A wall map has few segments
(the corridors have 8 walls), so one stray segment moves precision by 10 %: a single drive says
little about which method finds walls best. This script drives every simulated world of
``compare.py`` N times (laser noise and dropouts seeded 1..N, the same path), runs every method
of ``compare.METHODS`` at its main setting on each drive, and reports mean and range of wall
precision, recall and F1 per world and noise level, and the share of each map's length that
its drive's beams contradict (``freespace.judge`` through ``compare.score``: >= 5 beams pass
through, more than end on it; every scan's beams, from the simulated laser pose). Writes the
tables into benchmarks/README.md (between the ``drives`` markers) and the numbers into
benchmarks/results/drives.json.
"""

import argparse
import json
import sys
import time

from common import CONTRADICTED_NOTE, HERE, NOTABLE_PCT, stamp, write_readme
import compare
import numpy as np

try:
    from tqdm import tqdm
except ImportError:  # pragma: no cover - tqdm is in tools/requirements.txt
    def tqdm(x, **_):
        return x


def run(worlds: list, noises: list, drives: int, cap: float, missing: set) -> list:
    """One row per world, noise, drive and method (main settings), with the wall metrics."""
    methods = [m for m in compare.METHODS if compare.NEEDS.get(m) not in missing]
    jobs = [(w, nz, d) for w in worlds for nz in noises for d in range(1, drives + 1)]
    rows = []
    for w, nz, d in tqdm(jobs, desc='drives', unit='drive'):
        ds = compare.sim_dataset(w, nz, seed=d)
        k_ours = None
        for m in methods:
            out = compare.run_method(m, compare.METHODS[m]['main'], ds, k_ours or 1, cap)
            row = compare.score(ds, out)
            if m == 'ours-batch':
                k_ours = row['segments']
            rows.append({'world': w, 'noise': nz, 'drive': d, 'method': m,
                         'segments': row['segments'], 'mean_cm': row['mean_cm'],
                         'precision': row['precision'], 'recall': row['recall'],
                         'f1': row['f1'], 'seconds': row['seconds'],
                         'contradicted_pct': row['contradicted_pct'],
                         'contradicted_segments': row['contradicted_segments']})
    return rows


def summary(rows: list) -> tuple:
    """Markdown table (mean F1 [min-max] per method) and the claim's verdict lines."""
    methods = list(dict.fromkeys(r['method'] for r in rows))
    cases = list(dict.fromkeys((r['world'], r['noise']) for r in rows))
    head = ('| world | noise | ' + ' | '.join(methods) + ' |\n|---|---:|'
            + '---:|' * len(methods) + '\n')
    body, verdicts, held = '', [], 0
    for w, nz in cases:
        f1 = {m: np.array([r['f1'] for r in rows if r['world'] == w and r['noise'] == nz
                           and r['method'] == m]) for m in methods}
        body += (f'| {w} | {100 * nz:g} cm | '
                 + ' | '.join(f'{v.mean():.3f} [{v.min():.2f}-{v.max():.2f}]' for v in f1.values())
                 + ' |\n')
        others = {m: v.mean() for m, v in f1.items() if not m.startswith('ours')}
        best = max(others, key=others.get)
        ours = f1['ours-batch'].mean()
        ok = ours >= others[best]
        held += ok
        verdicts.append(f'- {w} {100 * nz:g} cm: ours-batch {ours:.3f}, ours-incremental '
                        f"{f1['ours-incremental'].mean():.3f}; best other {best} "
                        f'{others[best]:.3f} -> ' + ('holds' if ok else '**does not hold**'))
    return head + body, verdicts, held, len(cases)


def contradicted_summary(rows: list) -> tuple:
    """
    Markdown table of the contradicted share per world, noise and method, and notes.

    Cells: mean share of map length over the drives [highest] (mean contradicted segments).
    A note for every world, noise and method with a map above ``NOTABLE_PCT`` %.
    """
    methods = list(dict.fromkeys(r['method'] for r in rows))
    cases = list(dict.fromkeys((r['world'], r['noise']) for r in rows))
    head = ('| world | noise | ' + ' | '.join(methods) + ' |\n|---|---:|'
            + '---:|' * len(methods) + '\n')
    body, notes = '', []
    for w, nz in cases:
        cells = []
        for m in methods:
            sel = [r for r in rows if r['world'] == w and r['noise'] == nz and r['method'] == m]
            pct = np.array([r['contradicted_pct'] for r in sel])
            segs = np.array([r['contradicted_segments'] for r in sel])
            cells.append(f'{pct.mean():.1f}% [{pct.max():.1f}] ({segs.mean():.1f})')
            high = [r['drive'] for r in sel if r['contradicted_pct'] > NOTABLE_PCT]
            if high:
                notes.append(f'- {w} {100 * nz:g} cm, {m}: above {NOTABLE_PCT:g} % on drive'
                             f"{'s' if len(high) > 1 else ''} {', '.join(map(str, high))} "
                             f'(highest {pct.max():.1f} %, {segs.max()} segments).')
        body += f'| {w} | {100 * nz:g} cm | ' + ' | '.join(cells) + ' |\n'
    return head + body, notes


def main(argv=None) -> int:
    """Run the drives; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--drives', type=int, default=5, help='drives (seeds 1..N) per world')
    ap.add_argument('--noises', default=','.join(str(n) for n in compare.NOISES),
                    help='laser range noise levels (m), comma-separated')
    ap.add_argument('--cap', type=float, default=300.0,
                    help='time cap (s) of one global baseline run')
    ap.add_argument('--no-readme', action='store_true', help='do not rewrite README.md')
    args = ap.parse_args(argv)
    if args.drives < 1:
        ap.error('--drives must be at least 1')
    try:
        noises = [float(v) for v in args.noises.split(',')]
    except ValueError:
        ap.error(f'--noises: not a comma-separated list of numbers: {args.noises!r}')
    command = ('.venv/bin/python benchmarks/drives.py '
               + ' '.join(argv if argv is not None else sys.argv[1:])).strip()
    meta = stamp(command)
    missing = compare.missing_modules()
    t0 = time.perf_counter()
    rows = run(list(compare.sim_worlds()), noises, args.drives, args.cap, missing)
    meta['seconds'] = time.perf_counter() - t0
    table, verdicts, held, n = summary(rows)
    free_table, free_notes = contradicted_summary(rows)
    out = HERE / 'results'
    out.mkdir(exist_ok=True)
    (out / 'drives.json').write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1))
    block = (f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}, with "
             f"`{meta['command']}` ({meta['seconds'] / 60:.0f} min; "
             + (f"n/a: {', '.join(sorted(missing))} not installed; " if missing else '')
             + f'{args.drives} drives per world and noise level, every method at its main '
             'setting). Wall F1: mean over the drives [lowest-highest].\n\n' + table
             + f'\nHighest mean wall F1 (ours-batch against every other method; ties count): '
             f'holds on {held} of {n}.\n\n' + '\n'.join(verdicts) + '\n\n'
             f'Contradicted share of map length: {CONTRADICTED_NOTE}; beams of every scan of '
             'the drive, from the simulated laser pose to its points. Cells: mean over the '
             'drives [highest] (mean contradicted segments).\n\n' + free_table
             + ('\n' + f'Maps contradicted on more than {NOTABLE_PCT:g} % of their length:\n\n'
                + '\n'.join(free_notes) + '\n' if free_notes else
                f'\nNo map contradicted on more than {NOTABLE_PCT:g} % of its length.\n'))
    print(block)
    if not args.no_readme:
        write_readme('drives', block)
    return 0


if __name__ == '__main__':
    sys.exit(main())
