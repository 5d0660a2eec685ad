"""
Batch SMEMSF on the shared Radish logs and the simulated worlds.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/batch.py [--datasets DIR] [--only NAME ...] [--sweep]

Writes the results table into benchmarks/README.md (between the ``batch`` markers), the raw
numbers to benchmarks/results/batch.json and one PNG per dataset to benchmarks/results/ (and
one of the beams with the contradicted segments in red, ``batch-free-space-NAME.png``). Each map
is judged both ways: distance of the points to it, and the share of its length that the beams
pass through (``polyline_mapper.core.freespace``; origins from the CARMEN records' laser poses
and the simulated drives' poses). With
--sweep it also fits the Intel log at several noise floors and plots mean distance against
segment count.
"""

import argparse
import json
import pathlib
import sys
import time

from common import datasets_argument, stamp, write_readme
from polyline_mapper.core import fit, map_metrics, SMEMSFConfig
from polyline_mapper.core.freespace import judge
from polyline_mapper.plot import plot_free_space, plot_map
from polyline_mapper.recordings import drive_beams, read_beams
from polyline_mapper.sim import hall_with_arc, LaserSpec, office_floor, simulate_drive

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected']


def datasets(folder: pathlib.Path, only: list):
    """Yield (name, points, origins, truth walls or None) for every dataset available."""
    sims = {'sim-office': (office_floor, 0.01), 'sim-hall-arc': (hall_with_arc, 0.02)}
    for name, (world_fn, noise) in sims.items():
        if only and name not in only:
            continue
        world = world_fn()
        drive = simulate_drive(world, LaserSpec(noise=noise), step=0.25, rng=1)
        yield (name, *drive_beams(drive), world.walls)
    for name in LOGS:
        if only and name not in only:
            continue
        path = folder / 'radish' / f'{name}.log.gz'
        if not path.is_file():
            print(f'skip {name}: {path} not found', file=sys.stderr)
            continue
        points, origins, _ = read_beams(str(path))
        yield name, points, origins, None


def free_space_row(name: str, points, origins, segments, out_png) -> dict:
    """Judge a map against the beams; return the row's free-space numbers, draw the PNG."""
    v = judge(segments, points, origins)
    share = 100 * v.share
    plot_free_space(str(out_png), points, origins, segments, v.contradicted,
                    title=f'{name}: {len(segments)} segments, {share:.1f}% of map length '
                          f'contradicted ({int(v.contradicted.sum())} segments)')
    return {'contradicted_pct': share, 'contradicted_segments': int(v.contradicted.sum()),
            'beams': v.beams}


def run_one(name, points, origins, truth, out_dir: pathlib.Path,
            config: SMEMSFConfig) -> dict:
    """Fit one dataset; return its row of numbers and write its PNGs."""
    t0 = time.perf_counter()
    res = fit(points, config)
    seconds = time.perf_counter() - t0
    m = map_metrics(points, res.segments)
    row = {'dataset': name, 'points': m['points'], 'segments': m['segments'],
           'polylines': len(res.polylines), 'iterations': res.iterations,
           'converged': res.converged, 'mean_cm': 100 * m['mean_distance'],
           'p95_cm': 100 * m['p95_distance'], 'coverage_pct': 100 * m['coverage_0_10m'],
           'compression': m['compression'], 'sigma_cm': 100 * res.sigma,
           'seconds': seconds}
    row.update(free_space_row(name, points, origins, res.segments,
                              out_dir / f'batch-free-space-{name}.png'))
    plot_map(str(out_dir / f'batch-{name}.png'), points, res.segments, res.polylines,
             title=f'{name}: {m["segments"]} segments, mean {row["mean_cm"]:.2f} cm, '
                   f'coverage {row["coverage_pct"]:.1f}%', truth=truth)
    print(f'{name:30s} {m["points"]:8d} pts {m["segments"]:5d} segs {res.iterations:2d} it '
          f'mean {row["mean_cm"]:.2f} cm cov {row["coverage_pct"]:.1f}% contradicted '
          f'{row["contradicted_pct"]:.1f}% ({row["contradicted_segments"]}) {seconds:6.1f} s',
          flush=True)
    return row


