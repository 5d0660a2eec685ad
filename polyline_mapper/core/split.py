"""
LSS: line segment split (method step 2).

Each segment is cut into ``n = max(1, round(L / 2r))`` equal sub-segments of length close to
``2r`` (the remainder is spread over all of them rather than left as a stub at one end). The
support of a sub-segment is the point weight inside the square of side 2r centred on it, two
sides parallel to it (``|normal| <= r`` and the along-position inside the sub-segment).

Threshold C, from the support statistics of each segment (density varies with range and with
how often a place was seen, so one global C would cut sparse far walls and keep bridges over
dense gaps):

- ``lam_j`` = the 80th percentile of segment j's sub-segment supports (its density where it has
  data; at least 1),
- ``C_j = floor(split_fraction * lam_j)``; a sub-segment with support <= C_j is *low*,
- a run of m consecutive low sub-segments is removed only when a run that long is unlikely
  anywhere on the segment under its own density: ``n_j * P(support <= C_j | Poisson(lam_j)) ** m
  <= gap_p`` with n_j sub-segments (a Bonferroni bound over the positions). On a dense wall a
  single empty square splits; on a sparse far wall only a longer gap does.

Connected remainders become the new segments; a segment with no survivors disappears.
"""

import numpy as np
from scipy.stats import poisson

from .geometry import directions, PointIndex


def _runs(flag: np.ndarray, group: np.ndarray) -> tuple:
    """Label runs of equal ``flag`` inside each ``group``; return run id per item and count."""
    start = np.ones(flag.size, dtype=bool)
    start[1:] = (flag[1:] != flag[:-1]) | (group[1:] != group[:-1])
    run = np.cumsum(start) - 1
    return run, int(run[-1]) + 1 if run.size else 0


def split_segments(index: PointIndex, segments: np.ndarray, r: float,
                   split_fraction: float = 0.1, gap_p: float = 1e-3,
                   percentile: float = 80.0) -> tuple:
    """
    Split segments where their support drops (LSS).

    Parameters
    ----------
    index : PointIndex
        The points.
    segments : (K, 2, 2) array
        Metres.
    r : float
        Half the sub-segment length and half the square's side, metres.
    split_fraction : float
        C_j as a fraction of the segment's typical sub-segment support.
    gap_p : float
        Significance of a low run (see the module docstring).
    percentile : float
        Percentile of a segment's sub-segment supports taken as its typical support.

    Returns
    -------
    segments : (K', 2, 2) the surviving pieces.
    parent : (K',) index of the input segment each piece came from.

    """
    k = len(segments)
    if k == 0:
        return np.zeros((0, 2, 2)), np.zeros(0, dtype=np.intp)
    u, length = directions(segments)
    n_sub = np.maximum(1, np.rint(length / (2.0 * r)).astype(np.intp))
    sub_len = length / n_sub
    offset = np.cumsum(n_sub) - n_sub
    total = int(n_sub.sum())
    sub_seg = np.repeat(np.arange(k), n_sub)
    sub_k = np.arange(total) - offset[sub_seg]

    p = index.pairs(segments, r)
    inside = (p.along >= 0) & (p.along <= length[p.seg])
    seg = p.seg[inside]
    kk = np.clip((p.along[inside] / np.where(sub_len[seg] > 0, sub_len[seg], 1.0)).astype(np.intp),
                 0, n_sub[seg] - 1)
    support = np.bincount(offset[seg] + kk, weights=index.weights[p.pt[inside]],
                          minlength=total)

    # Typical support per segment: a within-segment percentile, vectorised by sorting.
    order = np.lexsort((support, sub_seg))
    pos = offset + np.floor((percentile / 100.0) * (n_sub - 1)).astype(np.intp)
    lam = np.maximum(support[order][pos], 1.0)
    c = np.floor(split_fraction * lam)
    p_low = np.clip(poisson.cdf(c, lam), 1e-300, 1.0)
    min_run = np.log(gap_p / n_sub) / np.log(np.minimum(p_low, 1 - 1e-12))

    low = support <= c[sub_seg]
    run, n_runs = _runs(low, sub_seg)
    run_len = np.bincount(run, minlength=n_runs)
    drop = low & (run_len[run] >= min_run[sub_seg])
    keep = ~drop
    if not keep.any():
        return np.zeros((0, 2, 2)), np.zeros(0, dtype=np.intp)

    run, n_runs = _runs(keep, sub_seg)
    kept_runs = np.unique(run[keep])
    first = np.full(n_runs, total, dtype=np.intp)
    last = np.full(n_runs, -1, dtype=np.intp)
    idx = np.arange(total)
    np.minimum.at(first, run, idx)
    np.maximum.at(last, run, idx)
    first, last = first[kept_runs], last[kept_runs]
    parent = sub_seg[first]
    a = segments[parent, 0]
    t0 = (sub_k[first] * sub_len[parent])[:, None]
    t1 = ((sub_k[last] + 1) * sub_len[parent])[:, None]
    pieces = np.stack([a + t0 * u[parent], a + t1 * u[parent]], axis=1)
    return pieces, parent
