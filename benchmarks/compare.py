"""
Ours against the line-map methods users would pick instead, on the same data, in one run.

Usage (from the repository root, after ``bash tools/dev.sh setup``, which installs the
baselines' libraries, listed in benchmarks/requirements.txt)::

    .venv/bin/python benchmarks/compare.py [--quick] [--datasets DIR] [--report]

Runs every method of ``METHODS`` on every dataset (simulated worlds with known walls at three
noise levels, and every shared Radish log found under DIR/radish), sweeping each method's main
knob, and writes benchmarks/results.md (tables, claims, how each method was configured),
benchmarks/results/compare.json (every number) and benchmarks/results/compare_*.png (error
against segment count per dataset, per-scan latency histograms). ``--quick``: one simulated
world and the first 500 scans of the Intel log. ``--report``: rewrite results.md and the plots
from compare.json without running anything.
"""

import argparse
import json
import os
import pathlib
import sys
import time

from baselines import (em_bic, em_lines, hough_segments, scan_segments, SegmentMerger,
                       sequential_ransac, wall_scores)
from baselines.walls import observed_walls
from common import datasets_argument, HERE, stamp
import numpy as np
from polyline_mapper.core import fit, map_metrics, SMEMSFConfig
from polyline_mapper.core.freespace import judge
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.recordings import drive_beams
from polyline_mapper.sim import corridor_loop, hall_with_arc, LaserSpec, office_floor
from polyline_mapper.sim import simulate_drive

try:
    from tqdm import tqdm
except ImportError:  # pragma: no cover - tqdm is in tools/requirements.txt
    def tqdm(x, **_):
        return x

LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected', 'freiburg-campus-corrected']
NOISES = (0.005, 0.02, 0.05)
SUBSAMPLE = 50_000
"""Global baselines (EM, EM+BIC, RANSAC) fit at most this many points (seeded random subset);
every method is scored on all points."""
MEMORY_LIMIT_GIB = 18
"""Address-space limit of the run: a method that needs more gets a MemoryError, noted in its
row, instead of the kernel killing the whole run (24 GiB machine)."""
BIG = 1_000_000
FREE_OK = 2.0
"""Contradicted share of map length (%) at or below which claim 1's free-space side holds."""
"""Datasets with more points run each method at its main setting only (no sweep)."""

# Each method: main knob, its value for the table row, the values swept for the curves, and the
# fixed settings. 'k_ours' means: the segment count of ours-batch on the same dataset.
METHODS = {
    'ours-batch': {'knob': 'sigma (m)', 'main': None, 'sweep': [None, 0.015, 0.03, 0.05]},
    'ours-incremental': {'knob': 'sigma (m)', 'main': None, 'sweep': [None, 0.03, 0.05]},
    'em-fixed-k': {'knob': 'K (x K of ours-batch)', 'main': 1.0, 'sweep': [0.5, 1.0, 2.0],
                   'fixed': {'sigma': 0.03, 'restarts': 3, 'max_iter': 100, 'kappa': 3.0}},
    'em-bic': {'knob': 'sigma (m)', 'main': 0.03, 'sweep': [0.02, 0.03, 0.05],
               'fixed': {'k_start': 2, 'growth': 1.25, 'patience': 3, 'max_iter': 100}},
    'split-merge': {'knob': 'epsilon (m)', 'main': 0.05, 'sweep': [0.02, 0.05, 0.1, 0.2],
                    'fixed': {'jump': 0.2, 'jump_rel': 0.05, 'min_points': 5,
                              'merge_angle_deg': 5.0, 'merge_offset': 0.05,
                              'merge_gap': 0.10}},
    'ransac': {'knob': 'threshold (m)', 'main': 0.05, 'sweep': [0.02, 0.05, 0.1],
               'fixed': {'min_inliers': 20, 'gap': 0.3, 'min_points': 10, 'max_trials': 500,
                         'tile': 5.0}},
    'hough': {'knob': 'votes', 'main': 20, 'sweep': [10, 20, 40, 80],
              'fixed': {'cell': 0.05, 'min_length': 0.3, 'max_gap': 0.2, 'theta_deg': 0.5}},
}
PER_SCAN = ('ours-incremental', 'split-merge')
GLOBAL = ('em-fixed-k', 'em-bic', 'ransac', 'hough')
NEEDS = {'split-merge': 'cv2', 'hough': 'cv2', 'ransac': 'skimage'}


# ----------------------------------------------------------------------------- datasets


def sim_worlds() -> dict:
    """Return the simulated worlds: office, corridors, curved walls, clutter."""
    from baselines import cluttered_room
    return {'office': office_floor, 'corridors': corridor_loop, 'hall-arc': hall_with_arc,
            'clutter': cluttered_room}


