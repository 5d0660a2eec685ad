"""
Where the contradicted length of a map lies: registration, or what the laser sees through.

Usage (from the repository root, after ``bash tools/dev.sh setup``)::

    .venv/bin/python benchmarks/contradicted_where.py LOG MAP.json [MAP.json ...] [--own]
        [--json FILE]
    .venv/bin/python benchmarks/contradicted_where.py LOG --chunks 50 [--set KEY=VALUE ...]
    .venv/bin/python benchmarks/contradicted_where.py LOG MAP.json --lost REF.json [--sample N]

A segment is contradicted (``core/freespace.py``) when at least 5 beams pass through it and more
pass than end on it. For every contradicted segment of MAP (a ``replay`` or ``fit`` map of the
CARMEN log LOG) each passing beam is recorded with its scan and how far beyond the segment's
line it ends (perpendicular, metres: ``past``), and each ending beam with its scan. The
segment is then put in one class by the majority of its passes:

- NEAR (median ``past`` <= 1 m: the passing beams end just behind the segment, as where one
  wall is mapped 0.1-1 m off where other scans see it: registration, or a line fitted off its
  wall), split into: *twin mapped* (most passes end within 0.10 m of another map segment
  within 15 deg of it: the parallel bands of one wall), *same visit* (most passes come from
  scans within ``VISIT`` scans of a scan that ends on the segment) and *other visit*;
- FAR (median ``past`` > 1 m: the beams go on well beyond), split into *same visit* (the laser
  sees through it from where it also sees it: porous or intermittent returns, as from
  vegetation, low objects and the ground as the robot pitches, people) and *other visit*
  (what is there on one visit is not on another: change, or registration off by more than
  1 m).

Registration between visits can explain at most the NEAR classes and FAR *other visit*; FAR
*same visit* is what the map would keep with perfect poses between visits.

``--own``: judge with the beams at the map's own trajectory (a map made with scan matching;
the stats' ``contradicted_share`` of such a map is against those beams), not the log's poses.

``--chunks N``: replay the log in pieces of N consecutive scans, each into a map of its own
(``replay``'s default settings, or ``--set``), and judge each piece's map with its own beams:
the contradicted share without any second visit.

``--lost REF.json``: the points of LOG (at its poses) that REF covers (within 0.10 m) and MAP
does not, and how many of them the laser sees through: more beams of any other scan pass
through the point than end there (``transient.transient_counts`` with REF as the surface,
``--sample`` of them, seeded), against the same share among the points both cover.

Prints a table per map; ``--json`` writes the per-segment rows.
"""

import argparse
import gzip
import json
import os
import sys
import tempfile

import numpy as np
from polyline_mapper.core.freespace import (_distance_to, judge, MIN_ANGLE, pair_tests, runs,
                                            span_pairs, TOL)
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.poses import se2_compose
from polyline_mapper.scan import scan_to_points
from scipy.spatial import cKDTree

VISIT = 10
"""Scans: a pass this close (in scan index) to a scan ending on the segment is the same visit."""
NEAR = 1.0
"""Metres: median distance beyond the line up to which the passes count as NEAR."""
TWIN_DEG = 15.0
"""Degrees: a map segment this parallel to a contradicted one, that its passes end on, is its
twin (with ``NEAR``)."""
CLASSES = ('near, twin mapped', 'near, same visit', 'near, other visit', 'far, same visit',
           'far, other visit')


def own_beams(trajectory: np.ndarray, log) -> tuple:
    """
    Return ``(points, origins)`` of the log's scans at a map's trajectory, (N, 2) each, metres.

    ``trajectory``: (R, 4) rows (stamp, x, y, yaw) of the robot, one per scan the map used,
    stamped as ``replay`` stamps the log's scans (``CarmenLog.stamps``); scans it did not use
    (not mapped while lost) are left out.
    """
    tr = np.asarray(trajectory, dtype=np.float64)
    stamps = log.stamps()[0]
    row = np.clip(np.searchsorted(stamps, tr[:, 0]), 0, len(stamps) - 1)
    if not np.allclose(stamps[row], tr[:, 0], atol=1e-6):
        raise ValueError("the map's trajectory is not stamped as the log's scans")
    lasers = se2_compose(tr[:, 1:4], np.asarray(log.laser_offset, dtype=np.float64))
    pts, org = [], []
    for rec, pose in zip((log.records[i] for i in row), lasers):
        q = scan_to_points(rec.ranges, rec.angles, pose, 0.0, log.usable_range(rec))
        pts.append(q)
        org.append(np.repeat(pose[None, :2], len(q), axis=0))
    return np.concatenate(pts), np.concatenate(org)


