"""
Free-space evidence (issue 18): whether the points it leaves unexplained are transient.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/transient.py [--datasets DIR] [--only NAME ...] [--window 10]
        [--modes replay batch] [--set KEY=NUMBER ...] [--name NAME] [--no-readme]

For each log (Intel, CSAIL, infinite corridor, fr079) and each mode (``replay``: the
incremental map ``polyline-mapper replay`` makes, every scan, poses from the log;
``batch``: ``fit`` of all the log's points), the map is made with ``free_space_window`` 0
(no evidence, the default before 2026-11-27; batch without beams) and ``--window`` (the
evidence per LSS square; ghosts, hit margin and memory 0, as before they became the default,
unless ``--set`` gives them). Each map is judged both ways: mean distance and coverage
(0.10 m) of all the log's points (``map_metrics``), contradicted share of length
(``freespace.judge``, every scan's beams).

Then the points that the window map leaves uncovered (farther than 0.10 m from it) but the
default map covers are classified (``transient_counts``, ``is_transient``): a point is
TRANSIENT when beams of LATER scans pass through its location (a person who walked on, an
object moved away) more often than they end there. A beam passes through the point when it
crosses the point's surface (a short segment through it along the default map's nearest
segment, ``surface_tangents``) within ``RADIUS`` of it, at >= 20 deg, and ends more than 0.10 m
beyond it, perpendicular: the pass test of the map -> beams metric (``freespace.pair_tests``,
``freespace.span_pairs``); it ends there when its return lies within ``RADIUS`` along and 0.10
m across. Beams of EARLIER scans are counted too (something moved in later). Reported: the
share of those points that are transient (>= 1 and >= 3 later passes), the coverage points
they account for, and the share of the mean-distance growth (window - default, over all
points) that the transient ones carry; then both bars with the transient lost points set
aside. As a control, the share of transient points among those both maps cover (the static
world, apart from what moved but stayed in both maps).

Writes a table into benchmarks/README.md (between the ``transient`` markers) and the raw
numbers to benchmarks/results/transient.json.
"""

import argparse
import json
import pathlib
import sys
import time

from common import datasets_argument, HERE, radish_logs, stamp, write_readme
import numpy as np
from polyline_mapper.core.freespace import (judge, MIN_ANGLE, pair_tests, run_bounds, runs,
                                            span_pairs, TOL)
from polyline_mapper.core.index import nearest_distance

LOGS = ['intel-corrected', 'csail-corrected', 'infinite-corridor-corrected',
        'freiburg-079-corrected']
RADIUS = 0.05
"""Metres: a beam passes through a point's location when it crosses the point's surface
within this distance of the point (about half the spacing of 1-degree beams at 5 m)."""
NEIGHBOURS = 6
"""Scan neighbours on each side (in beam order) that may set a point's surface direction."""
REACH = 0.25
"""Metres: neighbours within this distance (or ``REACH_SHARE`` of the range, the larger) of a
point set its surface direction."""
REACH_SHARE = 0.05
"""Share of a point's range within which its scan neighbours set its surface direction."""


def scan_tangents(points: np.ndarray, origins: np.ndarray) -> np.ndarray:
    """
    Return the surface direction at each point from its neighbours in its scan, (N, 2) unit.

    Points come scan by scan in beam order (one run of equal ``origins`` per scan). The
    direction is the principal axis of the point and its neighbours of the same scan up to
    ``NEIGHBOURS`` places before and after it that lie within ``REACH`` (or ``REACH_SHARE`` x
    range, the larger) of it; with fewer than two such neighbours, perpendicular to the beam
    (the surface taken head-on).
    """
    n = len(points)
    rel = points - origins
    rng = np.hypot(rel[:, 0], rel[:, 1])
    reach = np.maximum(REACH, REACH_SHARE * rng)
    starts, _ = run_bounds(origins)
    scan = np.repeat(np.arange(starts.size), np.diff(np.append(starts, n)))
    i = np.arange(n)
    sx, sy, sxx, syy, sxy = (np.zeros(n) for _ in range(5))
    cnt = np.zeros(n)
    for k in range(-NEIGHBOURS, NEIGHBOURS + 1):
        j = np.clip(i + k, 0, n - 1)
        d = points[j] - points
        ok = (scan[j] == scan) & (np.hypot(d[:, 0], d[:, 1]) <= reach) & (i + k == j)
        dx, dy = np.where(ok, d[:, 0], 0.0), np.where(ok, d[:, 1], 0.0)
        cnt += ok
        sx += dx
        sy += dy
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    m = np.maximum(cnt, 1.0)
    cxx, cyy, cxy = sxx / m - (sx / m) ** 2, syy / m - (sy / m) ** 2, sxy / m - sx * sy / m ** 2
    theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    d = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    head_on = np.stack([-rel[:, 1], rel[:, 0]], axis=1) / np.maximum(rng, 1e-12)[:, None]
    return np.where((cnt >= 3)[:, None], d, head_on)