def sim_dataset(world_name: str, noise: float, seed: int = 1) -> dict:
    """Drive through a simulated world: 271 beams over 270 deg, 12 m, a scan every 0.5 m."""
    world = sim_worlds()[world_name]()
    spec = LaserSpec(beams=271, range_max=12.0, noise=noise, dropout=0.01)
    drive = simulate_drive(world, spec, step=0.5, rng=seed)
    angles = spec.angles()
    scans = [(r, angles, p, spec.range_min, spec.range_max)
             for r, p in zip(drive.ranges, drive.poses)]
    points, origins = drive_beams(drive)
    return {'name': f'sim-{world_name}-{100 * noise:g}cm', 'scans': scans, 'points': points,
            'origins': origins, 'world': world,
            'walls': world.walls[observed_walls(world.walls, points)]}


def log_dataset(path: pathlib.Path, max_scans: int = None) -> dict:
    """Read the scans (no-return code applied) and end points of a corrected CARMEN log."""
    from polyline_mapper.scan import scan_to_points
    log = read_carmen(str(path))
    top = log.no_return * 0.99
    recs = log.records[:max_scans] if max_scans else log.records
    scans = [(rec.ranges, rec.angles, rec.pose, 0.0, min(rec.range_max, top)) for rec in recs]
    per_scan = [scan_to_points(*s) for s in scans]
    points = np.concatenate(per_scan)
    origins = np.repeat(np.array([rec.pose[:2] for rec in recs]),
                        [len(p) for p in per_scan], axis=0)      # each beam's laser position
    name = path.name.replace('.log.gz', '') + (f'-first{max_scans}' if max_scans else '')
    return {'name': name, 'scans': scans, 'points': points, 'origins': origins, 'world': None,
            'walls': None}


def dataset_specs(folder: pathlib.Path, quick: bool) -> list:
    """(name, loader) of every dataset to run, and notes on the ones skipped."""
    specs, notes = [], []
    worlds = ['office'] if quick else list(sim_worlds())
    noises = (0.02,) if quick else NOISES
    for w in worlds:
        for nz in noises:
            specs.append((f'sim-{w}-{100 * nz:g}cm', lambda w=w, nz=nz: sim_dataset(w, nz)))
    for name in (['intel-corrected'] if quick else LOGS):
        path = folder / 'radish' / f'{name}.log.gz'
        if not path.is_file():
            notes.append(f'{name}: skipped, {path} not found')
            continue
        specs.append((name, lambda p=path: log_dataset(p, 500 if quick else None)))
    return specs, notes


# ----------------------------------------------------------------------------- methods


def subsample(points: np.ndarray, n: int = SUBSAMPLE, seed: int = 0) -> np.ndarray:
    """At most ``n`` of the points, a seeded random subset."""
    if len(points) <= n:
        return points
    return points[np.random.default_rng(seed).choice(len(points), n, replace=False)]


def run_method(method: str, value, ds: dict, k_ours: int, cap: float) -> dict:
    """Run one method at one knob value; return segments, timing and notes."""
    cfg = METHODS[method].get('fixed', {})
    pts, scans = ds['points'], ds['scans']
    per_scan, note, late = None, '', False
    deadline = time.perf_counter() + cap
    t0 = time.perf_counter()
    if method == 'ours-batch':
        segs = fit(pts, SMEMSFConfig(sigma=value)).segments
    elif method == 'ours-incremental':
        mapper = IncrementalMapper(IncrementalConfig(smemsf=SMEMSFConfig(sigma=value)))
        per_scan = []
        for ranges, angles, pose, rmin, rmax in scans:
            t1 = time.perf_counter()
            info = mapper.update_scan(ranges, angles, pose, rmin, rmax)
            if info.skipped is None:
                per_scan.append(1000.0 * (time.perf_counter() - t1))
        segs = mapper.polylines().segments
    elif method == 'split-merge':
        merger = SegmentMerger(cfg['merge_angle_deg'], cfg['merge_offset'], cfg['merge_gap'])
        per_scan = []
        for ranges, angles, pose, rmin, rmax in scans:
            t1 = time.perf_counter()
            s, st = scan_segments(ranges, angles, pose, rmin, rmax, epsilon=value,
                                  jump=cfg['jump'], jump_rel=cfg['jump_rel'],
                                  min_points=cfg['min_points'])
            merger.add_many(s, st)
            per_scan.append(1000.0 * (time.perf_counter() - t1))
        segs = merger.segments()
    elif method in ('em-fixed-k', 'em-bic', 'ransac'):
        fit_pts = subsample(pts)
        if len(fit_pts) < len(pts):
            note = f'fit on {len(fit_pts)} of {len(pts)} points'
        if method == 'em-fixed-k':
            k = max(1, int(round(value * k_ours)))
            res = em_lines(fit_pts, k, cfg['sigma'], restarts=cfg['restarts'],
                           max_iter=cfg['max_iter'], kappa=cfg['kappa'], rng=0,
                           deadline=deadline)
            segs, late = res.segments, res.timed_out
        elif method == 'em-bic':
            res = em_bic(fit_pts, value, k_start=cfg['k_start'], growth=cfg['growth'],
                         patience=cfg['patience'], max_iter=cfg['max_iter'], rng=0,
                         deadline=deadline)
            segs, late = res.segments, res.timed_out
            note = (note + '; ' if note else '') + f'BIC min at K={len(segs)} of ' + \
                f'{res.path[0]["k"]}..{res.path[-1]["k"]}'
        else:
            segs, late = sequential_ransac(fit_pts, threshold=value, rng=0, deadline=deadline,
                                           **cfg)
    elif method == 'hough':
        segs = hough_segments(pts, threshold=value, **cfg)
    else:
        raise ValueError(f'unknown method {method!r}')
    seconds = time.perf_counter() - t0
    if late:
        note = (note + '; ' if note else '') + f'timeout after {cap:.0f} s (best so far)'
    return {'segs': np.asarray(segs, dtype=np.float64).reshape(-1, 2, 2), 'seconds': seconds,
            'per_scan_ms': per_scan, 'note': note, 'timed_out': late}