def beam_details(segs: np.ndarray, pts: np.ndarray, org: np.ndarray) -> tuple:
    """
    Return the passes and ends of every beam on ``segs`` (K, 2, 2), as two dicts of arrays.

    Passes: ``seg`` (row of ``segs``), ``scan`` (run of equal origins), ``beam`` (row of
    ``pts``), ``past`` (metres beyond the line); ends: ``seg``, ``scan``. The tests are
    ``freespace.scan_counts``' own.
    """
    passes = {'seg': [], 'scan': [], 'beam': [], 'past': []}
    ends = {'seg': [], 'scan': []}
    min_sin = np.sin(MIN_ANGLE)
    for si, (a, b) in enumerate(runs(org)):
        o = org[a]
        rel = pts[a:b] - o
        rng = np.hypot(rel[:, 0], rel[:, 1])
        w_all = segs[:, 0] - o
        e_all = segs[:, 1] - segs[:, 0]
        near = _distance_to(-w_all, e_all)
        sel = np.flatnonzero(near <= rng.max() + TOL)
        if sel.size == 0:
            continue
        w, e = w_all[sel], e_all[sel]
        for c0, _, k, beam in span_pairs(w, e, rel, TOL, near[sel] <= TOL):
            ww, ee = w[k + c0], e[k + c0]
            through, end = pair_tests(rel[beam], rng[beam], ww, ee, TOL, min_sin)
            if through.any():
                d, r = rel[beam][through], rng[beam][through]
                wt, et = ww[through], ee[through]
                den = d[:, 0] * et[:, 1] - d[:, 1] * et[:, 0]
                sin = np.abs(den) / (r * np.hypot(et[:, 0], et[:, 1]))
                t = (wt[:, 0] * et[:, 1] - wt[:, 1] * et[:, 0]) / den
                passes['seg'].append(sel[k[through] + c0])
                passes['scan'].append(np.full(int(through.sum()), si))
                passes['beam'].append(a + beam[through])
                passes['past'].append((1.0 - t) * r * sin)
            if end.any():
                ends['seg'].append(sel[k[end] + c0])
                ends['scan'].append(np.full(int(end.sum()), si))
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in passes.items()}
    return cat, {k: np.concatenate(v) if v else np.zeros(0) for k, v in ends.items()}


def twin_passes(segs: np.ndarray, pts: np.ndarray, passes: dict, lengths: np.ndarray,
                subset: np.ndarray) -> np.ndarray:
    """Return whether each pass ends on another segment within ``TWIN_DEG`` of its own, (P,)."""
    samples, owner = [], []
    for i, (a, b) in enumerate(segs):
        n = max(2, int(np.ceil(lengths[i] / 0.05)) + 1)
        samples.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
        owner.append(np.full(n, i))
    dist, idx = cKDTree(np.concatenate(samples)).query(pts[passes['beam'].astype(int)])
    j = np.concatenate(owner)[idx]
    i = subset[passes['seg'].astype(int)]
    di, dj = segs[i, 1] - segs[i, 0], segs[j, 1] - segs[j, 0]
    cos = np.abs(np.einsum('ij,ij->i', di, dj)) / np.maximum(
        np.hypot(di[:, 0], di[:, 1]) * np.hypot(dj[:, 0], dj[:, 1]), 1e-12)
    return (dist <= TOL) & (j != i) & (cos >= np.cos(np.deg2rad(TWIN_DEG)))


def classify(segs: np.ndarray, pts: np.ndarray, org: np.ndarray) -> dict:
    """Judge ``segs`` with the beams; return the total length and one row per contradicted."""
    fs = judge(segs, pts, org)
    subset = np.flatnonzero(fs.contradicted)
    passes, ends = beam_details(segs[subset], pts, org)
    twin = twin_passes(segs, pts, passes, fs.lengths, subset)
    rows = []
    for c, seg in enumerate(subset):
        pm, em = passes['seg'] == c, ends['seg'] == c
        ps, end_scans = passes['scan'][pm], np.unique(ends['scan'][em])
        if end_scans.size:
            at = np.clip(np.searchsorted(end_scans, ps), 1, max(len(end_scans) - 1, 1))
            gap = np.minimum(np.abs(ps - end_scans[np.minimum(at - 1, len(end_scans) - 1)]),
                             np.abs(ps - end_scans[np.minimum(at, len(end_scans) - 1)]))
        else:
            gap = np.full(len(ps), np.inf)
        past = float(np.median(passes['past'][pm]))
        same = float(np.mean(gap <= VISIT)) >= 0.5
        if past > NEAR:
            kind = 'far, same visit' if same else 'far, other visit'
        elif float(np.mean(twin[pm])) >= 0.5:
            kind = 'near, twin mapped'
        else:
            kind = 'near, same visit' if same else 'near, other visit'
        rows.append({'seg': int(seg), 'length': float(fs.lengths[seg]),
                     'passes': int(pm.sum()), 'ends': int(em.sum()),
                     'pass_scans': int(np.unique(ps).size), 'end_scans': int(end_scans.size),
                     'past_median': past, 'same_visit': float(np.mean(gap <= VISIT)),
                     'twin': float(np.mean(twin[pm])), 'class': kind})
    return {'total_length': float(fs.lengths.sum()), 'share': fs.share, 'rows': rows}