def surface_tangents(points: np.ndarray, origins: np.ndarray, idx: np.ndarray,
                     segments=None) -> np.ndarray:
    """
    Return the surface direction at the points ``idx`` of a recording, (len(idx), 2) unit.

    That of the point's nearest segment of ``segments`` (a reference map, (K, 2, 2)) when it
    lies within ``TOL`` of it: the surface the map claims there; else ``scan_tangents``.
    """
    t = scan_tangents(points, origins)[idx]
    if segments is None or len(segments) == 0:
        return t
    segs = np.asarray(segments, dtype=np.float64)
    dist, near = nearest_distance(points[idx], segs, radius=TOL)
    on = np.flatnonzero(dist <= TOL)
    d = segs[near[on], 1] - segs[near[on], 0]
    norm = np.hypot(d[:, 0], d[:, 1])
    ok = norm > 0
    t[on[ok]] = d[ok] / norm[ok, None]
    return t


def transient_counts(points: np.ndarray, origins: np.ndarray, subset=None, segments=None,
                     radius: float = RADIUS, tol: float = TOL, min_angle: float = MIN_ANGLE,
                     progress: bool = False) -> np.ndarray:
    """
    Count the beams of later and of earlier scans that pass through and end at each point.

    ``points`` (N, 2) and ``origins`` (N, 2): every beam of a recording, scan by scan (a run of
    equal origins is one scan). For each point of ``subset`` (indices, default all) its
    surface is the segment of half-length ``tol + radius`` centred on it along
    ``surface_tangents`` (the nearest segment of ``segments``, a reference map, when the point
    lies within ``TOL`` of it, else its scan neighbours). A beam PASSES through the point when
    it passes through that segment in the sense of the map -> beams metric
    (``freespace.pair_tests``: crossing more than ``tol`` from the segment's ends, so within
    ``radius`` of the point, at >= ``min_angle``, ending more than ``tol`` beyond its line); it
    ENDS at the point when its return lies within ``radius`` of the point along the surface
    and within ``tol`` across it (the same footprint). Beams of the point's own scan do not
    count. Returns (len(subset), 4) ints: later passes, later ends, earlier passes, earlier
    ends.
    """
    pts = np.asarray(points, dtype=np.float64)
    org = np.asarray(origins, dtype=np.float64)
    idx = np.arange(len(pts)) if subset is None else np.asarray(subset, dtype=np.intp)
    out = np.zeros((idx.size, 4), dtype=np.int64)
    if idx.size == 0 or len(pts) == 0:
        return out
    starts, _ = run_bounds(org)
    scan_of = np.repeat(np.arange(starts.size), np.diff(np.append(starts, len(pts))))
    own = scan_of[idx]
    tang = surface_tangents(pts, org, idx, segments)
    u = tang * (tol + radius)
    q = pts[idx]
    first_end, e = q - u, 2.0 * u
    lo, hi = q.min(axis=0), q.max(axis=0)
    min_sin = np.sin(min_angle)
    pieces = runs(org)
    t0 = time.perf_counter()
    for j, (a, b) in enumerate(pieces):
        scan = scan_of[a]
        o = org[a]
        rel = pts[a:b] - o
        rng = np.hypot(rel[:, 0], rel[:, 1])
        box_lo = np.minimum(o, pts[a:b].min(axis=0)) - 2 * tol
        box_hi = np.maximum(o, pts[a:b].max(axis=0)) + 2 * tol
        if np.any(box_lo > hi) or np.any(box_hi < lo):
            continue
        cand = np.flatnonzero((own != scan) & np.all(q >= box_lo, axis=1)
                              & np.all(q <= box_hi, axis=1))
        cand = cand[np.hypot(*(q[cand] - o).T) <= rng.max() + 2 * tol]
        if cand.size == 0:
            continue
        w, ec, qc, tc = first_end[cand] - o, e[cand], q[cand] - o, tang[cand]
        count = np.zeros((cand.size, 2), dtype=np.int64)
        for c0, c1, k, beam in span_pairs(w, ec, rel, tol):
            g = k + c0
            through, _ = pair_tests(rel[beam], rng[beam], w[g], ec[g], tol, min_sin)
            d = rel[beam] - qc[g]
            along = d[:, 0] * tc[g, 0] + d[:, 1] * tc[g, 1]
            across = d[:, 0] * tc[g, 1] - d[:, 1] * tc[g, 0]
            end = (np.abs(along) <= radius) & (np.abs(across) <= tol)
            count[c0:c1, 0] += np.bincount(k[through], minlength=c1 - c0)
            count[c0:c1, 1] += np.bincount(k[end], minlength=c1 - c0)
        seen = np.flatnonzero(count.any(axis=1))
        col = np.where(own[cand[seen]] < scan, 0, 2)
        out[cand[seen], col] += count[seen, 0]
        out[cand[seen], col + 1] += count[seen, 1]
        if progress and (j % 1000 == 0 or j == len(pieces) - 1):
            print(f'  transient: scan {j + 1}/{len(pieces)}, {time.perf_counter() - t0:.0f} s',
                  file=sys.stderr, flush=True)
    return out