def score(ds: dict, out: dict) -> dict:
    """Metrics of one run on all the dataset's points (and walls when simulated)."""
    m = map_metrics(ds['points'], out['segs'])
    free = judge(out['segs'], ds['points'], ds['origins'])
    row = {'segments': m['segments'], 'mean_cm': 100 * m['mean_distance'],
           'contradicted_pct': 100 * free.share,
           'contradicted_segments': int(free.contradicted.sum()),
           'p95_cm': 100 * m['p95_distance'], 'coverage_pct': 100 * m['coverage_0_10m'],
           'compression': m['compression'], 'seconds': out['seconds'],
           'per_scan_total_ms': 1000 * out['seconds'] / len(ds['scans']),
           'note': out['note'], 'timed_out': out['timed_out']}
    if out['per_scan_ms'] is not None and len(out['per_scan_ms']):
        t = np.asarray(out['per_scan_ms'])
        row.update(median_ms=float(np.median(t)), p99_ms=float(np.percentile(t, 99)),
                   times_ms=[round(float(v), 3) for v in t])
    if ds['walls'] is not None:
        w = wall_scores(out['segs'], ds['walls'], ds['world'].distance, points=ds['points'])
        row.update(precision=w['precision'], recall=w['recall'], f1=w['f1'],
                   end_cm=100 * w['end_error_median'], walls=w['walls'])
    return row


def missing_modules() -> set:
    """Names of the optional libraries (cv2, skimage) that do not import."""
    missing = set()
    for mod in ('cv2', 'skimage'):
        try:
            __import__(mod)
        except ImportError:
            missing.add(mod)
    return missing


def run_dataset(ds: dict, cap: float, missing: set) -> list:
    """Every method at every knob value on one dataset; rows in METHODS order."""
    rows, k_ours = [], None
    big = len(ds['points']) > BIG
    jobs = [(m, v) for m, spec in METHODS.items()
            for v in ([spec['main']] if big else spec['sweep'])]
    for method, value in tqdm(jobs, desc=ds['name'], unit='run', leave=False):
        base = {'dataset': ds['name'], 'method': method, 'value': value,
                'main': value == METHODS[method]['main']}
        if NEEDS.get(method) in missing:
            rows.append({**base, 'segments': None,
                         'note': f'n/a: {NEEDS[method]} not installed'})
            continue
        try:
            out = run_method(method, value, ds, k_ours or 1, cap)
            row = {**base, **score(ds, out)}
        except MemoryError:         # the address-space limit set in main(), not a crash
            rows.append({**base, 'segments': None, 'note': 'n/a: out of memory '
                         f'(limit {MEMORY_LIMIT_GIB} GiB)'})
            tqdm.write(f"  {ds['name']:28s} {method:16s} out of memory")
            continue
        if method == 'em-fixed-k':
            row['k'] = max(1, int(round(value * (k_ours or 1))))
        if method == 'ours-batch' and row['main']:
            k_ours = row['segments']
        rows.append(row)
        tqdm.write(f"  {ds['name']:28s} {method:16s} {str(value):6s} {row['segments']:5d} segs "
                   f"mean {row['mean_cm']:6.2f} cm cov {row['coverage_pct']:5.1f}% "
                   f"contra {row['contradicted_pct']:5.1f}% "
                   f"{row['seconds']:7.2f} s" + (f" F1 {row['f1']:.2f}" if 'f1' in row else '')
                   + (f" [{row['note']}]" if row['note'] else ''))
    return rows


# ----------------------------------------------------------------------------- report


def main_rows(rows: list, dataset: str) -> dict:
    """Return the main-setting row of each method on one dataset."""
    return {r['method']: r for r in rows if r['dataset'] == dataset and r['main']}


