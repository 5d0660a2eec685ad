"""
Plain EM line fitting: a fixed number of segments, or the number chosen by BIC.

The model is the one EM line extraction uses (e.g. Sack and Burgard, IAV 2004; the EMSF step
of Latecki et al. 2006 without split and merge): each point belongs to one of K segments with a
Gaussian orthogonal error of scale ``sigma``, or to a uniform outlier class.

- E-step: responsibilities from the point-to-SEGMENT distance, exp(-d^2 / 2 sigma^2), normalised
  per point together with an outlier class at the kernel value of ``kappa`` sigma. Pairs farther
  than ``kappa`` sigma get weight 0 (they would underflow against the outlier class anyway), so
  the step is sparse and scales to big maps.
- M-step: weighted orthogonal regression per segment (weighted mean, major axis of the weighted
  scatter).
- Trim: each segment becomes the shortest piece of its new line holding the projections of its
  MAP support (the points it explains best). A segment left with fewer than 3 points is
  re-seeded at a random unexplained point, so K stays fixed.
- Seeds: K cells of a 0.5 m grid, chosen at random among the occupied ones (so seeds spread over
  space, not over point density), each a short segment fitted to its 15 nearest points.
"""

from dataclasses import dataclass, field
import time

import numpy as np
from polyline_mapper.core.geometry import as_points, lengths
from polyline_mapper.core.index import PointIndex

from .lines import line_segments

MIN_SUPPORT = 3


@dataclass
class EMResult:
    """The best fit found: segments, iterations of its run, log-likelihood, BIC and K path."""

    segments: np.ndarray
    """(K, 2, 2) metres."""
    iterations: int
    log_likelihood: float
    bic: float = float('nan')
    path: list = field(default_factory=list)
    """For em_bic: one dict per K tried (k, segments, log_likelihood, bic, seconds)."""
    timed_out: bool = False


def _map_pairs(p, n: int) -> tuple:
    """Index of each point's nearest pair (MAP support) and the per-point nearest distance."""
    order = np.lexsort((p.dist, p.pt))
    pts = p.pt[order]
    first = np.ones(pts.size, dtype=bool)
    first[1:] = pts[1:] != pts[:-1]
    is_map = np.zeros(p.pt.size, dtype=bool)
    is_map[order[first]] = True
    d = np.full(n, np.inf)
    d[p.pt[is_map]] = p.dist[is_map]
    return is_map, d


def seed_segments(points: np.ndarray, centres: np.ndarray, tree,
                  neighbours: int = 15) -> np.ndarray:
    """Short segments fitted to the ``neighbours`` nearest points of each centre, (C, 2, 2)."""
    if len(centres) == 0:
        return np.zeros((0, 2, 2))
    kk = min(neighbours, len(points))
    _, nn = tree.query(centres, k=kk)
    nn = np.asarray(nn).reshape(len(centres), kk)
    labels = np.repeat(np.arange(len(centres)), kk)
    seg, _ = line_segments(points, labels, len(centres), support=nn.ravel())
    return seg


def spread_centres(points: np.ndarray, k: int, rng, cell: float = 0.5,
                   among: np.ndarray = None) -> np.ndarray:
    """``k`` points in distinct ``cell`` grid cells where possible (from ``among`` indices)."""
    idx = np.arange(len(points)) if among is None else among
    if idx.size == 0 or k <= 0:
        return np.zeros((0, 2))
    keys = np.floor(points[idx] / cell).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    cand = idx[first]
    pick = rng.choice(cand.size, size=k, replace=cand.size < k)
    return points[cand[pick]]


def log_likelihood(points: np.ndarray, segments: np.ndarray, sigma: float,
                   index: PointIndex = None) -> float:
    """
    Log-likelihood of the points under the segment mixture with a uniform outlier class.

    A segment of length L has the density exp(-d^2 / 2 sigma^2) / (L sigma sqrt(2 pi) +
    2 pi sigma^2) (a Gaussian tube with round caps, normalised over the plane); mixing weights
    are the MAP support shares; outliers (no segment within 5 sigma, at least 0.1 %) are uniform
    over the bounding box.
    """
    n = len(points)
    index = index if index is not None else PointIndex(points)
    area = max(float(np.prod(np.ptp(points, axis=0) + 10 * sigma)), 1e-6)
    if len(segments) == 0:
        return float(n * np.log(1.0 / area))
    p = index.pairs(segments, 5.0 * sigma)
    is_map, _ = _map_pairs(p, n)
    nk = np.bincount(p.seg[is_map], minlength=len(segments)).astype(float)
    n0 = n - nk.sum()
    pi0 = max(n0 / n, 1e-3)
    pik = nk / n * (1.0 - pi0) / max(nk.sum() / n, 1e-12)
    norm = lengths(segments) * sigma * np.sqrt(2 * np.pi) + 2 * np.pi * sigma ** 2
    g = np.exp(-0.5 * (p.dist / sigma) ** 2) / norm[p.seg]
    dens = np.bincount(p.pt, pik[p.seg] * g, n) + pi0 / area
    return float(np.log(dens).sum())


def bic_score(log_lik: float, k: int, n: int) -> float:
    """BIC = -2 log L + 5 K ln N (4 end-point coordinates and a mixing weight per segment)."""
    return float(-2.0 * log_lik + 5.0 * k * np.log(max(n, 2)))