def is_transient(counts: np.ndarray, min_passes: int = 1) -> np.ndarray:
    """
    Return which points are transient: later beams passed through them, more than ended there.

    ``counts`` from ``transient_counts``: at least ``min_passes`` later passes and more later
    passes than later ends (the metric's rule, from the point's side: a wall seen again is
    hit again, a place a person left is seen through).
    """
    return (counts[:, 0] >= min_passes) & (counts[:, 0] > counts[:, 1])


def make_map(path: pathlib.Path, mode: str, window: int, extra: dict = None) -> tuple:
    """
    Map one log: ``(segments, points, origins, seconds, update median ms or None)``.

    ``extra``: more ``IncrementalConfig`` fields for a replay with ``window`` > 0 (a batch fit
    takes ``free_space_hit_margin`` of them).
    """
    t0 = time.perf_counter()
    if mode == 'replay':
        from polyline_mapper.core.incremental import IncrementalConfig
        from polyline_mapper.replay import run_replay
        more = {'free_space_ghosts': 0, 'free_space_hit_margin': 0.0, 'free_space_memory': 0.0}
        more.update(extra if window > 0 and extra else {})
        res = run_replay(str(path), IncrementalConfig(free_space_window=window, **more))
        st = res.map_value.stats
        return (res.map_value.segments, res.points, res.session.origins(),
                time.perf_counter() - t0, st.get('update_ms_median'))
    from polyline_mapper.core import fit
    from polyline_mapper.recordings import read_beams
    points, origins, _ = read_beams(str(path))
    margin = (extra or {}).get('free_space_hit_margin', 0.0)
    res = (fit(points, origins=origins, free_space_window=window, free_space_hit_margin=margin)
           if window > 0 else fit(points))
    return res.segments, points, origins, time.perf_counter() - t0, None