def sweep(points, out_dir: pathlib.Path) -> list:
    """Fit the Intel log at several noise floors; plot mean distance against segments."""
    rows = []
    for sigma in (0.015, 0.02, 0.03, 0.04, 0.05, 0.07):
        res = fit(points, SMEMSFConfig(sigma=sigma))
        m = map_metrics(points, res.segments)
        rows.append({'sigma_cm': 100 * sigma, 'segments': m['segments'],
                     'mean_cm': 100 * m['mean_distance'],
                     'coverage_pct': 100 * m['coverage_0_10m']})
        print(f'  sweep sigma {sigma:.3f}: {rows[-1]}', flush=True)
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot([r['segments'] for r in rows], [r['mean_cm'] for r in rows], 'o-')
    for r in rows:
        ax.annotate(f"sigma {r['sigma_cm']:.1f} cm", (r['segments'], r['mean_cm']), fontsize=7,
                    xytext=(4, 4), textcoords='offset points')
    ax.set_xlabel('segments')
    ax.set_ylabel('mean point-to-map distance [cm]')
    ax.set_title('Intel lab: accuracy against map size (noise floor sweep)')
    ax.grid(True, alpha=0.4)
    fig.tight_layout()
    fig.savefig(out_dir / 'batch-intel-sweep.png', dpi=130)
    plt.close(fig)
    return rows


def table(rows: list) -> str:
    """Format rows as a Markdown table."""
    head = ('| dataset | points | segments | polylines | iterations | mean (cm) | p95 (cm) | '
            'coverage 0.10 m | contradicted (segments) | compression | sigma (cm) | '
            'time (s) |\n'
            '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n')
    body = ''.join(
        f"| {r['dataset']} | {r['points']} | {r['segments']} | {r['polylines']} | "
        f"{r['iterations']}{'' if r['converged'] else ' (cap)'} | {r['mean_cm']:.2f} | "
        f"{r['p95_cm']:.2f} | {r['coverage_pct']:.1f}% | "
        f"{r['contradicted_pct']:.1f}% ({r['contradicted_segments']}) | {r['compression']:.0f} | "
        f"{r['sigma_cm']:.2f} | {r['seconds']:.1f} |\n" for r in rows)
    return head + body


def main(argv=None) -> int:
    """Run the benchmark; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='*', default=[], help='dataset names to run')
    ap.add_argument('--sweep', action='store_true', help='also sweep the Intel noise floor')
    ap.add_argument('--no-readme', action='store_true', help='do not rewrite README.md')
    args = ap.parse_args(argv)
    out_dir = HERE / 'results'
    out_dir.mkdir(exist_ok=True)
    config = SMEMSFConfig()
    rows, intel = [], None
    for name, points, origins, truth in datasets(pathlib.Path(args.datasets), args.only):
        rows.append(run_one(name, points, origins, truth, out_dir, config))
        if name == 'intel-corrected':
            intel = points
    sweep_rows = sweep(intel, out_dir) if args.sweep and intel is not None else []
    command = 'python benchmarks/batch.py ' + ' '.join(argv if argv is not None else sys.argv[1:])
    meta = stamp(command)
    (out_dir / 'batch.json').write_text(json.dumps({'meta': meta, 'rows': rows,
                                                    'sweep': sweep_rows}, indent=1))
    block = (f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}, with "
             f"`{meta['command']}` (default SMEMSFConfig; time is the fit alone, one process, "
             f'no other load). "contradicted": share of map length that >= 5 beams pass '
             'through, more than end on it (`core/freespace.py`; beams of every scan).\n\n'
             + table(rows))
    if sweep_rows:
        block += ('\nNoise-floor sweep on the Intel log (`--sweep`, plot '
                  '`results/batch-intel-sweep.png`):\n\n| sigma (cm) | segments | mean (cm) | '
                  'coverage |\n|---:|---:|---:|---:|\n' + ''.join(
                      f"| {r['sigma_cm']:.1f} | {r['segments']} | {r['mean_cm']:.2f} | "
                      f"{r['coverage_pct']:.1f}% |\n" for r in sweep_rows))
    if not args.no_readme:
        write_readme('batch', block)
    print(block)
    return 0


if __name__ == '__main__':
    sys.exit(main())
