"""Helpers shared by the benchmark scripts: machine description, commit, README blocks."""

import argparse
import datetime
import json
import os
import pathlib
import platform
import subprocess
import sys

import numpy as np
from polyline_mapper.core.freespace import judge
from polyline_mapper.core.register import transform
from polyline_mapper.recordings import make_drive, OdometryDrift, SIM_START

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
CONTRADICTED_NOTE = ('"contradicted": share of map length (and number of segments) that >= 5 '
                     'laser beams pass through, more than end on it (`core/freespace.py`)')
"""How the contradicted columns are measured, for a block's header line."""
NOTABLE_PCT = 2.0
"""Contradicted share (%) of map length above which a map is listed under its table."""


def machine() -> str:
    """Describe the machine: CPU model, cores, memory, Python and numpy versions."""
    cpu = platform.processor() or platform.machine()
    try:
        with open('/proc/cpuinfo') as fh:
            for line in fh:
                if line.startswith('model name'):
                    cpu = line.split(':', 1)[1].strip()
                    break
    except OSError:
        pass
    mem = ''
    try:
        with open('/proc/meminfo') as fh:
            kb = int(fh.readline().split()[1])
            mem = f', {kb / 2 ** 20:.0f} GiB'
    except (OSError, ValueError, IndexError):
        pass
    import scipy
    return (f'{cpu}, {os.cpu_count()} cores{mem}; Python {platform.python_version()}, '
            f'numpy {np.__version__}, scipy {scipy.__version__}')


OUTPUTS = ('benchmarks/results', 'benchmarks/README.md', 'benchmarks/results.md', 'README.md')
"""What the benchmarks write: changes there do not make a measured tree dirty."""


def git_rev() -> str:
    """
    Return the short commit hash of the working tree, with -dirty when its code is modified.

    Changes to the benchmarks' own outputs (``OUTPUTS``, written by an earlier benchmark of the
    same run) do not count: the measured code is still the commit.
    """
    try:
        rev = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=REPO,
                             capture_output=True, text=True, check=True).stdout.strip()
        changed = subprocess.run(
            ['git', 'status', '--porcelain', '--untracked-files=no', '--', '.']
            + [f':(exclude){p}' for p in OUTPUTS],
            cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'
    return rev + ('-dirty' if changed else '')


def stamp(command: str) -> dict:
    """Return the date, machine, commit and command of a measurement."""
    return {'date': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
            'machine': machine(), 'commit': git_rev(), 'command': command.strip()}


def write_readme(name: str, block: str) -> None:
    """Replace the text between the ``name`` markers of benchmarks/README.md."""
    path = HERE / 'README.md'
    begin, end = f'<!-- {name}:begin -->', f'<!-- {name}:end -->'
    text = path.read_text() if path.exists() else f'# Benchmarks\n\n{begin}\n{end}\n'
    if begin not in text:
        text += f'\n{begin}\n{end}\n'
    pre, rest = text.split(begin, 1)
    _, post = rest.split(end, 1)
    path.write_text(f'{pre}{begin}\n{block}{end}{post}')


def publish(block: str, result: str, meta: dict, rows: list, lines: list,
            quick: bool) -> None:
    """
    Write a run: results/``result``.json and the README block ``block``, from ``lines``.

    ``quick`` (a partial run): print the lines and write nothing.
    """
    if quick:
        print('\n'.join(lines))
        return
    (HERE / 'results' / f'{result}.json').write_text(
        json.dumps({'meta': meta, 'rows': rows}, indent=1) + '\n')
    write_readme(block, '\n'.join(lines) + '\n')


def datasets_argument(parser) -> None:
    """Add ``--datasets`` (default: $POLYLINE_MAPPER_DATASETS, else ../shared/datasets)."""
    parser.add_argument('--datasets', default=os.environ.get(
        'POLYLINE_MAPPER_DATASETS', str(REPO.parent / 'shared' / 'datasets')))


def radish_logs(datasets: str, names, only=None):
    """Yield (name, path) of the Radish logs ``names`` (``only`` those) found under datasets."""
    for name in names:
        if only and name not in only:
            continue
        path = pathlib.Path(datasets) / 'radish' / f'{name}.log.gz'
        if not path.is_file():
            import sys
            print(f'skip {name}: {path} not found', file=sys.stderr)
            continue
        yield name, path


def write_results(name: str, meta: dict, rows: list) -> None:
    """Write ``{'meta', 'rows'}`` to results/``name``.json."""
    out = HERE / 'results'
    out.mkdir(exist_ok=True)
    (out / f'{name}.json').write_text(json.dumps({'meta': meta, 'rows': rows}, indent=1) + '\n')


def table_header(meta: dict, columns: list) -> list:
    """Return a README block's first lines: how it was measured, then a table's header."""
    return [f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
            f"`{meta['command']}`.", '', '| ' + ' | '.join(columns) + ' |',
            '|' + '---|' * len(columns)]


def drive_truth(drive, trajectory) -> np.ndarray:
    """
    Return a simulated drive's true poses (R, 3) at the rows of a replay's ``trajectory``.

    The rows are stamped as ``drive_messages`` stamps the scans (``SIM_START`` + the drive's
    stamps); each takes the pose of the scan it is.
    """
    stamps = np.asarray(trajectory)[:, 0]
    return drive.poses[np.searchsorted(SIM_START + np.asarray(drive.stamps), stamps - 1e-6)]


def aligned_segments(segments, alignment) -> np.ndarray:
    """
    Return ``segments`` (K, 2, 2) moved by a rigid ``alignment`` (x, y, yaw).

    With ``core.metrics.trajectory_error``'s ``alignment``: the map laid onto the true frame by
    the motion that aligns its trajectory (the ATE's), ``register.transform`` of every end.
    """
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 2)
    return transform(segs, alignment).reshape(-1, 2, 2)


