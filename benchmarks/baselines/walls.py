"""Wall precision / recall / F1 and end-point error of a segment map against known walls."""

import numpy as np
from polyline_mapper.core.geometry import project, sample_segments
from polyline_mapper.core.index import PointIndex
from scipy.spatial import cKDTree


def split_at_junctions(walls: np.ndarray, tol: float = 1e-6) -> tuple:
    """
    Cut each wall where another wall's end touches its inside (T-junctions).

    A room wall ending on a long outer wall splits it into the pieces a laser sees from
    different rooms; a wall counts as found when one segment covers 80 % of such a piece.

    Returns
    -------
    pieces : (P, 2, 2) metres.
    parent : (P,) index of the wall each piece comes from.

    """
    walls = np.asarray(walls, dtype=np.float64)
    ends = walls.reshape(-1, 2)
    out, parent = [], []
    for i, w in enumerate(walls):
        d, length = w[1] - w[0], np.hypot(*(w[1] - w[0]))
        u = d / length
        rel = ends - w[0]
        t = rel @ u
        off = np.abs(u[0] * rel[:, 1] - u[1] * rel[:, 0])
        cut = np.unique(t[(off < tol) & (t > tol) & (t < length - tol)])
        stops = np.concatenate([[0.0], cut, [length]])
        out += [[w[0] + a * u, w[0] + b * u] for a, b in zip(stops[:-1], stops[1:])]
        parent += [i] * (len(stops) - 1)
    return np.array(out), np.array(parent, dtype=np.intp)


def observed_walls(walls: np.ndarray, points: np.ndarray, tol: float = 0.10,
                   share: float = 0.8, step: float = 0.05) -> np.ndarray:
    """Mask of walls with a data point within ``tol`` of at least ``share`` of their length."""
    samples, owner = sample_segments(walls, step)
    d, _ = cKDTree(points).query(samples, distance_upper_bound=tol)
    seen = (np.bincount(owner, np.isfinite(d).astype(float), len(walls))
            / np.bincount(owner, None, len(walls)))
    return seen >= share


def wall_scores(segments: np.ndarray, walls: np.ndarray, truth_distance=None, tol: float = 0.10,
                cover: float = 0.8, step: float = 0.02, points: np.ndarray = None) -> dict:
    """
    Wall recall, segment precision, F1 and end-point error.

    - A wall is found when ONE segment lies within ``tol`` of at least ``cover`` of the wall's
      length (samples every ``step`` m). Recall = found walls / walls.
    - A segment is correct when at least ``cover`` of its length lies within ``tol`` of the true
      geometry (``truth_distance(points) -> (M,)`` metres, e.g. ``World.distance`` so that
      chains along curved walls count; default: distance to ``walls``). Precision = correct
      segments / segments.
    - Walls are first cut at T-junctions (``split_at_junctions``); precision, recall and F1
      count the pieces. Given the data ``points``, a piece no scan saw (``observed_walls``:
      points within ``tol`` of less than ``cover`` of it, e.g. a room corner closed off behind
      a slanted wall) is left out: no method can find it.
    - End-point error: at each end of an uncut wall with a found piece (corners, door jambs,
      free ends), the distance to the nearest end of a segment running along that wall (both
      ends within ``tol`` of its line, within 10 degrees); median and mean over those ends.

    Returns
    -------
    dict with precision, recall, f1, found, walls, end_error_median, end_error_mean (metres).

    """
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    whole = np.asarray(walls, dtype=np.float64).reshape(-1, 2, 2)
    walls, parent = split_at_junctions(whole) if len(whole) else (whole, np.zeros(0, int))
    if points is not None and len(walls):
        seen = observed_walls(walls, np.asarray(points, dtype=np.float64), tol, cover)
        walls, parent = walls[seen], parent[seen]
    nw, k = len(walls), len(segs)
    out = {'walls': nw, 'segments': k, 'found': 0, 'precision': 0.0, 'recall': 0.0, 'f1': 0.0,
           'end_error_median': float('nan'), 'end_error_mean': float('nan')}
    if nw == 0 or k == 0:
        return out
    samples, owner = sample_segments(walls, step)
    per_wall = np.bincount(owner, minlength=nw)
    p = PointIndex(samples).pairs(segs, tol)
    key = owner[p.pt] * k + p.seg
    uniq, cnt = np.unique(key, return_counts=True)
    frac = cnt / per_wall[uniq // k]
    best = np.zeros(nw)
    best_seg = np.full(nw, -1)
    order = np.argsort(frac)
    best[uniq[order] // k] = frac[order]
    best_seg[uniq[order] // k] = uniq[order] % k
    found = best >= cover
    if truth_distance is None:
        def truth_distance(q):
            d, _, _ = project(np.repeat(q, nw, axis=0), np.tile(walls, (len(q), 1, 1)))
            return d.reshape(len(q), nw).min(axis=1)
    ss, so = sample_segments(segs, step)
    near = np.concatenate([truth_distance(ss[i:i + 20000]) <= tol
                           for i in range(0, len(ss), 20000)])
    good = np.bincount(so, near.astype(float), k) / np.bincount(so, None, k) >= cover
    prec, rec = float(good.mean()), float(found.mean())
    out.update(found=int(found.sum()), precision=prec, recall=rec,
               f1=0.0 if prec + rec == 0 else 2 * prec * rec / (prec + rec))
    errors = []
    su, sl = segs[:, 1] - segs[:, 0], np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
    for w in whole[np.unique(parent[found])]:
        d = w[1] - w[0]
        u = d / np.hypot(*d)
        rel = segs - w[0]
        off = np.abs(u[0] * rel[..., 1] - u[1] * rel[..., 0]).max(axis=1)
        cos = np.abs(su @ u) / np.maximum(sl, 1e-12)
        ok = (off <= tol) & (cos >= np.cos(np.deg2rad(10.0)))
        if not ok.any():
            continue
        cand = segs[ok].reshape(-1, 2)
        for end in w:
            errors.append(float(np.min(np.linalg.norm(cand - end, axis=1))))
    if errors:
        out.update(end_error_median=float(np.median(errors)),
                   end_error_mean=float(np.mean(errors)))
    return out