def free_space_holds(ours: dict, other: dict):
    """
    Return whether ours claims no more walls through free space than ``other``.

    True when ours' contradicted share is <= ``FREE_OK`` % or no higher than the other's; None
    when the run did not measure it (an older compare.json).
    """
    o, b = ours.get('contradicted_pct'), other.get('contradicted_pct')
    if o is None:
        return None
    return bool(o <= FREE_OK or (b is not None and o <= b))


def lower_share(rows: list, dataset: str, ours: dict) -> str:
    """Say which other methods (main setting) have a lower contradicted share than ours."""
    if ours.get('contradicted_pct') is None:
        return ''
    better = [(r['contradicted_pct'], m) for m, r in main_rows(rows, dataset).items()
              if not m.startswith('ours') and r.get('contradicted_pct') is not None
              and r['contradicted_pct'] < ours['contradicted_pct']]
    if not better:
        return ''
    return ('; lower contradicted share than ours-batch at their main setting: '
            + ', '.join(f'{m} {c:.1f}%' for c, m in sorted(better)))


def claims(data: dict) -> str:
    """Check the issue's claims against the numbers; plain statements with margins."""
    rows, names = data['rows'], data['datasets']
    out = ['## Claims, checked\n']
    held, unmeasured, lines = 0, 0, []
    for d in names:
        mr = main_rows(rows, d)
        ours = mr.get('ours-batch')
        if not ours or ours.get('segments') is None:
            continue
        rivals = []
        for m in METHODS:
            if m.startswith('ours'):
                continue
            cand = [r for r in rows if r['dataset'] == d and r['method'] == m
                    and r.get('segments') and r['segments'] <= ours['segments']]
            if cand:
                best = min(cand, key=lambda r: r['mean_cm'])
                rivals.append((best['mean_cm'], m, best))
        if not rivals:
            lines.append(f'- {d}: no other method produced a map with <= {ours["segments"]} '
                         'segments at any setting tried (nothing to compare); ours-batch '
                         f"contradicted {fmt(ours.get('contradicted_pct'), '.1f', '%')}.")
            held += 1
            continue
        rivals.sort(key=lambda x: x[0])
        best_mean, best_m, best = rivals[0]
        accurate = ours['mean_cm'] < best_mean
        free = free_space_holds(ours, best)
        ok = accurate and free is True
        held += ok
        unmeasured += free is None
        lines.append(
            f"- {d}: ours-batch {ours['mean_cm']:.2f} cm at {ours['segments']} segments, "
            f"contradicted {fmt(ours.get('contradicted_pct'), '.1f', '%')}; best other at <= "
            f"{ours['segments']} segments: {best_m} {best_mean:.2f} cm ({best['segments']} "
            f"segments, {METHODS[best_m]['knob']} = {best['value']}), contradicted "
            f"{fmt(best.get('contradicted_pct'), '.1f', '%')} -> "
            + ('**holds**' if ok else '**not judged** (free space not measured in this run)'
               if accurate and free is None else '**does not hold**')
            + (f', margin {best_mean - ours["mean_cm"]:.2f} cm' if accurate else
               f', ours worse on mean distance by {ours["mean_cm"] - best_mean:.2f} cm')
            + f' ({best_mean / ours["mean_cm"]:.2f}x)'
            + ('' if free is not False else
               f"; ours loses on free space ({ours['contradicted_pct']:.1f}% > "
               f"{best['contradicted_pct']:.1f}% and > {FREE_OK:g}%)")
            + lower_share(rows, d, ours))
    out.append(f'1. **Lowest mean distance at equal or fewer segments, and no more walls '
               f'through free space** (every setting of every other method with at most as '
               f'many segments as ours-batch; ours-batch at its default; ours must have the '
               f'lower mean distance AND a contradicted share of map length no higher than '
               f"that best other's, or <= {FREE_OK:g} %): holds on {held} of {len(lines)} "
               'datasets' + (f' ({unmeasured} without the free-space numbers)' if unmeasured
                             else '')
               + '. "Contradicted": share of map length that >= 5 beams pass through, '
               'more than end on it (`polyline_mapper/core/freespace.py`); beams from the '
               "scans' poses.\n")
    out += [ln + '\n' for ln in lines]
    sims = [d for d in names if d.startswith('sim-')]
    f1_lines, f1_held = [], 0
    for d in sims:
        mr = main_rows(rows, d)
        if 'f1' not in mr.get('ours-batch', {}):
            continue
        # Other methods, as in claim 1: ours-incremental is ours, not a rival (it is shown).
        others = {m: r['f1'] for m, r in mr.items() if not m.startswith('ours') and 'f1' in r}
        if not others:
            continue
        best_m = max(others, key=others.get)
        ok = mr['ours-batch']['f1'] >= others[best_m]
        f1_held += ok
        f1_lines.append(f"- {d}: ours-batch F1 {mr['ours-batch']['f1']:.2f}, "
                        'ours-incremental '
                        + fmt(mr.get('ours-incremental', {}).get('f1'))
                        + f'; best other {best_m} {others[best_m]:.2f} -> '
                        + ('holds' if ok else '**does not hold**'))
    out.append(f'\n2. **Highest wall F1 on simulated data** (main settings): ours-batch is '
               f'highest (ties count) on {f1_held} of {len(f1_lines)} simulated datasets, on '
               'this one drive per world; `drives.py` repeats it over several drives (table in '
               '[README.md](README.md#wall-f1-over-several-drives-drivespy)).\n')
    out += [ln + '\n' for ln in f1_lines]
    t_lines, t_fast, t_equal, t_same, t_five = [], 0, 0, 0, 0
    for d in names:
        mr = main_rows(rows, d)
        inc = mr.get('ours-incremental')
        if not inc or 'median_ms' not in inc:
            continue
        t_five += inc['median_ms'] <= 5.0
        glob = {m: mr[m] for m in GLOBAL if m in mr and mr[m].get('segments') is not None}
        # Used online, a global method refits every point seen so far on every scan: at the end
        # of the log one scan costs one fit of all points (its total time).
        faster = [m for m, r in glob.items() if 1000 * r['seconds'] <= inc['median_ms']]
        better = [m for m in faster if glob[m]['mean_cm'] <= inc['mean_cm']]
        # Equal quality as in claim 1: at least as accurate with at most as many segments.
        same = [m for m in better if glob[m]['segments'] <= inc['segments']]
        t_fast += not faster
        t_equal += not better
        t_same += not same
        verdict = f" -> not faster than {', '.join(faster)}" if faster else ''
        if better:
            verdict += (f" (at least as accurate: {', '.join(better)}; "
                        + (f"with at most as many segments: {', '.join(same)})" if same
                           else 'none with at most as many segments)'))
        t_lines.append(
            f"- {d}: ours-incremental median {inc['median_ms']:.2f} ms/scan "
            f"(p99 {inc['p99_ms']:.1f}), mean {inc['mean_cm']:.2f} cm at {inc['segments']} "
            'segments; global baselines, one refit of all points (online cost per scan at the '
            'end) / total over scans: '
            + ', '.join(f"{m} {1000 * r['seconds']:.1f} / {r['per_scan_total_ms']:.2f} ms "
                        f"({r['mean_cm']:.2f} cm, {r['segments']} segments)"
                        for m, r in glob.items())
            + verdict)
    out.append(f'\n3. **Incremental median <= 5 ms per scan**: on {t_five} of {len(t_lines)} '
               f'datasets. **Faster per scan than every global baseline**: on {t_fast} of '
               f'{len(t_lines)} datasets, counting a global method used online at one refit of '
               'all the points (what each scan costs it at the end of the log; RANSAC and the '
               'EMs on a subsample, so a lower bound); no global baseline is both faster and at '
               f'least as accurate (mean distance) on {t_equal} of {len(t_lines)}; none is '
               'faster at equal quality (at least as accurate with at most as many segments, '
               f'the comparison of claim 1) on {t_same} of {len(t_lines)}. Counted at '
               'its total time divided by the number of scans (a batch run after the drive, '
               'not an online map), each global method is faster on every dataset.\n')
    out += [ln + '\n' for ln in t_lines]
    return ''.join(out)