def classify(points, origins, base, cut, control: int = 20000, seed: int = 0) -> dict:
    """
    Judge both maps and classify the points ``cut`` leaves uncovered and ``base`` covers.

    ``base``: the default map (window 0), ``cut``: the map with the evidence. Returns the row
    of numbers (percentages of all points, cm, shares of the lost points).
    """
    n = len(points)
    d0, _ = nearest_distance(points, base, radius=0.5)
    d1, _ = nearest_distance(points, cut, radius=0.5)
    row = {'points': int(n)}
    for key, segs, d in (('base', base, d0), ('cut', cut, d1)):
        v = judge(segs, points, origins)
        row[key] = {'segments': int(len(segs)), 'mean_cm': 100 * float(d.mean()),
                    'coverage': 100 * float(np.mean(d <= TOL)),
                    'contradicted_pct': 100 * v.share,
                    'contradicted_segments': int(v.contradicted.sum())}
    lost = np.flatnonzero((d0 <= TOL) & (d1 > TOL))
    t0 = time.perf_counter()
    counts = transient_counts(points, origins, lost, base, progress=True)
    kept = np.flatnonzero((d0 <= TOL) & (d1 <= TOL))
    sample = np.sort(np.random.default_rng(seed).choice(kept, min(control, kept.size),
                                                        replace=False))
    c_counts = transient_counts(points, origins, sample, base)
    trans = is_transient(counts)
    earlier = (counts[:, 2] >= 1) & (counts[:, 2] > counts[:, 3])
    growth = float(np.sum(d1 - d0))

    def share(mask):
        return float(mask.mean()) if mask.size else 0.0
    row.update(
        classify_seconds=time.perf_counter() - t0,
        lost=int(lost.size), lost_pct=100 * lost.size / n,
        gained_pct=100 * float(np.mean((d0 > TOL) & (d1 <= TOL))),
        lost_transient=share(trans), lost_transient_3=share(is_transient(counts, 3)),
        lost_passed_later=share(counts[:, 0] >= 1),
        lost_earlier_only=share(~trans & earlier),
        lost_transient_pct=100 * float(trans.sum()) / n,
        lost_static_pct=100 * float((~trans).sum()) / n,
        mean_growth_cm=100 * growth / n,
        growth_share_transient=(float(np.sum((d1 - d0)[lost[trans]])) / growth
                                if growth > 0 else 0.0),
        growth_share_lost=float(np.sum((d1 - d0)[lost])) / growth if growth > 0 else 0.0,
        control_transient=share(is_transient(c_counts)),
        control_passed_later=share(c_counts[:, 0] >= 1))
    # the bars with the transient lost points set aside (issue 18)
    static = np.ones(n, dtype=bool)
    static[lost[trans]] = False
    row['cut_static'] = {'mean_cm': 100 * float(d1[static].mean()),
                         'coverage': 100 * float(np.mean(d1[static] <= TOL)),
                         'base_mean_cm': 100 * float(d0[static].mean()),
                         'base_coverage': 100 * float(np.mean(d0[static] <= TOL))}
    return row


