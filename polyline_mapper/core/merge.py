"""
Merging by perceptual grouping (method step 4).

Merged segment ms(L1, L2) exactly as the paper builds it: with L1 = AB and L2 = CD oriented so
that AB . CD >= 0, its direction is that of AB + CD (the longer segment weighs more), its line is
placed between the two midpoints so that d1 * l1 = d2 * l2 (closer to the longer one), and it is
the shortest piece of that line that holds the projections of A, B, C and D.

Cost, with the paper's weights: ``cost = 2 * parC + 1/4 * colC + 1/2 * proxC``. The three terms
are our own (the paper cites a reference we do not have), dimensionless, each about 1 where it
alone starts to argue against grouping:

- ``parC = theta / theta_ref``: angle between the two segments over a reference angle
  (default 10 degrees).
- ``colC = e / sigma``: the largest distance of A, B, C, D from the merged line, in units of
  the current noise scale sigma; two pieces of one wall have e of about one sigma.
- ``proxC = g / (g + min(l1, l2))``: the gap g between the two projections on the merged line
  relative to the shorter segment (Lowe's proximity: a gap matters relative to what it
  separates); 0 when the projections overlap, tending to 1 for a gap much longer than the
  shorter segment.

A pair with a segment shorter than 8 r that narrowly fails (cost < 3) gets a second chance from
the data: it merges when the merged segment keeps 90 % of both supports within 2 sigma (short
pieces fitted at junctions are tilted by the other wall's points, so their angle misleads).

A pair merges when its cost is below ``merge_threshold`` (default 1) and, if the gap is longer
than r, the gap is backed by data: the gap is tiled with squares of side 2r (approximated by
disks of radius r) and the same Poisson gap test as in LSS must not find a significant run of
low squares there. Without that test a door opening between two collinear walls would be bridged,
and a planner would see the door closed.

Candidate pairs come from a k-d tree over points sampled along the segments (an exact all-pairs
test only for sets of at most 64 segments, where it is cheaper). Merging is greedy by increasing
cost, each segment at most once per round, rounds repeated until nothing merges; after the first
round only pairs that involve a newly merged segment are examined, since nothing else changed.
"""

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import pdtr

from .geometry import directions, label_runs, lengths, project, sample_segments
from .index import PointIndex, unique_counts


def merged_segment(s1: np.ndarray, s2: np.ndarray) -> dict:
    """
    Build the paper's merged segment of pairs of segments, with the quantities the cost needs.

    Parameters
    ----------
    s1 : (M, 2, 2) array
        First segment of each pair, metres.
    s2 : (M, 2, 2) array
        Second segment of each pair, metres.

    Returns
    -------
    dict with ``segment`` (M, 2, 2), ``theta`` (M,) radians in [0, pi/2], ``offset`` (M,) largest
    end-point distance from the merged line, ``gap`` (M,) metres between the projections,
    ``gap_ends`` (M, 2, 2) the gap's end points on the merged line, ``l1``, ``l2`` (M,) lengths.

    """
    d1 = s1[:, 1] - s1[:, 0]
    d2 = s2[:, 1] - s2[:, 0]
    flip = np.einsum('ij,ij->i', d1, d2) < 0
    s2 = np.where(flip[:, None, None], s2[:, ::-1], s2)
    d2 = np.where(flip[:, None], -d2, d2)
    # Reductions over the short axes (2 coordinates, 2 or 4 ends) column by column: NumPy runs
    # them one row at a time. The same arithmetic: norm(d, axis=1) is sqrt(0 + x x + y y), and
    # mean(axis=1) is (0 + a + b) / 2.
    d1x, d1y, d2x, d2y = d1[:, 0], d1[:, 1], d2[:, 0], d2[:, 1]
    l1 = np.sqrt(d1x * d1x + d1y * d1y)
    l2 = np.sqrt(d2x * d2x + d2y * d2y)
    v = d1 + d2
    vn = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1])
    u = np.where(vn[:, None] > 0, v / np.where(vn > 0, vn, 1.0)[:, None], [1.0, 0.0])
    n = np.empty_like(u)
    n[:, 0] = -u[:, 1]
    n[:, 1] = u[:, 0]
    m1 = (0.0 + s1[:, 0] + s1[:, 1]) / 2
    m2 = (0.0 + s2[:, 0] + s2[:, 1]) / 2
    wsum = np.where(l1 + l2 > 0, l1 + l2, 1.0)
    c = (l1 * np.einsum('ij,ij->i', n, m1) + l2 * np.einsum('ij,ij->i', n, m2)) / wsum
    ends = np.concatenate([s1, s2], axis=1)                      # (M, 4, 2): A, B, C, D
    t = np.einsum('mkj,mj->mk', ends, u)
    off = np.abs(np.einsum('mkj,mj->mk', ends, n) - c[:, None])
    e = np.maximum(np.maximum(np.maximum(off[:, 0], off[:, 1]), off[:, 2]), off[:, 3])
    base = c[:, None] * n
    lo1, hi1 = np.minimum(t[:, 0], t[:, 1]), np.maximum(t[:, 0], t[:, 1])
    lo2, hi2 = np.minimum(t[:, 2], t[:, 3]), np.maximum(t[:, 2], t[:, 3])
    seg = np.empty((len(t), 2, 2))
    seg[:, 0] = base + np.minimum(lo1, lo2)[:, None] * u
    seg[:, 1] = base + np.maximum(hi1, hi2)[:, None] * u
    g0 = np.minimum(hi1, hi2)
    g1 = np.maximum(lo1, lo2)
    gap = np.maximum(0.0, g1 - g0)
    gap_ends = np.empty((len(t), 2, 2))
    gap_ends[:, 0] = base + g0[:, None] * u
    gap_ends[:, 1] = base + g1[:, None] * u
    cosang = np.abs(np.einsum('ij,ij->i', d1, d2)) / np.where(l1 * l2 > 0, l1 * l2, 1.0)
    theta = np.arccos(np.clip(cosang, 0.0, 1.0))
    return {'segment': seg, 'theta': theta, 'offset': e, 'gap': gap, 'gap_ends': gap_ends,
            'l1': l1, 'l2': l2}