def fmt(v, spec: str = '.2f', unit: str = '') -> str:
    """Format a number or return a dash."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return '-'
    return f'{v:{spec}}{unit}'


def table(rows: list, dataset: str, sim: bool) -> str:
    """Markdown table of the main row of each method on one dataset."""
    head = ('| method | setting | segments | mean cm | p95 cm | coverage | contradicted | '
            'compression | per scan ms | total s |'
            + (' precision | recall | F1 | end err cm |' if sim else '')
            + ' note |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|'
            + ('---:|---:|---:|---:|' if sim else '') + '---|\n')
    body = ''
    for m in METHODS:
        r = main_rows(rows, dataset).get(m)
        if r is None:
            continue
        knob = METHODS[m]['knob'].split(' ')[0]
        val = 'auto' if r['value'] is None else r['value']
        setting = f'{knob}={val}' + (f" (K={r['k']})" if 'k' in r else '')
        if r.get('segments') is None:
            body += f'| {m} | {setting} | n/a |' + ' |' * (7 + 4 * sim) + f" {r['note']} |\n"
            continue
        per = (f"{r['median_ms']:.2f} (median)" if 'median_ms' in r
               else f"{r['per_scan_total_ms']:.1f} (total/scans)")
        body += (f"| {m} | {setting} | {r['segments']} | {fmt(r['mean_cm'])} | "
                 f"{fmt(r['p95_cm'])} | {fmt(r['coverage_pct'], '.1f', '%')} | "
                 f"{fmt(r.get('contradicted_pct'), '.1f', '%')} | "
                 f"{fmt(r['compression'], '.0f')} | {per} | {r['seconds']:.1f} |")
        if sim:
            body += (f" {r['precision']:.2f} | {r['recall']:.2f} | {r['f1']:.2f} | "
                     f"{fmt(r['end_cm'], '.1f')} |")
        body += f" {r['note']} |\n"
    return head + body


def method_text() -> str:
    """One paragraph per method: how it was configured, so each row can be reproduced."""
    c = {m: METHODS[m].get('fixed', {}) for m in METHODS}
    return f"""## How each method was run