def table(name: str, result: dict) -> str:
    """Return the classes of ``result`` as lines: share of map length, segments, metres."""
    total = result['total_length']
    lines = [f'{name}: {100 * result["share"]:.2f} % of {total:.0f} m contradicted']
    for kind in CLASSES:
        rows = [r for r in result['rows'] if r['class'] == kind]
        length = sum(r['length'] for r in rows)
        lines.append(f'  {kind:18s} {100 * length / total:6.2f} %  {len(rows):5d} segments '
                     f'{length:7.1f} m')
    return '\n'.join(lines)


def chunks(log_path: str, size: int, overrides: list) -> str:
    """Replay ``size``-scan pieces of the log alone; return their contradicted shares."""
    from polyline_mapper.config import load_mapper_config
    from polyline_mapper.replay import run_replay
    with gzip.open(log_path, 'rt') if log_path.endswith('.gz') else open(log_path) as fh:
        lines = fh.read().splitlines()
    head = [line for line in lines if line.startswith(('PARAM', '#'))]
    scans = [line for line in lines if line.startswith(('FLASER', 'ROBOTLASER1'))]
    config = load_mapper_config(None, overrides)
    total = contradicted = 0.0
    shares = []
    with tempfile.TemporaryDirectory() as tmp:
        for first in range(0, len(scans), size):
            path = os.path.join(tmp, f'piece{first}.log')
            with open(path, 'w') as fh:
                fh.write('\n'.join(head + scans[first:first + size]) + '\n')
            value = run_replay(path, config).map_value
            segs = np.asarray(value.segments, dtype=np.float64).reshape(-1, 2, 2)
            length = float(np.hypot(*(segs[:, 1] - segs[:, 0]).T).sum())
            share = value.stats['contradicted_share']
            total += length
            contradicted += share * length
            shares.append(share)
            print(f'scans {first}-{first + size - 1}: {len(segs)} segments, {length:.0f} m, '
                  f'contradicted {100 * share:.1f} %', file=sys.stderr, flush=True)
    return (f'{len(shares)} pieces of {size} scans, each mapped and judged alone: '
            f'{100 * contradicted / total:.1f} % of their length contradicted (median piece '
            f'{100 * float(np.median(shares)):.1f} %, max {100 * max(shares):.1f} %)')


def lost_points(log, ref: np.ndarray, segs: np.ndarray, sample: int) -> str:
    """Return the points ``ref`` covers and ``segs`` does not, and the share seen through."""
    from polyline_mapper.core.index import nearest_distance
    from transient import transient_counts
    pts, org = log.beams()
    d_ref = nearest_distance(pts, ref, radius=TOL)[0]
    d_new = nearest_distance(pts, segs, radius=TOL)[0]
    lost = np.flatnonzero((d_ref <= TOL) & (d_new > TOL))
    both = np.flatnonzero((d_ref <= TOL) & (d_new <= TOL))
    rng = np.random.default_rng(0)
    text = [f'{len(lost)} of {len(pts)} points ({100 * len(lost) / len(pts):.1f} %) lost']
    for name, idx in (('lost', lost), ('covered by both', both)):
        sub = rng.choice(idx, min(sample, len(idx)), replace=False)
        c = transient_counts(pts, org, sub, ref)
        seen = (c[:, 0] + c[:, 2] >= 1) & (c[:, 0] + c[:, 2] > c[:, 1] + c[:, 3])
        text.append(f'{name}: {100 * float(np.mean(seen)):.1f} % of {len(sub)} seen through')
    return '; '.join(text)


def main() -> int:
    """Classify the contradicted length of each map, or run the pieces."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('log', help='the CARMEN log the maps were made from')
    ap.add_argument('maps', nargs='*', help='map JSON files (replay or fit)')
    ap.add_argument('--own', action='store_true',
                    help="judge with the beams at each map's own trajectory")
    ap.add_argument('--json', help='write the per-segment rows here')
    ap.add_argument('--chunks', type=int, metavar='N',
                    help='map and judge pieces of N scans alone instead')
    ap.add_argument('--lost', metavar='REF.json',
                    help='the points REF covers and each map does not: seen through?')
    ap.add_argument('--sample', type=int, default=20000, help='with --lost: points sampled')
    ap.add_argument('--set', nargs='*', default=[], metavar='KEY=VALUE',
                    help="with --chunks: the mapper's settings, as replay --set takes them")
    args = ap.parse_args()
    if args.chunks:
        print(chunks(args.log, args.chunks, args.set))
        return 0
    log = read_carmen(args.log)
    beams = None if args.own else log.beams()
    out = {}
    for path in args.maps:
        with open(path) as fh:
            data = json.load(fh)
        segs = np.asarray(data['segments'], dtype=np.float64).reshape(-1, 2, 2)
        if args.lost:
            with open(args.lost) as fh:
                ref = np.asarray(json.load(fh)['segments'], dtype=np.float64).reshape(-1, 2, 2)
            print(f'{os.path.basename(path)} against {os.path.basename(args.lost)}: '
                  + lost_points(log, ref, segs, args.sample), flush=True)
            continue
        pts, org = own_beams(data['trajectory'], log) if args.own else beams
        out[path] = classify(segs, pts, org)
        print(table(os.path.basename(path), out[path]), flush=True)
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(out, fh)
    return 0


if __name__ == '__main__':
    sys.exit(main())