def _em_run(points, index, segs, sigma, kappa, max_iter, tol, rng, deadline):
    """One EM run from ``segs``; return (segments, iterations, timed_out)."""
    n, k = len(points), len(segs)
    radius = kappa * sigma
    out_w = np.exp(-0.5 * kappa ** 2)
    prev = np.full(n, -2, dtype=np.intp)
    it = 0
    for it in range(1, max_iter + 1):
        p = index.pairs(segs, radius)
        lw = np.exp(-0.5 * (p.dist / sigma) ** 2)
        w = lw / (np.bincount(p.pt, lw, n) + out_w)[p.pt]
        is_map, d = _map_pairs(p, n)
        new, _ = line_segments(points, p.seg, k, weights=w, support=p.pt, trim=is_map)
        count = np.bincount(p.seg[is_map], minlength=k)
        dead = np.flatnonzero((count < MIN_SUPPORT) | ~np.isfinite(new).all(axis=(1, 2)))
        if dead.size:
            lonely = np.flatnonzero(~np.isfinite(d))
            centres = spread_centres(points, dead.size, rng,
                                     among=lonely if lonely.size else None)
            new[dead] = seed_segments(points, centres, index.tree)
        segs = new
        label = np.full(n, -1, dtype=np.intp)
        label[p.pt[is_map]] = p.seg[is_map]
        if dead.size == 0 and np.mean(label != prev) <= tol:
            break
        prev = label
        if deadline is not None and time.perf_counter() > deadline:
            return segs, it, True
    return segs, it, False


def em_lines(points, k: int, sigma: float, restarts: int = 3, max_iter: int = 100,
             kappa: float = 3.0, tol: float = 1e-3, rng=0, init: np.ndarray = None,
             deadline: float = None, index: PointIndex = None) -> EMResult:
    """
    Fit exactly ``k`` segments by EM, best of ``restarts`` random seedings (by log-likelihood).

    Parameters
    ----------
    points
        (N, 2) metres.
    k
        Number of segments (>= 1).
    sigma
        Noise scale (m) of the E-step kernel.
    restarts
        Independent seedings; the one with the highest log-likelihood wins.
    init
        (k, 2, 2) start segments for the first run instead of a random seeding.
    kappa
        E-step cut-off and outlier level, in sigmas.
    max_iter, tol
        Iteration cap, and the share of points changing their MAP segment that stops a run
        (segments grow by at most kappa sigma per iteration, so a run goes on while they do).
    rng
        Seed or numpy Generator.
    deadline
        A time.perf_counter() value after which runs stop early (result flagged).
    index
        A PointIndex of ``points`` to reuse, or None.

    Returns
    -------
    EMResult; segments that end without support are dropped (rare: they are re-seeded).

    """
    pts = as_points(points)
    if int(k) != k or k < 1:
        raise ValueError(f'k must be an integer >= 1, got {k!r}')
    if not sigma > 0:
        raise ValueError(f'sigma must be > 0, got {sigma!r}')
    if len(pts) < 2:
        raise ValueError('need at least 2 points')
    rng = np.random.default_rng(rng)
    index = index if index is not None else PointIndex(pts)
    best = None
    for run in range(max(1, restarts)):
        if run == 0 and init is not None:
            start = np.asarray(init, dtype=np.float64)
        else:
            start = seed_segments(pts, spread_centres(pts, int(k), rng), index.tree)
        segs, its, late = _em_run(pts, index, start, sigma, kappa, max_iter, tol, rng, deadline)
        segs = segs[np.isfinite(segs).all(axis=(1, 2))]
        ll = log_likelihood(pts, segs, sigma, index)
        if best is None or ll > best.log_likelihood:
            best = EMResult(segs, its, ll, bic_score(ll, len(segs), len(pts)), timed_out=late)
        if late:
            best.timed_out = True
            break
    return best


def em_bic(points, sigma: float, k_start: int = 2, growth: float = 1.25, patience: int = 3,
           k_max: int = 5000, max_iter: int = 100, kappa: float = 3.0, rng=0,
           deadline: float = None) -> EMResult:
    """
    EM with the number of segments chosen by BIC: grow K until BIC stops improving.

    K starts at ``k_start`` and grows by max(1, (growth - 1) K) segments per step; each step is
    warm-started from the previous fit plus new seeds at unexplained points (farther than
    ``kappa`` sigma from every segment; random points when there are none). The search stops
    after ``patience`` steps without a lower BIC, at ``k_max`` or at the deadline; the fit with
    the lowest BIC is returned with the whole path.
    """
    pts = as_points(points)
    rng = np.random.default_rng(rng)
    index = PointIndex(pts)
    n = len(pts)
    best, path, prev = None, [], None
    k, worse = int(k_start), 0
    while k <= k_max:
        t0 = time.perf_counter()
        if prev is None:
            init = seed_segments(pts, spread_centres(pts, k, rng), index.tree)
        else:
            p = index.pairs(prev, kappa * sigma)
            _, d = _map_pairs(p, n)
            lonely = np.flatnonzero(~np.isfinite(d))
            extra = seed_segments(pts, spread_centres(pts, k - len(prev), rng,
                                                      among=lonely if lonely.size else None),
                                  index.tree)
            init = np.concatenate([prev, extra])
        res = em_lines(pts, k, sigma, restarts=1, max_iter=max_iter, kappa=kappa, rng=rng,
                       init=init, deadline=deadline, index=index)
        path.append({'k': k, 'segments': len(res.segments), 'log_likelihood': res.log_likelihood,
                     'bic': res.bic, 'seconds': time.perf_counter() - t0})
        if best is None or res.bic < best.bic:
            best, worse = res, 0
        else:
            worse += 1
        prev = res.segments
        if worse >= patience or res.timed_out:
            break
        k = max(k + 1, int(np.ceil(k * growth)))
    best.path = path
    best.timed_out = bool(path and deadline is not None and time.perf_counter() > deadline)
    return best