All methods see the same data: for simulated worlds the scans and their true poses, for the
Radish logs the scans with the corrected poses; "points" are the laser end points registered
with those poses (no-return readings dropped). Every map is scored on all points. The code of
the baselines is in `benchmarks/baselines/` (numpy parts unit-tested in
`test/test_baselines.py`). Main settings are values picked before any run (typical for a
laser with 1-5 cm noise), checked once with `--quick` (sim-office-2cm, first 500 Intel scans)
and not changed afterwards; they are the same on every dataset. Secondary settings (listed
below) were not tuned. Instead of per-dataset tuning, the curves show every swept setting, and
claim 1 lets each baseline use its best swept setting on each dataset.

- **ours-batch**: `polyline_mapper.core.fit(points, SMEMSFConfig(sigma=...))`, default
  configuration (sigma estimated from the points) for the table; sigma swept over
  {METHODS['ours-batch']['sweep']} for the curve.
- **ours-incremental**: `IncrementalMapper(IncrementalConfig(smemsf=SMEMSFConfig(sigma=...)))`,
  every scan in order through `update_scan`, map from `polylines()`; default configuration
  (3-scan buffer, one iteration per scan, free-space clearing of segments up to 0.9 m) for
  the table, sigma swept over
  {METHODS['ours-incremental']['sweep']}. Per-scan time is each `update_scan` call.
- **em-fixed-k** (plain EM, no split or merge; `baselines.em_lines`): K segments seeded at K
  random cells of a 0.5 m grid (each a line fitted to its 15 nearest points), E-step on the
  point-to-segment distance with an outlier class at kappa = {c['em-fixed-k']['kappa']} sigma,
  weighted orthogonal regression M-step, segments trimmed to the projections of their MAP
  support, dead segments re-seeded at unexplained points; sigma = {c['em-fixed-k']['sigma']} m,
  at most {c['em-fixed-k']['max_iter']} iterations, best of {c['em-fixed-k']['restarts']} seedings
  by log-likelihood. The table uses K = the segment count of ours-batch on the same dataset
  (equal segments); the curve K = {METHODS['em-fixed-k']['sweep']} x that. sigma is fixed at
  the main sigma of em-bic (not swept separately).
- **em-bic** (Sack and Burgard style; `baselines.em_bic`): the same EM, K grown from
  {c['em-bic']['k_start']} by x{c['em-bic']['growth']} (at least +1) per step, each step
  warm-started from the previous fit plus new seeds at unexplained points;
  BIC = -2 log L + 5 K ln N with a normalised Gaussian-tube density per segment and a
  uniform outlier class; stops after
  {c['em-bic']['patience']} steps without a lower BIC; the lowest-BIC fit is reported. Main
  sigma {METHODS['em-bic']['main']} m, swept over {METHODS['em-bic']['sweep']}.
- **split-merge** (`baselines.scan_segments` + `SegmentMerger`): each scan is broken into chains
  at invalid readings and range jumps (> {c['split-merge']['jump']} m +
  {c['split-merge']['jump_rel']} x range), each chain simplified with
  `cv2.approxPolyDP(chain, epsilon, closed=False)` in the laser frame, each piece with
  >= {c['split-merge']['min_points']} points refitted by total least squares and cut to its
  first and last point, moved to the world with the scan pose, and merged
  into the map when within {c['split-merge']['merge_angle_deg']} deg, both ends of the shorter
  within {c['split-merge']['merge_offset']} m of the longer's line and overlapping or at most
  {c['split-merge']['merge_gap']} m apart (merged line = least squares of all points behind both,
  from sufficient statistics). Main epsilon {METHODS['split-merge']['main']} m, swept over
  {METHODS['split-merge']['sweep']}. Per-scan time is segmentation plus merging.
- **ransac** (`baselines.sequential_ransac`): `skimage.measure.ransac(points, LineModelND,
  min_samples=2, residual_threshold=t, max_trials={c['ransac']['max_trials']},
  stop_probability=0.99)` repeatedly on the points not yet explained; each line's inliers are
  split at gaps > {c['ransac']['gap']} m, runs of >= {c['ransac']['min_points']} points
  refitted and kept; stop when the best line has < {c['ransac']['min_inliers']} inliers. Run per
  {c['ransac']['tile']} m tile (global RANSAC on a building-sized map almost never samples two
  points of the same wall), pieces joined across tiles by the split-merge merger. Main
  threshold {METHODS['ransac']['main']} m, swept over {METHODS['ransac']['sweep']}.
