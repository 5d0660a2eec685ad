"""
Incremental SMEMSF: quality against batch, update time, map-size independence, memory.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/incremental.py [--datasets DIR] [--quick]

Writes its tables into benchmarks/README.md (between the ``incremental`` markers), raw numbers
to benchmarks/results/incremental.json and plots to benchmarks/results/:
update time against map size, and update-time histograms.

- Quality: every scan of a log (or simulated drive) is fed to IncrementalMapper in order; the
  final map is compared with the batch fit of all the same points (mean distance, segment count,
  coverage, share of segments with a near-parallel overlapping twin closer than 0.1 m). The
  Intel log is also mapped from every 5th scan only (few, far-apart views, a known limit of the
  incremental mapper), against batch on those scans' points. Both maps are also judged against
  the beams of every scan mapped (``freespace.judge``: share of map length that >= 5 beams pass
  through, more than end on it); a beam runs from the scan's pose (the log's corrected pose, the
  simulated laser pose) to its point.
- Speed: the wall-clock time of each ``update_scan`` call (conversion to points included), on
  simulated 360- and 720-beam scans (full circle, 12 m, 1 cm noise) through the office floor,
  and on the real logs.
- Map size: the map is pre-loaded with N segments of synthetic corridor loops far from the
  drive (100 ... 5000), then the same office drive is mapped; median update time against N.
  ``--quality-only`` runs the quality table alone (no map-size curve, no memory run).
- Memory: resident set size after the first 500 scans of the fr079 log and after all of them.
"""

import argparse
import dataclasses
import json
import os
import pathlib
import sys
import time

from common import (contradicted, CONTRADICTED_NOTE, datasets_argument, HERE, load_note,
                    notable_lines, stamp, write_readme)
import numpy as np
from polyline_mapper.core import fit, map_metrics, SMEMSFConfig
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.core.metrics import twin_fraction
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.recordings import drive_beams
from polyline_mapper.sim import LaserSpec, office_floor, simulate_drive