def contradicted(segments, points, origins) -> dict:
    """
    Judge a map against the beams it was built from: ``freespace.judge``'s verdict as columns.

    ``segments`` (K, 2, 2), ``points`` (N, 2) beam ends, ``origins`` (N, 2) or (2,) laser
    positions, metres. Returns ``contradicted_pct`` (share of map length, %) and
    ``contradicted_segments``.
    """
    verdict = judge(segments, points, origins)
    return {'contradicted_pct': 100 * verdict.share,
            'contradicted_segments': int(verdict.contradicted.sum())}


def notable_lines(maps) -> list:
    """
    Return a line per map contradicted by more than ``NOTABLE_PCT`` % of its length.

    ``maps``: (label, contradicted_pct, contradicted_segments) triples.
    """
    return [f"- {label}: {pct:.1f} % of map length contradicted ({n} segment{'s' * (n != 1)})."
            for label, pct, n in maps if pct is not None and pct > NOTABLE_PCT]


def load_note(start) -> str:
    """
    Say how loaded the machine was: 5-minute load averages at start (``os.getloadavg()``) and now.

    A 5-minute load above 1.5 (this job counts for one) means other jobs shared the cores: the
    note says so.
    """
    end = os.getloadavg()
    cores = os.cpu_count() or 1
    note = f'load average (5 min) {start[1]:.1f} at start, {end[1]:.1f} at end, {cores} cores'
    if max(start[1], end[1]) > 1.5:
        note += ': other jobs shared the machine, times are slower than it runs alone'
    return note


def case_run(doc: str, script: str) -> tuple:
    """
    Parse the command line of a case-table benchmark; return (args, meta).

    ``--quick``: the first three cases only, printed (``publish`` writes nothing). ``doc``: the
    script's docstring (its first paragraph is the description); ``script``: its file name.
    """
    ap = argparse.ArgumentParser(description=doc.split('\n\n')[0].strip())
    ap.add_argument('--quick', action='store_true',
                    help='the first three cases only, printed (nothing written)')
    args = ap.parse_args()
    return args, stamp(f'.venv/bin/python benchmarks/{script} ' + ' '.join(sys.argv[1:]))


def drifting_drive(drives: dict, spec: str) -> tuple:
    """
    Return (drive, odometry) of ``make_drive(spec, 1)``, kept in ``drives`` for the next case.

    ``odometry``: the drive's poses with ``recordings.OdometryDrift`` seed 1 (at its stamps).
    """
    if spec not in drives:              # (setdefault would simulate the drive every case)
        drives[spec] = make_drive(spec, 1)
    drive = drives[spec]
    return drive, OdometryDrift().apply(np.asarray(drive.poses, dtype=np.float64), 1,
                                        stamps=drive.stamps)