- **hough** (`baselines.hough_segments`): points rasterised at {c['hough']['cell']} m (a cell
  is set when it holds a point), `cv2.HoughLinesP(image, rho=1 cell,
  theta={c['hough']['theta_deg']} deg, threshold=votes, minLineLength={c['hough']['min_length']} m,
  maxLineGap={c['hough']['max_gap']} m)`, end points mapped back to metres at cell centres. Main
  votes {METHODS['hough']['main']}, swept over {METHODS['hough']['sweep']}.

EM, EM+BIC and RANSAC fit a seeded random subset of at most {SUBSAMPLE} points on the bigger
logs (noted in the table) and stop at a time cap (noted as "timeout"; the best fit so far is
scored). On datasets with more than {BIG} points (fr079) every method runs at its main setting
only (no curve). Wall metrics (simulated data): walls observed along >= 80 % of their length
are cut at T-junctions and only the pieces observed along >= 80 % of their length count (the
room corner closed off behind the clutter world's slanted wall is no wall a scan saw); a wall is
found when ONE segment lies within 0.10 m of >= 80 % of it (recall); a segment is correct when
>= 80 % of it lies within 0.10 m of the true geometry, arcs included (precision); end-point
error is the median distance from each end of a found wall to the nearest end of a segment
running along it.
"""


def plots(data: dict, out_dir: pathlib.Path, prefix: str = 'compare') -> None:
    """Error against segment count per dataset; per-scan latency histograms."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    rows, names = data['rows'], data['datasets']
    colours = dict(zip(METHODS, plt.rcParams['axes.prop_cycle'].by_key()['color']))
    ncol = 4
    nrow = max(1, int(np.ceil(len(names) / ncol)))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow), squeeze=False)
    for ax, d in zip(axes.ravel(), names):
        for m in METHODS:
            rs = sorted([r for r in rows if r['dataset'] == d and r['method'] == m
                         and r.get('segments')], key=lambda r: r['segments'])
            if not rs:
                continue
            ax.plot([r['segments'] for r in rs], [r['mean_cm'] for r in rs], 'o-', ms=3,
                    color=colours[m], label=m)
            mr = [r for r in rs if r['main']]
            if mr:
                ax.plot(mr[0]['segments'], mr[0]['mean_cm'], 's', ms=7, mfc='none',
                        color=colours[m])
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.set_title(d, fontsize=9)
        ax.set_xlabel('segments', fontsize=8)
        ax.set_ylabel('mean distance [cm]', fontsize=8)
        ax.grid(True, which='both', alpha=0.3)
    for ax in axes.ravel()[len(names):]:
        ax.axis('off')
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle('Mean point-to-map distance against segment count (squares: main setting)')
    fig.tight_layout()
    fig.savefig(out_dir / f'{prefix}_curves.png', dpi=100)
    plt.close(fig)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow), squeeze=False)
    for ax, d in zip(axes.ravel(), names):
        mr = main_rows(rows, d)
        for m in PER_SCAN:
            if m in mr and mr[m].get('times_ms'):
                t = np.maximum(mr[m]['times_ms'], 1e-2)
                ax.hist(t, bins=np.logspace(-2, 2.5, 60), alpha=0.6, color=colours[m],
                        label=f'{m} (median {np.median(t):.2f})')
        ax.axvline(5.0, color='k', lw=0.8, ls='--')
        ax.set_xscale('log')
        ax.set_title(d, fontsize=9)
        ax.set_xlabel('per-scan time [ms]', fontsize=8)
        ax.legend(fontsize=6)
    for ax in axes.ravel()[len(names):]:
        ax.axis('off')
    fig.suptitle('Per-scan update time of the incremental methods (dashed: 5 ms)')
    fig.tight_layout()
    fig.savefig(out_dir / f'{prefix}_latency.png', dpi=100)
    plt.close(fig)


def versions() -> str:
    """Versions of the libraries the baselines use."""
    out = []
    for mod in ('cv2', 'skimage', 'tqdm', 'matplotlib'):
        try:
            out.append(f'{mod} {__import__(mod).__version__}')
        except ImportError:
            out.append(f'{mod} not installed')
    return ', '.join(out)