def grouping_cost(ms: dict, sigma: float, theta_ref: float) -> np.ndarray:
    """Perceptual-grouping cost 2 parC + 1/4 colC + 1/2 proxC of merged pairs (dimensionless)."""
    par = ms['theta'] / theta_ref
    col = ms['offset'] / sigma
    short = np.minimum(ms['l1'], ms['l2'])
    prox = ms['gap'] / np.where(ms['gap'] + short > 0, ms['gap'] + short, 1.0)
    return 2.0 * par + 0.25 * col + 0.5 * prox


def candidate_pairs(segments: np.ndarray, reach: float, among: np.ndarray = None,
                    dense_below: int = 64) -> np.ndarray:
    """
    Pairs (i < j) of segments that come within about ``reach`` of each other, shape (M, 2).

    With ``among`` (a bool mask), only pairs with at least one segment in it. When there are
    few pairs to test (at most ``dense_below ** 2``) each is tested exactly (cheaper than a
    tree); otherwise a k-d tree over points sampled along the segments finds them.
    """
    k = len(segments)
    if k < 2:
        return np.zeros((0, 2), dtype=np.intp)
    tested = k if among is None else int(np.count_nonzero(among))
    if tested * k <= dense_below ** 2:
        if among is None:
            i, j = np.triu_indices(k, 1)
        else:
            f = np.flatnonzero(among)
            i, j = np.repeat(f, k), np.tile(np.arange(k), f.size)
            ok = (j != i) & ~(among[j] & (j < i))            # each unordered pair once
            i, j = np.minimum(i[ok], j[ok]), np.maximum(i[ok], j[ok])
        lo = np.minimum(segments[:, 0], segments[:, 1]) - reach
        hi = np.maximum(segments[:, 0], segments[:, 1]) + reach
        lo_i, lo_j = np.take(lo, i, axis=0), np.take(lo, j, axis=0)
        hi_i, hi_j = np.take(hi, i, axis=0), np.take(hi, j, axis=0)
        meet = (lo_i <= hi_j) & (lo_j <= hi_i)
        box = np.flatnonzero(meet[:, 0] & meet[:, 1])
        i, j = i.take(box), j.take(box)
        d = _segment_distance(np.take(segments, i, axis=0), np.take(segments, j, axis=0))
        keep = np.flatnonzero(d <= reach)
        out = np.empty((keep.size, 2), dtype=np.intp)
        out[:, 0] = i.take(keep)
        out[:, 1] = j.take(keep)
        return out
    else:
        samples, owner = sample_segments(segments, reach)
        # An unbalanced tree without shrunk boxes builds faster and finds the same pairs.
        sp = cKDTree(samples, balanced_tree=False, compact_nodes=False).query_pairs(
            reach * 1.5, output_type='ndarray')
        a, b = owner[sp[:, 0]], owner[sp[:, 1]]
        keep = a != b
        lo, hi = np.minimum(a[keep], b[keep]), np.maximum(a[keep], b[keep])
        key, _ = unique_counts(lo * np.int64(k) + hi, k * k)
        pairs = np.stack([key // k, key % k], axis=1).astype(np.intp)
    if among is not None:
        pairs = pairs[among[pairs[:, 0]] | among[pairs[:, 1]]]
    return pairs


def _segment_distance(s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Distance between segments, pair by pair (0 where they cross)."""
    m = len(s1)
    ends = np.concatenate([s1[:, 0], s1[:, 1], s2[:, 0], s2[:, 1]])
    onto = np.concatenate([s2, s2, s1, s1])
    d = project(ends, onto)[0].reshape(4, m).min(axis=0)
    a, b = s1[:, 0], s1[:, 1]
    c, e = s2[:, 0], s2[:, 1]

    def orient(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1])
                       - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))
    cross = (orient(a, b, c) * orient(a, b, e) < 0) & (orient(c, e, a) * orient(c, e, b) < 0)
    return np.where(cross, 0.0, d)


def gap_supported(index: PointIndex, gap_ends: np.ndarray, gap: np.ndarray, r: float,
                  density: np.ndarray, split_fraction: float, gap_p: float) -> np.ndarray:
    """
    Whether each gap is backed by points (no significant run of low squares in it).

    ``density`` is the expected support of a 2r square on the pair's walls (M,).
    """
    ok = np.ones(len(gap), dtype=bool)
    check = np.flatnonzero(gap > r)
    if check.size == 0:
        return ok
    n = np.maximum(1, np.ceil(gap[check] / (2 * r)).astype(np.intp))
    owner = np.repeat(np.arange(check.size), n)
    first = np.cumsum(n) - n
    frac = (np.arange(owner.size) - first.take(owner) + 0.5) / n.take(owner)
    rows = check.take(owner)
    a = np.take(gap_ends[:, 0], rows, axis=0)
    b = np.take(gap_ends[:, 1], rows, axis=0)
    centres = a + (b - a) * frac[:, None]
    counts = index.count_in_disks(centres, r)
    lam = np.maximum(density[check], 1.0)
    c = np.floor(split_fraction * lam)
    p_low = np.clip(pdtr(c, lam), 1e-300, 1 - 1e-12)
    min_run = np.log(gap_p / n) / np.log(p_low)
    low = counts <= c[owner]
    # Longest run of low squares per gap.
    run, n_runs = label_runs(low, owner)
    run_len = np.bincount(run, minlength=n_runs)
    longest = np.zeros(check.size)
    np.maximum.at(longest, owner[low], run_len[run[low]])
    ok[check] = longest < min_run
    return ok


def _second_chance(index, ms, cost, pair_support, sigma, r, threshold):
    """
    Let the data decide for pairs with a short member that narrowly fail the grouping cost.

    A segment shorter than 8 r has an unreliable direction (a piece fitted at a junction is
    tilted by the other wall's points), so the angle term can wrongly forbid its merge. For such
    pairs with cost < 3 x threshold, the merge is accepted (cost set to 0) when the merged
    segment still has at least 90 % of both segments' support within 2 sigma of it.
    """
    short = np.minimum(ms['l1'], ms['l2']) <= 8.0 * r
    idx = np.flatnonzero(short & (cost >= threshold) & (cost < 3.0 * threshold))
    if idx.size == 0:
        return cost
    p = index.pairs(np.take(ms['segment'], idx, axis=0), 2.0 * sigma)
    held = np.bincount(p.seg, weights=index.weights[p.pt], minlength=idx.size)
    cost = cost.copy()
    cost[idx[held >= 0.9 * pair_support[idx]]] = 0.0
    return cost


def merge_segments(index: PointIndex, segments: np.ndarray, support: np.ndarray, sigma: float,
                   r: float, theta_ref: float = np.deg2rad(10.0), threshold: float = 1.0,
                   reach: float = None, split_fraction: float = 0.1, gap_p: float = 1e-3,
                   max_rounds: int = 50) -> tuple:
    """
    Merge similar segments until no pair passes the cost and gap tests.

    Parameters
    ----------
    index : PointIndex
        The points.
    segments : (K, 2, 2) array
        Metres.
    support : (K,) array
        Supporting point weight of each segment (for the gap test's density).
    sigma : float
        Current noise scale, metres.
    r : float
        Current LSS half-size, metres.
    theta_ref : float
        Angle (rad) at which the parallelism term is 1.
    threshold : float
        Pairs with a lower cost merge.
    reach : float
        Candidate distance, metres (default 4 r).
    split_fraction : float
        As in LSS, for the gap test.
    gap_p : float
        As in LSS, for the gap test.
    max_rounds : int
        Cap on merge rounds.

    Returns
    -------
    segments : (K', 2, 2), support : (K',), merges : int number of merges done.

    """
    segments = np.asarray(segments, dtype=np.float64)
    support = np.asarray(support, dtype=np.float64)
    reach = 4.0 * r if reach is None else reach
    merges = 0
    fresh = None                      # round 1 examines every pair
    for _ in range(max_rounds):       # after round 1 only pairs with a new segment can change
        pairs = candidate_pairs(segments, reach, fresh)
        if len(pairs) == 0:
            break
        i, j = pairs[:, 0], pairs[:, 1]
        ms = merged_segment(np.take(segments, i, axis=0), np.take(segments, j, axis=0))
        cost = grouping_cost(ms, sigma, theta_ref)
        cost = _second_chance(index, ms, cost, support.take(i) + support.take(j), sigma, r,
                              threshold)
        cand = np.flatnonzero(cost < threshold)
        if cand.size == 0:
            break
        dens = support / np.maximum(lengths(segments) / (2 * r), 1.0)
        ok = gap_supported(index, np.take(ms['gap_ends'], cand, axis=0), ms['gap'][cand], r,
                           np.minimum(dens[i[cand]], dens[j[cand]]), split_fraction, gap_p)
        cand = cand[ok]
        if cand.size == 0:
            break
        cand = cand[np.argsort(cost[cand], kind='stable')]
        used = np.zeros(len(segments), dtype=bool)
        chosen = []
        for m in cand:                        # greedy matching over segment pairs, not points
            if not (used[i[m]] or used[j[m]]):
                used[i[m]] = used[j[m]] = True
                chosen.append(m)
        chosen = np.asarray(chosen, dtype=np.intp)
        keep = ~used
        segments = np.concatenate([np.take(segments, np.flatnonzero(keep), axis=0),
                                   np.take(ms['segment'], chosen, axis=0)])
        support = np.concatenate([support[keep], support[i[chosen]] + support[j[chosen]]])
        fresh = np.zeros(len(segments), dtype=bool)
        fresh[int(keep.sum()):] = True
        merges += chosen.size
    return segments, support, merges


STUB_BAND = 1.5
"""``noise_stubs``: a stub must lie within this many cut-offs (kappa sigma) of the wall's line."""
STUB_ANGLE = np.deg2rad(30.0)
"""``noise_stubs``: a stub must cross the wall's direction at more than this angle."""


def noise_stubs(segments: np.ndarray, sigma: float, r: float, kappa: float) -> np.ndarray:
    """
    Mark the short segments that are a neighbouring wall's noise tail, shape (K,) bool.

    A segment is such a stub when it is shorter than 2r (one LSS square: too short for LSS to
    test), at least 4x shorter than a wall, steeper than ``STUB_ANGLE`` to it, and lies with
    both ends inside the wall's band (within ``STUB_BAND`` x kappa sigma of its line, between
    its ends). Where beams meet a wall head-on, range noise spreads the points across the wall
    by more than the fitted sigma (an average over all incidence angles); a handful of them on
    one side can then line up and survive as a 5-point, 6 cm stub sticking out of the wall
    (simulated corridors at 5 cm noise). A real object that small against a wall lies inside
    the band the map cannot resolve anyway; one that stands out of the band is kept.
    """
    segments = np.asarray(segments, dtype=np.float64)
    u, length = directions(segments)
    short = length < 2.0 * r
    out = np.zeros(len(segments), dtype=bool)
    if not short.any() or len(segments) < 2:
        return out
    band = STUB_BAND * kappa * sigma
    p = candidate_pairs(segments, band, short)
    s = np.concatenate([p[:, 0], p[:, 1]])             # the stub candidate
    w = np.concatenate([p[:, 1], p[:, 0]])             # the wall
    ok = short[s] & (length[w] >= 4.0 * length[s])
    s, w = s[ok], w[ok]
    cos = np.abs(u[s, 0] * u[w, 0] + u[s, 1] * u[w, 1])
    # Both ends of each stub candidate on its wall's line: rows (M, 2 ends).
    _, along, normal = project(segments[s].reshape(-1, 2), np.repeat(segments[w], 2, axis=0))
    along, off = along.reshape(-1, 2), np.abs(normal).reshape(-1, 2)
    hit = ((cos < np.cos(STUB_ANGLE)) & (off.max(axis=1) <= band)
           & (along.min(axis=1) >= 0.0) & (along.max(axis=1) <= length[w]))
    out[s[hit]] = True
    return out
