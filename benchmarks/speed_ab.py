"""
The update's speed against an older commit, on this machine, in the same minutes.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/speed_ab.py --ref 282231e [--scans 2000] [--runs 2] \
        [--datasets DIR] [--cpu 0]

The virtual machines these benchmarks run on differ in speed by 2x and more, and one machine's
speed drifts within minutes, so an update median measured on another day says little about
the code. This script checks out ``--ref`` into a temporary git worktree and maps the first
``--scans`` scans of the corrected fr079 log with the default ``IncrementalMapper`` (the
``incremental.py`` harness: every scan in order through ``update_scan``, each call timed),
alternating the reference tree and this one ``--runs`` times, each run in a fresh process
(pinned to core ``--cpu`` when given). It prints one line per run and writes the runs to
benchmarks/results/speed_ab.json with the machine, date and command; the README block of
``incremental.py`` is not touched.

The child only uses what every commit since the incremental mapper has
(``IncrementalMapper.update_scan``, ``formats.carmen.read_carmen``), so ``--ref`` may be any
such commit. The final segment count is printed next to each median: runs of the same tree
always give the same map, and two trees with the same count most likely map alike.
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

from common import datasets_argument, REPO, stamp, write_results
import numpy as np

LOG = 'freiburg-079-corrected'

CHILD = r"""
import json, sys, time
tree, path, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
sys.path.insert(0, tree)
import numpy as np
import polyline_mapper
assert polyline_mapper.__file__.startswith(tree), polyline_mapper.__file__
from polyline_mapper.core.incremental import IncrementalMapper
from polyline_mapper.formats.carmen import read_carmen
log = read_carmen(path)
mapper, times = IncrementalMapper(), []
for rec in log.records[:n]:
    t0 = time.perf_counter()
    info = mapper.update_scan(rec.ranges, rec.angles, rec.pose, 0.0, log.usable_range(rec))
    dt = time.perf_counter() - t0
    if info.skipped is None:
        times.append(1000.0 * dt)
print(json.dumps({'median_ms': float(np.median(times)), 'p90_ms': float(np.percentile(times, 90)),
                  'updates': len(times), 'segments': len(mapper.segments)}))
"""


def run_child(tree: str, path: str, scans: int, cpu) -> dict:
    """Map the log's first ``scans`` scans with the code of ``tree``; return its line."""
    cmd = [sys.executable, '-c', CHILD, tree, path, str(scans)]
    if cpu is not None:
        cmd = ['taskset', '-c', str(cpu)] + cmd
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f'speed_ab.py: the run of {tree} failed: '
                         f'{out.stderr.strip().splitlines()[-1:]}')
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    """Parse the arguments, run both trees alternately, print and write the runs."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    datasets_argument(ap)
    ap.add_argument('--ref', required=True, help='the commit to compare against')
    ap.add_argument('--scans', type=int, default=2000, help='first scans of fr079 to map')
    ap.add_argument('--runs', type=int, default=2, help='runs of each tree, alternating')
    ap.add_argument('--cpu', type=int, default=None, help='pin every run to this core')
    args = ap.parse_args()
    path = pathlib.Path(args.datasets) / 'radish' / f'{LOG}.log.gz'
    if not path.is_file():
        print(f'speed_ab.py: {path} not found (--datasets)', file=sys.stderr)
        return 2
    try:
        ref = subprocess.run(['git', 'rev-parse', '--short', args.ref], cwd=REPO, check=True,
                             capture_output=True, text=True).stdout.strip()
    except subprocess.CalledProcessError:
        print(f'speed_ab.py: {args.ref!r} is not a commit of this repository', file=sys.stderr)
        return 2
    meta = stamp('python benchmarks/speed_ab.py ' + ' '.join(sys.argv[1:]))
    meta.update(ref=ref, scans=args.scans, log=LOG, load_start=list(os.getloadavg()))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = os.path.join(tmp, 'ref')
        subprocess.run(['git', 'worktree', 'add', '--detach', '-q', work, ref], cwd=REPO,
                       check=True)
        try:
            for run in range(args.runs):
                for name, tree in ((ref, work), (meta['commit'], str(REPO))):
                    row = dict(run_child(tree, str(path), args.scans, args.cpu), tree=name,
                               run=run)
                    rows.append(row)
                    print(f"run {run + 1}/{args.runs} {name:>16}: median {row['median_ms']:.2f} "
                          f"ms, p90 {row['p90_ms']:.2f} ms, {row['segments']} segments",
                          flush=True)
        finally:
            subprocess.run(['git', 'worktree', 'remove', '--force', work], cwd=REPO)
    meta['load_end'] = list(os.getloadavg())
    for name in (ref, meta['commit']):
        med = [r['median_ms'] for r in rows if r['tree'] == name]
        print(f'{name}: run medians {", ".join(f"{m:.2f}" for m in med)} ms '
              f'(median {np.median(med):.2f})')
    write_results('speed_ab', meta, rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
