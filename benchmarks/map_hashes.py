"""
Fingerprints of the maps the benchmark runs make, to show that a refactor changes no map.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/map_hashes.py -o OUT.json [--datasets DIR] [--quick]
    .venv/bin/python benchmarks/map_hashes.py --compare BEFORE.json AFTER.json

Every map is made through the command line a user runs (``polyline-mapper fit`` / ``replay``),
so the script does not depend on internal APIs that a refactor may move:

- ``fit LOG`` and ``replay LOG`` of every shared Radish log (batch and incremental);
- ``replay LOG --every 5`` of the Intel log (few, far-apart scans);
- ``replay`` of a bag converted from the Intel log (``convert``), which must equal the log's;
- ``demo --offline`` (the simulated office drive, batch).

Each map's JSON is reduced to SHA-256 hashes (first 16 hex digits) of its float64 arrays:
``segments``, ``polylines`` (vertices, with each polyline's length), ``closed`` and ``support``,
so a change to one field shows alone. Timing fields are not hashed: they differ run to run.
``--compare`` prints which maps and fields differ between two runs; exit code 1 if any.
"""

import argparse
import hashlib
import json
import os
import pathlib
import subprocess
import sys
import tempfile

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected']


def _h(array) -> str:
    return hashlib.sha256(np.ascontiguousarray(array, dtype=np.float64).tobytes()).hexdigest()[:16]


def fingerprint(data: dict) -> dict:
    """Return the hashes of a map JSON's geometric fields and its segment count."""
    polys = data.get('polylines', [])
    flat = [v for p in polys for v in p]
    return {'n_segments': len(data.get('segments', [])),
            'segments': _h(np.asarray(data.get('segments', []), dtype=float).reshape(-1)),
            'polylines': _h(np.concatenate([[len(p) for p in polys],
                                            np.asarray(flat, dtype=float).reshape(-1)])),
            'closed': _h(np.asarray(data.get('closed', []), dtype=float)),
            'support': _h(np.asarray(data.get('support', []), dtype=float))}


def cases(datasets: pathlib.Path, quick: bool) -> list:
    """Return (name, argv after ``polyline-mapper``, input to convert first or None)."""
    logs = LOGS[:2] if quick else LOGS
    if (datasets / 'radish').is_dir():      # the datasets folder, as every other script takes
        datasets = datasets / 'radish'
    out = []
    for log in logs:
        path = str(datasets / f'{log}.log.gz')
        out.append((f'fit/{log}', ['fit', path], None))
        out.append((f'replay/{log}', ['replay', path], None))
    intel = str(datasets / 'intel-corrected.log.gz')
    out.append(('replay/intel-every5', ['replay', intel, '--every', '5'], None))
    out.append(('replay/intel-bag', ['replay', '{bag}'], intel))
    out.append(('demo-offline', ['demo', '--offline'], None))
    return out


def run(args) -> int:
    """Make every map and write the fingerprints."""
    exe = str(pathlib.Path(sys.executable).parent / 'polyline-mapper')
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, argv, convert in cases(pathlib.Path(args.datasets), args.quick):
            out = os.path.join(tmp, name.replace('/', '_') + '.json')
            if convert is not None:
                bag = os.path.join(tmp, 'bag-' + name.replace('/', '_'))
                subprocess.run([exe, 'convert', convert, '-o', bag], check=True,
                               capture_output=True)
                argv = [a.replace('{bag}', bag) for a in argv]
            proc = subprocess.run([exe] + argv + ['-o', out], capture_output=True, text=True)
            if proc.returncode != 0:
                print(f'{name}: failed: {proc.stderr.strip()}', file=sys.stderr)
                return 1
            with open(out) as fh:
                result[name] = fingerprint(json.load(fh))
            print(f"{name}: {result[name]['n_segments']} segments, "
                  f"segments {result[name]['segments']}", flush=True)
    pathlib.Path(args.output).write_text(json.dumps(result, indent=1, sort_keys=True) + '\n')
    return 0


def compare(before: str, after: str) -> int:
    """Print the maps and fields that differ; return 1 if any does."""
    a, b = (json.loads(pathlib.Path(p).read_text()) for p in (before, after))
    differ = 0
    for name in sorted(set(a) | set(b)):
        if name not in a or name not in b:
            print(f'{name}: only in {"after" if name in b else "before"}')
            differ += 1
            continue
        fields = [k for k in a[name] if a[name][k] != b[name].get(k)]
        print(f'{name}: ' + ('identical' if not fields else 'differs in ' + ', '.join(fields)))
        differ += bool(fields)
    print(f'{differ} of {len(set(a) | set(b))} maps differ')
    return 1 if differ else 0


def main() -> int:
    """Parse the arguments and run or compare."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('-o', '--output', help='write the fingerprints here (JSON)')
    ap.add_argument('--datasets', default=os.environ.get(
        'POLYLINE_MAPPER_DATASETS', str(REPO.parent / 'shared' / 'datasets')),
        help='the datasets folder (its radish/ logs), as the other scripts take it; its '
             'radish/ folder itself is taken too (default: $POLYLINE_MAPPER_DATASETS, else '
             '../shared/datasets)')
    ap.add_argument('--quick', action='store_true', help='only the Intel and CSAIL logs')
    ap.add_argument('--compare', nargs=2, metavar=('BEFORE', 'AFTER'))
    args = ap.parse_args()
    if args.compare:
        return compare(*args.compare)
    if not args.output:
        ap.error('-o is required (or --compare)')
    return run(args)


if __name__ == '__main__':
    sys.exit(main())