def report(data: dict, path: pathlib.Path) -> None:
    """Write results.md from the collected numbers."""
    meta = data['meta']
    text = ('# Comparison with other line-map methods\n\n'
            f"Measured {meta['date']} on {meta['machine']}; {meta['versions']}; commit "
            f"{meta['commit']}; load before the run: {meta['load']}; with "
            f"`{meta['command']}` ({meta['seconds'] / 60:.0f} min).\n\n"
            + ''.join(f"Interrupted and resumed {m['date']} (commit {m['commit']}) with "
                      f"`{m['command']}`; only the datasets not finished before ran then.\n\n"
                      for m in data.get('resumed', []))
            + 'Plots: [error against segment count](results/compare_curves.png) (every swept '
            'setting), [per-scan latency](results/compare_latency.png). Raw numbers: '
            '[results/compare.json](results/compare.json).\n\n')
    if data['notes']:
        text += 'Skipped: ' + '; '.join(data['notes']) + '.\n\n'
    text += (f"Datasets finished: {len(data['datasets'])} of {data.get('planned', '?')}"
             + ('' if len(data['datasets']) == data.get('planned') else
                ' (run still in progress or interrupted; the rest are missing below)')
             + '.\n\n')
    text += claims(data) + '\n## Results per dataset (main setting of each method)\n\n'
    text += ('Distances are of every point to its nearest segment; coverage is the share of '
             'points within 0.10 m; contradicted is the share of map length that >= 5 beams '
             'pass through, more than end on it; compression is points / (2 x segments); per '
             'scan: median update time for the incremental methods, total time / number of '
             'scans for the global ones.\n\n')
    for d in data['datasets']:
        n = next((r for r in data['rows'] if r['dataset'] == d), None)
        info = data['info'].get(d, {})
        text += (f"### {d}\n\n{info.get('points', '?')} points, {info.get('scans', '?')} scans"
                 + (f", {info['walls']} observed walls" if info.get('walls') else '')
                 + (f" ({n['walls']} observed pieces after cutting at T-junctions)"
                    if n is not None and n.get('walls') else '') + '\n\n')
        if n is not None:
            text += table(data['rows'], d, d.startswith('sim-')) + '\n'
    text += method_text()
    path.write_text(text)


def main(argv=None) -> int:
    """Run the comparison; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    datasets_argument(ap)
    ap.add_argument('--quick', action='store_true',
                    help='sim-office-2cm and the first 500 Intel scans only')
    ap.add_argument('--cap', type=float, default=300.0,
                    help='time cap (s) of one global baseline run')
    ap.add_argument('--resume', action='store_true',
                    help='keep the datasets results/compare.json has finished, run the rest '
                    '(after an interrupted run; results.md names both commands)')
    ap.add_argument('--report', action='store_true',
                    help='only rewrite results.md and the plots from results/compare.json')
    args = ap.parse_args(argv)
    out_dir = HERE / 'results'
    out_dir.mkdir(exist_ok=True)
    # --quick is for development: its files stay next to, not over, the real results
    prefix = 'compare_quick' if args.quick else 'compare'
    json_path = out_dir / f'{prefix}.json'
    md_path = out_dir / 'compare_quick.md' if args.quick else HERE / 'results.md'
    if args.report:
        data = json.loads(json_path.read_text())
        report(data, md_path)
        plots(data, out_dir, prefix)
        return 0
    missing = missing_modules()
    if missing:
        print(f"compare.py: {', '.join(sorted(missing))} not installed, so "
              f"{', '.join(m for m, n in NEEDS.items() if n in missing)} will be n/a; install "
              'with: .venv/bin/python -m pip install -r benchmarks/requirements.txt',
              file=sys.stderr)
    command = ('.venv/bin/python benchmarks/compare.py '
               + ' '.join(argv if argv is not None else sys.argv[1:])).strip()
    meta = stamp(command)
    meta.update(versions=versions(), load=' '.join(f'{v:.2f}' for v in os.getloadavg()))
    specs, notes = dataset_specs(pathlib.Path(args.datasets), args.quick)
    data = {'meta': meta, 'notes': notes, 'datasets': [], 'info': {}, 'rows': [],
            'planned': len(specs)}
    t_start = time.perf_counter()
    if args.resume and json_path.exists():
        data = json.loads(json_path.read_text())
        data.setdefault('resumed', []).append(meta)
        meta = data['meta']
        t_start -= meta.get('seconds', 0.0)
        specs = [(n, f) for n, f in specs if n not in data['datasets']]
    try:
        import resource
        limit = MEMORY_LIMIT_GIB * 2 ** 30
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    except (ImportError, ValueError, OSError):      # pragma: no cover - not Linux
        pass
    for name, load in tqdm(specs, desc='datasets', unit='dataset'):
        ds = load()
        data['datasets'].append(ds['name'])
        data['info'][ds['name']] = {'points': len(ds['points']), 'scans': len(ds['scans']),
                                    'walls': None if ds['walls'] is None else len(ds['walls'])}
        data['rows'] += run_dataset(ds, args.cap, missing)
        meta['seconds'] = time.perf_counter() - t_start
        json_path.write_text(json.dumps(data, indent=0))
        report(data, md_path)
        plots(data, out_dir, prefix)
    meta['load_after'] = ' '.join(f'{v:.2f}' for v in os.getloadavg())
    json_path.write_text(json.dumps(data, indent=0))
    report(data, md_path)
    plots(data, out_dir, prefix)
    print(f'wrote {md_path}, {json_path} and {out_dir}/{prefix}_*.png')
    return 0


if __name__ == '__main__':
    sys.exit(main())
