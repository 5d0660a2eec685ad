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
low: they were tested when observed, and a sparse new look is no evidence that a wall is gone.
LSS cuts new extensions and new segments.

Free-space evidence (``IncrementalConfig.free_space_window`` > 0): the same squares also count
the beams that end on them (hits) and pass through them (passes, ``cleanup.beam_evidence``),
as bounded, decaying counts (``accumulate_evidence``). A square whose passes outweigh its hits
(``free_squares``) is removed like a low square (``cut_squares``), whatever the segment's
length: a wall splits at a doorway, a door leaf or a person's track goes. The counts are kept per
square and follow the segments through refits, splits and merges (``carry_evidence``: each new
square takes the counts of the nearest old square, if close and parallel).
"""

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import pdtr

from .geometry import directions, group_minmax, label_runs
from .index import Pairs, PointIndex


EVIDENCE_CAP = 50.0
"""Largest hit or pass count of one square: the evidence a square holds is bounded, so a wall
seen a thousand times is removed after tens of scans that see through it, not a thousand."""

EVIDENCE_WINDOW = 10
"""Looks at a square over which its evidence decays in a batch fit with beams (the incremental
mapper's ``free_space_window`` when that is on)."""

MIN_PASSES = 3.0
"""A square is free only once at least this many (decayed) beams passed through it."""


def square_layout(segments: np.ndarray, r: float) -> tuple:
    """
    Return the LSS squares of each segment: ``(n_sub, sub_len)``, (K,) each.

    Segment k is cut into ``n_sub[k] = max(1, round(L / 2r))`` equal squares of length
    ``sub_len[k]`` (the remainder spread over all of them).
    """
    _, length = directions(segments)
    n_sub = np.maximum(1, np.rint(length / (2.0 * r)).astype(np.intp))
    return n_sub, length / n_sub


def square_centres(segments: np.ndarray, n_sub: np.ndarray) -> tuple:
    """Return the centre (M, 2) and the unit direction (M, 2) of every square, segment order."""
    u, length = directions(segments)
    k = np.repeat(np.arange(len(segments)), n_sub)
    i = np.arange(k.size) - np.repeat(np.cumsum(n_sub) - n_sub, n_sub)
    t = (i + 0.5) * (length / np.maximum(n_sub, 1)).take(k)
    uk = u.take(k, axis=0)
    return segments[:, 0].take(k, axis=0) + t[:, None] * uk, uk


def carry_evidence(centres: np.ndarray, dirs: np.ndarray, counts: np.ndarray,
                   segments: np.ndarray, n_sub: np.ndarray, r: float,
                   max_angle: float = np.deg2rad(30.0), return_source: bool = False):
    """
    Carry per-square evidence from old squares to the squares of new segments.

    ``centres`` (M, 2), ``dirs`` (M, 2) and ``counts`` (M, C) describe the old squares (of the
    segments a refit replaced: moved, split, merged, grown). Each new square takes the counts of
    the nearest old square centre within 1.5 ``r`` of its own centre (a refit moves a wall by
    less than r across it and shifts its squares by at most one along it) whose direction is
    within ``max_angle`` of its segment's; so a merge of twins does not add their counts up and
    a crossing wall's squares are not taken. New squares with no such old square (a wall's new
    extension) start at 0. Returns (n_sub.sum(), C); with ``return_source`` also the old
    square each new one took its counts from ((n_sub.sum(),), -1 for none).
    """
    total = int(np.sum(n_sub))
    out = np.zeros((total, counts.shape[1]))
    source = np.full(total, -1, dtype=np.intp)
    if total == 0 or len(centres) == 0:
        return (out, source) if return_source else out
    mine, u = square_centres(segments, n_sub)
    dist, j = cKDTree(centres).query(mine, k=1, distance_upper_bound=1.5 * r)
    ok = np.flatnonzero(np.isfinite(dist))
    ok = ok[np.abs(np.sum(dirs[j[ok]] * u[ok], axis=1)) >= np.cos(max_angle)]
    out[ok] = counts[j[ok]]
    if return_source:
        source[ok] = j[ok]
        return out, source
    return out


def accumulate_evidence(counts: np.ndarray, hits: np.ndarray, passes: np.ndarray,
                        window: float, cap: float = EVIDENCE_CAP) -> np.ndarray:
    """
    Add one scan's beams to the per-square counts: returns the new (M, 2) [hits, passes].

    Squares the scan observed (a hit or a pass) first forget 1 / ``window`` of what they held,
    then add the scan's counts, each capped at ``cap``; unobserved squares keep theirs (a wall
    out of view is not forgotten). So evidence is bounded and reflects about the last
    ``window`` looks at a square, and a square hit many times (up to the cap) needs many passes,
    over several scans, before it is free: a person walking in front of a wall adds nothing to
    it (beams ending before a square say nothing), a door that opened is free after a few looks.
    """
    seen = (hits + passes) > 0
    out = counts * np.where(seen, 1.0 - 1.0 / window, 1.0)[:, None]
    out[:, 0] += hits
    out[:, 1] += passes
    return np.minimum(out, cap, out=out)


def free_squares(counts: np.ndarray, min_passes: float = MIN_PASSES) -> np.ndarray:
    """Squares whose pass evidence outweighs their hits: passes >= min_passes and > hits."""
    return (counts[:, 1] >= min_passes) & (counts[:, 1] > counts[:, 0])


def cut_squares(segments: np.ndarray, n_sub: np.ndarray, keep: np.ndarray) -> tuple:
    """
    Remove squares from segments: every run of kept squares becomes a piece.

    ``keep`` is a (n_sub.sum(),) mask in segment order. Returns ``(pieces (P, 2, 2), parent
    (P,), first (P,), last (P,))``: each piece's segment, and its first and last square as
    indices into the flat square order. A segment keeping all its squares comes back unchanged
    (bit for bit); one keeping none is gone.
    """
    k = len(segments)
    sub_seg = np.repeat(np.arange(k), n_sub)
    sub_k = np.arange(sub_seg.size) - np.repeat(np.cumsum(n_sub) - n_sub, n_sub)
    run, n_runs = label_runs(keep, sub_seg)
    if not keep.any():
        e = np.zeros(0, dtype=np.intp)
        return np.zeros((0, 2, 2)), e, e, e
    # Runs are numbered in order, so each starts where the run number steps and ends before
    # the next one starts.
    start = np.flatnonzero(np.diff(run, prepend=-1))
    stop = np.append(start[1:], run.size) - 1
    kept_runs = np.flatnonzero(keep.take(start))
    first, last = start.take(kept_runs), stop.take(kept_runs)
    parent = sub_seg.take(first)
    u, length = directions(segments)
    sub_len = length / np.maximum(n_sub, 1)
    up, lp = u.take(parent, axis=0), sub_len.take(parent)
    a = segments[:, 0].take(parent, axis=0)
    whole = (sub_k.take(first) == 0) & (sub_k.take(last) == n_sub.take(parent) - 1)
    pieces = np.empty((len(parent), 2, 2))
    pieces[:, 0] = a + (sub_k.take(first) * lp)[:, None] * up
    pieces[:, 1] = a + ((sub_k.take(last) + 1) * lp)[:, None] * up
    pieces[whole] = segments[parent[whole]]
    return pieces, parent, first, last


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
        p = queried.where(queried.dist <= own)
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
