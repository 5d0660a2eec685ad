"""
LSS: line segment split (method step 2).

Each segment is cut into ``n = max(1, round(L / 2r))`` equal sub-segments of length close to
``2r`` (the remainder is spread over all of them rather than left as a stub at one end). The
support of a sub-segment is the point weight inside the square of side 2r centred on it, two
sides parallel to it (``|normal| <= r`` and the along-position inside the sub-segment).

Threshold C, from the support statistics of the squares around each square (density varies
with range, incidence and how often a place was seen, along one wall as much as between walls,
so neither one global C nor one C per segment works):

- ``lam_i`` = the larger of the mean supports of the 8 squares before and the 8 after square i
  on its segment (its expected support; at least 1),
- ``C_i = floor(split_fraction * lam_i)``; a square with support <= C_i is *low*,
- a run of consecutive low squares is removed only when it is unlikely anywhere on the segment
  under those expectations: ``n_j * prod_i P(support <= C_i | Poisson(lam_i)) <= gap_p`` over the
  run, with n_j squares on the segment (a Bonferroni bound over the positions). On a dense wall a
  single empty square splits; on a sparse far wall only a longer gap does; where density falls
  off gradually (a wall running away from the sensor) nothing is low.

Connected remainders become the new segments; a segment with no survivors disappears.

In incremental mapping (``incremental.py``) squares holding virtual points, the old map, are never
low: they were tested when observed, and a sparse new look is no evidence that a wall is gone
(that would need free-space evidence from ray casting). LSS cuts new extensions and new segments.
"""

import numpy as np
from scipy.special import pdtr

from .geometry import directions, group_minmax, label_runs
from .index import Pairs, PointIndex


def _flank_level(support, group, pos, n, flank):
    """Larger of the mean supports of the ``flank`` items before and after each, per group."""
    csum = np.concatenate([[0.0], np.cumsum(support)])
    idx = np.arange(support.size)
    start = idx - pos                         # first item of the group
    stop = start + n[group]                   # one past its last item
    lo = np.maximum(idx - flank, start)
    hi = np.minimum(idx + 1 + flank, stop)
    left = (csum[idx] - csum[lo]) / np.maximum(idx - lo, 1)
    right = (csum[hi] - csum[idx + 1]) / np.maximum(hi - idx - 1, 1)
    return np.maximum(np.maximum(left, right), 1.0)


def split_segments(index: PointIndex, segments: np.ndarray, r: float,
                   split_fraction: float = 0.1, gap_p: float = 1e-3,
                   flank: int = 8, query_radius: float = 0.0,
                   return_pairs: bool = False) -> tuple:
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
    flank : int
        Squares on each side whose mean support is a square's expected support.
    query_radius : float
        Query the point-segment pairs out to at least this distance (m), for the caller to
        derive the pieces' pairs from (``index.piece_pairs``); the split itself uses those
        within r (2r with an old map present, for the span its virtual points hold).
    return_pairs : bool
        Also return those pairs and where each piece starts on its parent.

    Returns
    -------
    segments : (K', 2, 2) the surviving pieces.
    parent : (K',) index of the input segment each piece came from.
    pairs : Pairs of the input segments (only with ``return_pairs``).
    start : (K',) along-position of each piece's first end on its parent, metres (only with
        ``return_pairs``).

    """
    k = len(segments)
    none = (np.zeros((0, 2, 2)), np.zeros(0, dtype=np.intp))
    if k == 0:
        return none + ((Pairs(*(np.zeros(0, dtype=np.intp),) * 2, *(np.zeros(0),) * 3),
                        np.zeros(0)) if return_pairs else ())
    u, length = directions(segments)
    n_sub = np.maximum(1, np.rint(length / (2.0 * r)).astype(np.intp))
    sub_len = length / n_sub
    offset = np.cumsum(n_sub) - n_sub
    total = int(n_sub.sum())
    sub_seg = np.repeat(np.arange(k), n_sub)
    sub_k = np.arange(total) - offset[sub_seg]

    incremental = index.n_real < len(index)
    own = 2.0 * r if incremental else r
    queried = index.pairs(segments, max(own, query_radius))
    p = queried
    if query_radius > own:
        near = np.flatnonzero(queried.dist <= own)
        p = Pairs(*(np.take(a, near) for a in (
            queried.pt, queried.seg, queried.dist, queried.along, queried.normal)))
    sq = np.flatnonzero((p.along >= 0) & (p.along <= length.take(p.seg))
                        & (np.abs(p.normal) <= r))
    seg = p.seg.take(sq)
    safe_len = np.where(sub_len > 0, sub_len, 1.0)
    kk = np.clip((p.along.take(sq) / safe_len.take(seg)).astype(np.intp), 0, n_sub.take(seg) - 1)
    support = np.bincount(offset.take(seg) + kk, weights=index.weights.take(p.pt.take(sq)),
                          minlength=total)

    # Expected support of each square from its flanks: the larger of the mean supports of the
    # `flank` squares before and after it, within its segment (at least 1).
    lam = _flank_level(support, sub_seg, sub_k, n_sub, flank)
    c = np.floor(split_fraction * lam)
    low = support <= c
    if incremental:
        # Squares within the span the old map's virtual points cover on a segment were tested
        # when they were observed; a sparse new look at them is no evidence that the wall is
        # gone: never low. (The span, not each square's count: virtual points and squares are
        # both about 2r apart and their phases drift. Within 2r of the line: a refit may tilt a
        # long wall a little.)
        # Projections are taken with a float tolerance: a virtual point sampled at a segment's
        # end projects to -1e-17 as often as to 0, and must still hold the end square.
        tol = 1e-9 * np.maximum(length[p.seg], 1.0)
        virtual = ((p.pt >= index.n_real) & (p.along >= -tol)
                   & (p.along <= length[p.seg] + tol))
        vlo, vhi = group_minmax(np.clip(p.along[virtual], 0.0, length[p.seg[virtual]]),
                                p.seg[virtual], k)
        centre = (sub_k + 0.5) * sub_len[sub_seg]
        held = (centre >= vlo[sub_seg] - 0.5 * sub_len[sub_seg]) & \
               (centre <= vhi[sub_seg] + 0.5 * sub_len[sub_seg])
        low &= ~held
    # A run of low squares is a gap when its probability under the local levels, summed over
    # the run in logs, is below gap_p / (squares in the segment).
    logp = np.zeros(total)
    logp[low] = np.log(np.clip(pdtr(c[low], lam[low]), 1e-300, 1.0))
    run, n_runs = label_runs(low, sub_seg)
    run_logp = np.bincount(run, weights=logp, minlength=n_runs)
    drop = low & (run_logp[run] <= np.log(gap_p / n_sub[sub_seg]))
    keep = ~drop
    if not keep.any():
        return none + ((queried, np.zeros(0)) if return_pairs else ())

    run, n_runs = label_runs(keep, sub_seg)
    kept_runs = run[keep]                      # non-decreasing: runs are numbered in order
    kept_runs = kept_runs[np.append(True, kept_runs[1:] != kept_runs[:-1])]
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
    if return_pairs:
        return pieces, parent, queried, t0[:, 0]
    return pieces, parent