def rss_bytes() -> int:
    """Resident set size of this process (Linux /proc), bytes."""
    with open('/proc/self/statm') as fh:
        return int(fh.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')


def run_mapper(scans, mapper=None, on_scan=None):
    """Feed (ranges, angles, pose, rmin, rmax) scans; return the mapper and times (ms)."""
    mapper = mapper or IncrementalMapper()
    times = []
    for i, (ranges, angles, pose, rmin, rmax) in enumerate(scans):
        t0 = time.perf_counter()
        info = mapper.update_scan(ranges, angles, pose, rmin, rmax)
        dt = time.perf_counter() - t0
        if info.skipped is None:
            times.append(1000.0 * dt)
        if on_scan is not None:
            on_scan(i, mapper)
    return mapper, np.array(times)


def sim_scans(beams: int, rng: int = 1):
    """Simulate an office drive with a full-circle laser of ``beams`` beams: scans, beams."""
    spec = LaserSpec(beams=beams, fov=2 * np.pi, range_max=12.0, noise=0.01, dropout=0.01)
    drive = simulate_drive(office_floor(), spec, step=0.25, rng=rng)
    angles = spec.angles()
    scans = [(r, angles, p, spec.range_min, spec.range_max)
             for r, p in zip(drive.ranges, drive.poses)]
    return (scans, *drive_beams(drive))


def log_scans(path: pathlib.Path, every: int = 1):
    """
    Read every ``every``-th scan of a CARMEN log (no-return code applied): scans, beams.

    Returns the scans, their points (N, 2) and each point's laser position (N, 2), metres.
    """
    log = read_carmen(str(path))
    log = dataclasses.replace(log, records=log.records[::every])
    scans = [(rec.ranges, rec.angles, rec.pose, 0.0, log.usable_range(rec))
             for rec in log.records]
    return (scans, *log.beams())


def quality_row(name, scans, points, origins, repeat: int = 1) -> dict:
    """
    Incremental vs batch on the same points, and both maps against the same beams.

    The scans are mapped ``repeat`` times (the map is the same every time); the update times
    reported are those of the run with the median median, and the range of the runs' medians
    is kept, because this machine's speed drifts by up to 2x within minutes.
    """
    runs = [run_mapper(scans) for _ in range(max(1, int(repeat)))]
    medians = [float(np.median(t)) for _, t in runs]
    mapper, times = runs[int(np.argsort(medians)[len(medians) // 2])]
    inc_segs = mapper.polylines().segments
    t0 = time.perf_counter()
    batch = fit(points)
    batch_s = time.perf_counter() - t0
    mi, mb = map_metrics(points, inc_segs), map_metrics(points, batch.segments)
    ci = contradicted(inc_segs, points, origins)
    cb = contradicted(batch.segments, points, origins)
    row = {'dataset': name, 'scans': len(scans), 'beams': int(len(scans[0][0])),
           'points': mi['points'],
           'inc_segments': mi['segments'], 'batch_segments': mb['segments'],
           'inc_mean_cm': 100 * mi['mean_distance'], 'batch_mean_cm': 100 * mb['mean_distance'],
           'inc_coverage': 100 * mi['coverage_0_10m'],
           'batch_coverage': 100 * mb['coverage_0_10m'],
           'inc_twins_pct': 100 * twin_fraction(inc_segs),
           'batch_twins_pct': 100 * twin_fraction(batch.segments),
           'inc_contradicted_pct': ci['contradicted_pct'],
           'inc_contradicted_segments': ci['contradicted_segments'],
           'batch_contradicted_pct': cb['contradicted_pct'],
           'batch_contradicted_segments': cb['contradicted_segments'],
           'median_ms': float(np.median(times)), 'p99_ms': float(np.percentile(times, 99)),
           'max_ms': float(times.max()), 'batch_s': batch_s, 'times': times.tolist(),
           'run_medians_ms': medians}
    print(f"{name}: inc {row['inc_segments']} segs {row['inc_mean_cm']:.2f} cm "
          f"{row['inc_coverage']:.1f}% twins {row['inc_twins_pct']:.1f}% contradicted "
          f"{row['inc_contradicted_pct']:.1f}% | batch "
          f"{row['batch_segments']} segs {row['batch_mean_cm']:.2f} cm "
          f"{row['batch_coverage']:.1f}% contradicted {row['batch_contradicted_pct']:.1f}% | "
          f"update median {row['median_ms']:.1f} ms "
          f"p99 {row['p99_ms']:.1f} ms (run medians {', '.join(f'{m:.1f}' for m in medians)})",
          flush=True)
    return row


def synthetic_map(n: int, rng) -> np.ndarray:
    """About ``n`` segments of square corridor loops (10 m, doors every 2 m) far from the drive."""
    segs = []
    k = 0
    while len(segs) < n:
        ox, oy = 100.0 + 25.0 * (k % 40), 25.0 * (k // 40)
        for y in (0.0, 2.0):
            for x0 in np.arange(0.0, 10.0, 2.0):
                segs.append([[ox + x0, oy + y], [ox + x0 + 1.5, oy + y]])
                segs.append([[ox + y, oy + x0], [ox + y, oy + x0 + 1.5]])
        k += 1
    return np.array(segs[:n]) + rng.normal(0, 0.002, (n, 2, 2))


def size_curve(scans, sizes, out_dir, rounds: int = 1) -> list:
    """
    Median update time of the office drive against the size of a pre-loaded map.

    The sizes are run round-robin, ``rounds`` times, and each size's times pooled, so that a
    drift of the machine's speed during the run is spread over all sizes instead of showing up
    as a slope.
    """
    pooled = {n: [] for n in sizes}
    for _ in range(max(1, int(rounds))):
        for n in sizes:
            # sigma fixed at the office drive's estimate, so every map size does the same work
            mapper = IncrementalMapper(IncrementalConfig(smemsf=SMEMSFConfig(sigma=0.0085)))
            mapper.load(synthetic_map(n, np.random.default_rng(n)))
            pooled[n].append(run_mapper(scans, mapper)[1])
    rows = []
    for n in sizes:
        times = np.concatenate(pooled[n])
        rows.append({'map_segments': n, 'median_ms': float(np.median(times)),
                     'p99_ms': float(np.percentile(times, 99))})
        print(f'  map {n:5d} segments: median {rows[-1]["median_ms"]:.2f} ms '
              f'p99 {rows[-1]["p99_ms"]:.2f} ms', flush=True)
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot([r['map_segments'] for r in rows], [r['median_ms'] for r in rows], 'o-',
            label='median')
    ax.plot([r['map_segments'] for r in rows], [r['p99_ms'] for r in rows], 's--', label='p99')
    ax.set_xscale('log')
    ax.set_ylim(0, None)
    ax.set_xlabel('segments already in the map')
    ax.set_ylabel('update time per scan [ms]')
    ax.set_title('Incremental update time against map size (720 beams)')
    ax.grid(True, alpha=0.4)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_dir / 'incremental-map-size.png', dpi=130)
    plt.close(fig)
    return rows


def histograms(rows, out_dir) -> None:
    """Update-time histograms of every quality run."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(rows), figsize=(4 * len(rows), 3.2), squeeze=False)
    for ax, row in zip(axes[0], rows):
        ax.hist(row['times'], bins=40, color='tab:blue')
        ax.axvline(row['median_ms'], color='k', lw=1, label=f"median {row['median_ms']:.1f}")
        ax.axvline(row['p99_ms'], color='r', lw=1, label=f"p99 {row['p99_ms']:.1f}")
        ax.set_title(f"{row['dataset']} ({row['beams']} beams)", fontsize=9)
        ax.set_xlabel('update time [ms]')
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / 'incremental-update-times.png', dpi=110)
    plt.close(fig)


def memory(path: pathlib.Path) -> dict:
    """RSS after the first 500 scans of a log and after all of them, with the map's size."""
    scans = log_scans(path)[0]
    marks = {}

    def on_scan(i, mapper):
        if i == 499 or i == len(scans) - 1:
            marks[i] = (rss_bytes(), mapper.nbytes(), len(mapper.segments))
    run_mapper(scans, on_scan=on_scan)
    (r500, b500, k500), (rend, bend, kend) = marks[499], marks[len(scans) - 1]
    row = {'scans': len(scans), 'rss_500_mb': r500 / 2 ** 20, 'rss_end_mb': rend / 2 ** 20,
           'map_500_kb': b500 / 1024, 'map_end_kb': bend / 1024, 'segments_500': k500,
           'segments_end': kend, 'bound_mb': (1.2 * r500 + bend) / 2 ** 20}
    row['within_bound'] = bool(rend <= 1.2 * r500 + bend)
    print(f'memory: {row}', flush=True)
    return row


def main(argv=None) -> int:
    """Run the benchmark; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    datasets_argument(ap)
    ap.add_argument('--quick', action='store_true', help='fewer map sizes, no memory run')
    ap.add_argument('--quality-only', action='store_true',
                    help='the quality table only: no map-size curve, no memory run')
    ap.add_argument('--no-readme', action='store_true', help='do not rewrite README.md')
    ap.add_argument('--repeat', type=int, default=3,
                    help='map each drive and log this many times for the update times')
    args = ap.parse_args(argv)
    out_dir = HERE / 'results'
    out_dir.mkdir(exist_ok=True)
    radish = pathlib.Path(args.datasets) / 'radish'
    load0 = os.getloadavg()
    command = ('python benchmarks/incremental.py '
               + ' '.join(argv if argv is not None else sys.argv[1:]))
    meta = stamp(command)                         # the code measured: the tree at the start
    rows = []
    for beams in (360, 720):
        rows.append(quality_row(f'sim-office-{beams}', *sim_scans(beams), args.repeat))
    for name in ('intel-corrected', 'freiburg-079-corrected'):
        path = radish / f'{name}.log.gz'
        if path.is_file():
            rows.append(quality_row(name, *log_scans(path), args.repeat))
            if name == 'intel-corrected':
                # Few, far-apart scans (a known limit): every 5th scan, batch on the same points.
                rows.append(quality_row(f'{name} (every 5th scan)', *log_scans(path, 5),
                                        args.repeat))
        else:
            print(f'skip {name}: {path} not found', file=sys.stderr)
    curve = []
    if not args.quality_only:
        sizes = [100, 1000, 5000] if args.quick else [100, 300, 1000, 2000, 5000]
        curve = size_curve(sim_scans(720)[0], sizes, out_dir, args.repeat)
    histograms(rows, out_dir)
    fr079 = radish / 'freiburg-079-corrected.log.gz'
    mem = (memory(fr079) if fr079.is_file() and not (args.quick or args.quality_only)
           else None)
    meta['load'] = load_note(load0)
    (out_dir / 'incremental.json').write_text(json.dumps(
        {'meta': meta, 'quality': rows, 'size_curve': curve, 'memory': mem}, indent=1))
    block = (f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}, with "
             f"`{meta['command']}` (default IncrementalConfig: 3-scan buffer, one SMEMSF "
             f'iteration per scan). Every drive and log is mapped {args.repeat} times; the '
             'update times are those of the run with the median median, and the last column '
             'gives the median of every run (the speed of this virtual machine drifts; '
             f"{meta['load']}). "
             f"{CONTRADICTED_NOTE}; beams of every scan mapped, from the scan's pose (corrected "
             'log pose, simulated laser pose) to its points; both maps against the same '
             'beams.\n\n'
             '| dataset | scans x beams | segments inc / batch | mean cm inc / batch | '
             'coverage inc / batch | twins inc / batch | contradicted inc / batch (segments) | '
             'update median / p99 / max (ms) | run medians (ms) |\n'
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|\n')
    for r in rows:
        block += (f"| {r['dataset']} | {r['scans']} x {r['beams']} | {r['inc_segments']} / "
                  f"{r['batch_segments']} ({r['inc_segments'] / r['batch_segments']:.2f}x) | "
                  f"{r['inc_mean_cm']:.2f} / {r['batch_mean_cm']:.2f} "
                  f"({r['inc_mean_cm'] / r['batch_mean_cm']:.2f}x) | "
                  f"{r['inc_coverage']:.1f}% / {r['batch_coverage']:.1f}% | "
                  f"{r['inc_twins_pct']:.1f}% / {r['batch_twins_pct']:.1f}% | "
                  f"{r['inc_contradicted_pct']:.1f}% ({r['inc_contradicted_segments']}) / "
                  f"{r['batch_contradicted_pct']:.1f}% ({r['batch_contradicted_segments']}) | "
                  f"{r['median_ms']:.1f} / {r['p99_ms']:.1f} / {r['max_ms']:.1f} | "
                  + ', '.join(f'{m:.1f}' for m in r['run_medians_ms']) + ' |\n')
    notes = notable_lines(
        [(f"{r['dataset']} {kind}", r[f'{key}_contradicted_pct'],
          r[f'{key}_contradicted_segments'])
         for r in rows for kind, key in (('incremental', 'inc'), ('batch', 'batch'))])
    if notes:
        block += ('\nMaps contradicted on more than 2 % of their length:\n\n'
                  + '\n'.join(notes) + '\n')
    if args.quality_only:
        block += ('\nQuality only (`--quality-only`): no map-size curve, no memory run in this '
                  'measurement.\n')
    else:
        block += ('\nUpdate time against map size (720-beam office drive, map pre-loaded with '
                  f'synthetic corridor loops, sizes run round-robin {args.repeat} times; plot '
                  '`results/incremental-map-size.png`, histograms '
                  '`results/incremental-update-times.png`):\n\n| segments in map | median ms | '
                  'p99 ms |\n|---:|---:|---:|\n')
        block += ''.join(f"| {c['map_segments']} | {c['median_ms']:.2f} | {c['p99_ms']:.2f} |\n"
                         for c in curve)
    if mem:
        block += (f"\nMemory over the fr079 log ({mem['scans']} scans): RSS "
                  f"{mem['rss_500_mb']:.1f} MiB after 500 scans, {mem['rss_end_mb']:.1f} MiB "
                  f"after all; map {mem['map_500_kb']:.0f} KiB -> {mem['map_end_kb']:.0f} KiB "
                  f"({mem['segments_500']} -> {mem['segments_end']} segments); bound 1.2 x RSS "
                  f"at 500 + map = {mem['bound_mb']:.1f} MiB: "
                  f"{'met' if mem['within_bound'] else 'NOT met'}.\n")
    if not args.no_readme:
        write_readme('incremental', block)
    print(block)
    return 0


if __name__ == '__main__':
    sys.exit(main())