def table(rows: list) -> str:
    """Format the rows as Markdown tables: the maps, then the lost points."""
    out = ['| log | mode | window | segments | contradicted % (segments) | mean (cm) | '
           'coverage (%) | update median (ms) |', '|---|---|---:|---:|---:|---:|---:|---:|']
    for r in rows:
        for key, w in (('base', 0), ('cut', r['window'])):
            m = r[key]
            ms = r.get(f'{key}_update_ms')
            out.append(f"| {r['log']} | {r['mode']} | {w} | {m['segments']} | "
                       f"{m['contradicted_pct']:.1f} ({m['contradicted_segments']}) | "
                       f"{m['mean_cm']:.2f} | {m['coverage']:.1f} | "
                       f"{'-' if ms is None else f'{ms:.1f}'} |")
    out += ['', '| log | mode | lost (% of points) | transient: >= 1 / >= 3 later passes, '
            'more than later ends (% of lost) | seen through earlier only (% of lost) | '
            'lost, transient / static (% of points) | mean growth (cm) | '
            'of it on transient lost points | control: kept points transient | '
            'window map without transient lost points: '
            'mean (cm), coverage (%) |', '|---|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for r in rows:
        s = r['cut_static']
        out.append(f"| {r['log']} | {r['mode']} | {r['lost_pct']:.2f} | "
                   f"{100 * r['lost_transient']:.0f} / {100 * r['lost_transient_3']:.0f} | "
                   f"{100 * r['lost_earlier_only']:.0f} | {r['lost_transient_pct']:.2f} / "
                   f"{r['lost_static_pct']:.2f} | {r['mean_growth_cm']:.2f} | "
                   f"{100 * r['growth_share_transient']:.0f} % | "
                   f"{100 * r['control_transient']:.1f} % "
                   f"({100 * r['control_passed_later']:.1f} % passed) | "
                   f"{s['mean_cm']:.2f} (default {s['base_mean_cm']:.2f}), "
                   f"{s['coverage']:.1f} (default {s['base_coverage']:.1f}) |")
    return '\n'.join(out) + '\n'


def main(argv=None) -> int:
    """Map, judge and classify; write the tables and the raw numbers."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    datasets_argument(ap)
    ap.add_argument('--only', nargs='*', default=[], help='log names to run')
    ap.add_argument('--modes', nargs='*', default=['replay', 'batch'],
                    choices=['replay', 'batch'])
    ap.add_argument('--window', type=int, default=10, help='free_space_window when on')
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=NUMBER',
                    help='more IncrementalConfig fields of the window replay (numbers; the '
                    'batch fit takes free_space_hit_margin)')
    ap.add_argument('--name', default='transient',
                    help='README markers and results/NAME.json (default: transient)')
    ap.add_argument('--no-readme', action='store_true', help='do not rewrite README.md')
    args = ap.parse_args(argv)
    if args.window < 1:
        print('transient.py: error: --window must be >= 1', file=sys.stderr)
        return 2
    try:
        extra = {k: float(v) if '.' in v or 'e' in v.lower() else int(v)
                 for k, v in (item.split('=', 1) for item in args.set)}
    except ValueError:
        print(f'transient.py: error: --set takes KEY=NUMBER, got {args.set}', file=sys.stderr)
        return 2
    meta = stamp('.venv/bin/python benchmarks/transient.py '
                 + ' '.join(argv if argv is not None else sys.argv[1:]))
    rows = []
    for name, path in radish_logs(args.datasets, LOGS, args.only):
        for mode in args.modes:
            base, points, origins, s0, ms0 = make_map(path, mode, 0)
            print(f'{name} {mode} window 0: {len(base)} segments, {s0:.0f} s', flush=True)
            cut, _, _, s1, ms1 = make_map(path, mode, args.window, extra)
            print(f'{name} {mode} window {args.window}: {len(cut)} segments, {s1:.0f} s',
                  flush=True)
            row = {'log': name, 'mode': mode, 'window': args.window, 'set': extra,
                   'base_seconds': s0,
                   'cut_seconds': s1, 'base_update_ms': ms0, 'cut_update_ms': ms1,
                   **classify(points, origins, base, cut)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    out = HERE / 'results'
    out.mkdir(exist_ok=True)
    text = json.dumps({'meta': meta, 'rows': rows}, indent=1) + '\n'
    (out / f'{args.name}.json').write_text(text)
    block = (f"Measured {meta['date']} on {meta['machine']}, commit {meta['commit']}: "
             f"`{meta['command']}`. Window 0: the default map (replay: `polyline-mapper "
             f'replay LOG`; batch: `fit` of the bare points); window {args.window}: '
             f'`--set free_space_window={args.window}`'
             + ''.join(f' `{k}={v}`' for k, v in extra.items())
             + ' (batch: `fit` with the beams). '
             "Contradicted: `core/freespace.py`, every scan's beams. *Lost*: points the "
             'window map leaves farther than 0.10 m that the default map covers; *transient*: '
             'beams of later scans pass through the point (cross its surface within '
             f'{100 * RADIUS:.0f} cm of it at >= 20 deg and end > 10 cm beyond it), more than '
             'end there (within 5 cm along, 10 cm across; `transient_counts`, '
             '`is_transient`); *seen through earlier only*: not transient, but beams of '
             'earlier scans passed more than ended (something moved in). Control: the same '
             'test on 20000 points both maps cover (in brackets: any later pass).\n\n'
             + table(rows))
    if not args.no_readme:
        write_readme(args.name, block)
    print(block)
    return 0


if __name__ == '__main__':
    sys.exit(main())
