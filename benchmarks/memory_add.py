"""
The beams' memory alone: the time of ``BeamMemory.add`` on fr079's scans, and its state's hash.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/memory_add.py [--datasets DIR] [--scans 1500] [--repeat 3]

fr079's first ``--scans`` scans are mapped with the default mapper (the ``incremental.py``
harness, corrected poses) while every call of ``BeamMemory.add`` is recorded; the calls are
then replayed into a fresh memory ``--repeat`` times and timed alone. Printed: the time per
call (each run) and a hash of the memory's cells, which a change that only makes ``add``
faster must leave as it is. Nothing is written: run it before and after a change (a worktree
of the other commit on ``PYTHONPATH``) on the same core.
"""

import argparse
import hashlib
import pathlib
import sys
import time

from common import datasets_argument
from incremental import log_scans, run_mapper
import numpy as np
from polyline_mapper.core import memory
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper


def recorded_calls(path: pathlib.Path, scans: int) -> tuple:
    """Map the first ``scans`` scans; return the memory's (cell, window, cap) and its calls."""
    calls, made = [], []
    add = memory.BeamMemory.add

    def recording(self, origin, points, tol, range_tol=0.03):
        if not made:
            made.append((self.cell, self.window, self.cap))
        calls.append((np.array(origin, dtype=float), np.array(points, dtype=float), tol,
                      range_tol))
        return add(self, origin, points, tol, range_tol)

    memory.BeamMemory.add = recording
    try:
        run_mapper(log_scans(path)[0][:scans], IncrementalMapper(IncrementalConfig()))
    finally:
        memory.BeamMemory.add = add
    return made[0], calls


def main() -> int:
    """Record the calls once, replay them ``--repeat`` times; print ms per call and the hash."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--scans', type=int, default=1500)
    ap.add_argument('--repeat', type=int, default=3)
    args = ap.parse_args()
    path = pathlib.Path(args.datasets) / 'radish' / 'freiburg-079-corrected.log.gz'
    if not path.is_file():
        print(f'memory_add.py: error: {path} not found', file=sys.stderr)
        return 2
    (cell, window, cap), calls = recorded_calls(path, args.scans)
    for k in range(max(1, args.repeat)):
        mem = memory.BeamMemory(cell, window, cap)
        t0 = time.perf_counter()
        for call in calls:
            mem.add(*call)
        ms = 1e3 * (time.perf_counter() - t0) / len(calls)
        state = (mem._pool[:mem._used * memory.CHUNK ** 2].tobytes() + mem._keys.tobytes()
                 + mem._slot.tobytes())
        print(f'run {k + 1}: {len(calls)} calls, {ms:.3f} ms per call, {mem.cells} cells, '
              f'state {hashlib.sha1(state).hexdigest()[:12]}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
