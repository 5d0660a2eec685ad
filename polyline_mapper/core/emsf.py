"""
EMSF: EM segment fitting (method step 1).

E-step on point-to-SEGMENT distances, M-step by weighted orthogonal regression, then trimming of
each line to the projections of its MAP support set.

Outliers (decision recorded in docs/method-decisions.md): a point only takes part in the E-step
for segments within ``cutoff = kappa * sigma``; in the normaliser we add a uniform outlier
component whose density equals the Gaussian kernel at the cut-off, ``exp(-kappa^2 / 2)``. A point
on a segment therefore keeps almost all its weight (0.99 at 1 sigma for kappa = 3), a point at the
cut-off splits half-half with the outlier class, and a point farther than the cut-off from every
segment pulls nothing. Such unexplained points are handed to seeding (see ``seed.py``) instead,
which is how walls the current model does not explain are found.
"""

from dataclasses import dataclass

import numpy as np

from .geometry import directions, group_minmax, lengths
from .index import Pairs, PointIndex

END_SIGMAS = 2.0
"""Trimming with the beams known (``PointIndex.beams``): each supporting point bounds its
segment's extent only up to its position moved inwards by this many times its error along the
line, its noise scale x |cos| of the angle between its beam and the line. A range error moves a
point along its beam; at grazing incidence that is along the wall, and the extreme projection
of a wall's points, which the old map's virtual points then hold for good, lay beyond its end
by the largest such error of the whole drive. The incremental mapper passes the beams only with
``SMEMSFConfig.range_noise`` > 0 (the per-point noise model this rides on), so the default maps
are untouched. A constant, not a config field: 2 noise scales is a property of the noise model,
not of a site or a lidar (those go in range_noise), and a field would need the node's parameter
descriptors and the config files for no tuning anyone needs."""


@dataclass
class EStep:
    """Responsibilities of the candidate pairs and each point's MAP segment."""

    pairs: Pairs
    weight: np.ndarray       # (P,) responsibility w_ij of each pair, in [0, 1]
    support: np.ndarray      # (N,) MAP segment of each point, -1 for outliers / no candidate
    kept: np.ndarray = None  # indices of the input segments emsf_step kept, in output order


def e_step(index: PointIndex, segments: np.ndarray, sigma: float, kappa: float,
           extend: float = 0.0, pairs: Pairs = None, grow: float = None) -> EStep:
    """
    Compute responsibilities of the segments for the points.

    Parameters
    ----------
    index : PointIndex
        The points (and their multiplicities).
    segments : (K, 2, 2) array
        Metres.
    sigma : float
        Kernel width in metres.
    kappa : float
        Cut-off in units of sigma; the outlier class has the kernel's density at the cut-off.
    extend : float
        Distances are measured to the segments extended by this much (m) at both ends, so that
        a wall can claim the collinear points just past its end and grow as it comes into view;
        trimming still stops at its last supporting point.
    pairs : Pairs
        The pairs of the (extended) segments within ``kappa * sigma``, when the caller already
        has them (see ``index.piece_pairs``); queried from ``index`` when None.
    grow : float
        With the beams known (``index.beams``) and ``extend`` beyond it: a point past an end
        pairs with the segment only within ``grow`` plus ``END_SIGMAS`` times its error along
        the line (``_along_error``), the most trimming moves it back, so the segment grows by
        up to ``grow`` however grazing the beams, and no farther for the points seen head-on.

    """
    n = len(index)
    if pairs is None:
        if extend > 0 and len(segments):
            u, _ = directions(segments)
            longer = np.empty_like(segments)
            longer[:, 0] = segments[:, 0] - extend * u
            longer[:, 1] = segments[:, 1] + extend * u
            segments = longer
        pairs = index.pairs(segments, kappa * index.widest(sigma))
    scale = index.sigmas(sigma)
    if scale is not None:               # each point's own cut-off, kappa times its noise scale
        pairs = pairs.where(pairs.dist <= kappa * scale.take(pairs.pt))
    if grow is not None and extend > grow and index.beams is not None and len(pairs.pt):
        u, length = directions(segments)
        t = pairs.along - extend
        past = np.maximum(-t, t - length.take(pairs.seg))
        pairs = pairs.where(past <= grow + END_SIGMAS * _along_error(index, pairs.pt, u,
                                                                     pairs.seg, sigma))
    if len(pairs.pt) == 0:
        return EStep(pairs, np.zeros(0), np.full(n, -1, dtype=np.intp))
    # Kernel and outlier class relative to each point's nearest segment, so nothing underflows
    # however far the cut-off (log-sum-exp shift).
    pt = pairs.pt
    z = (pairs.dist / (sigma if scale is None else scale.take(pt))) ** 2
    zmin = np.full(n, np.inf)
    np.minimum.at(zmin, pt, z)
    g = np.exp(-0.5 * (z - zmin.take(pt)))
    outlier = np.zeros(n)
    has = np.isfinite(zmin)
    outlier[has] = np.exp(-0.5 * (kappa ** 2 - zmin[has]))
    norm = np.bincount(pt, weights=g, minlength=n) + outlier
    norm_p = norm.take(pt)
    w = g / norm_p
    # MAP support: the pair with the largest weight of its point, if it beats the outlier class
    # (ties go to the later pair; both are equally good).
    best = np.zeros(n)
    np.maximum.at(best, pt, w)
    win = np.flatnonzero((w == best.take(pt)) & (w >= outlier.take(pt) / norm_p))
    support = np.full(n, -1, dtype=np.intp)
    support[pt.take(win)] = pairs.seg.take(win)
    return EStep(pairs, w, support)


def weighted_lines(points: np.ndarray, seg: np.ndarray, w: np.ndarray, k: int,
                   return_thickness: bool = False) -> tuple:
    """
    Weighted orthogonal regression lines for ``k`` groups (the M-step).

    Parameters
    ----------
    points : (P, 2) array
        The point of each weighted pair.
    seg : (P,) int array
        Group of each pair, in [0, k).
    w : (P,) array
        Non-negative weights.
    k : int
        Number of groups.
    return_thickness : bool
        Also return each group's thickness: the weighted RMS distance from its line (m).

    Returns
    -------
    centre : (k, 2) weighted mean, metres.
    direction : (k, 2) unit vector along the line (eigenvector of the largest eigenvalue of the
        weighted scatter, i.e. orthogonal to the smallest one).
    mass : (k,) total weight.

    """
    return _lines(points[:, 0], points[:, 1], seg, w, k, return_thickness)


def _lines(px, py, seg, w, k, return_thickness=False):
    """Return ``weighted_lines`` of the points with coordinates ``px``, ``py`` (P,) each."""
    mass = np.bincount(seg, weights=w, minlength=k)
    safe = np.where(mass > 0, mass, 1.0)
    cx = np.bincount(seg, weights=w * px, minlength=k) / safe
    cy = np.bincount(seg, weights=w * py, minlength=k) / safe
    dx = px - cx.take(seg)
    dy = py - cy.take(seg)
    sxx = np.bincount(seg, weights=w * dx * dx, minlength=k)
    syy = np.bincount(seg, weights=w * dy * dy, minlength=k)
    sxy = np.bincount(seg, weights=w * dx * dy, minlength=k)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    direction = np.empty((k, 2))
    direction[:, 0] = np.cos(theta)
    direction[:, 1] = np.sin(theta)
    centre = np.empty((k, 2))
    centre[:, 0] = cx
    centre[:, 1] = cy
    if return_thickness:
        lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
        return centre, direction, mass, np.sqrt(np.maximum(lam_min, 0.0) / safe)
    return centre, direction, mass


def _extent(t, seg, k, spread=None):
    """
    Per-group [lo, hi] of the positions ``t``, each first moved inwards by its ``spread``.

    A group whose moved positions leave no interval keeps the plain one (its points are all
    too uncertain along the line to say more).
    """
    lo, hi = group_minmax(t, seg, k)
    if spread is None:
        return lo, hi
    lo2, _ = group_minmax(t + spread, seg, k)
    _, hi2 = group_minmax(t - spread, seg, k)
    ok = hi2 > lo2
    return np.where(ok, lo2, lo), np.where(ok, hi2, hi)


def _along_error(index: PointIndex, pt: np.ndarray, direction: np.ndarray, seg: np.ndarray,
                 sigma: float) -> np.ndarray:
    """Each point's range error along the line of ``seg`` (m): noise scale x |beam . u|."""
    b = index.beams
    cos = np.abs(np.take(b[:, 0], pt) * np.take(direction[:, 0], seg)
                 + np.take(b[:, 1], pt) * np.take(direction[:, 1], seg))
    scale = index.sigmas(sigma)
    return cos * (sigma if scale is None else scale.take(pt))


def _trim_foreign_tails(t, seg, w, t_near, seg_near, w_near, lo, hi, width, fraction,
                        spread=None):
    """
    Move each group's [lo, hi] inwards past end bins where it owns too few of the nearby points.

    ``t, seg, w``: projections, groups and weights of the support (owned) points; ``t_near,
    seg_near, w_near``: the same for every point near the segment. Bins are ``width`` long from
    lo. An end bin is kept when the owned weight is at least ``fraction`` of the nearby weight.
    A group that owns less than that in every bin is a redundant twin of others: its interval
    comes back empty (lo == hi), so it is dropped. ``spread``: see ``_extent``.
    """
    k = len(lo)
    ok = hi > lo
    nb = np.where(ok, np.maximum(1, np.ceil((hi - lo) / width)).astype(np.intp), 1)
    off = np.cumsum(nb) - nb
    total = int(nb.sum())

    def bins(tt, ss):
        return off.take(ss) + np.clip(np.floor((tt - lo.take(ss)) / width), 0,
                                      nb.take(ss) - 1).astype(np.intp)

    b_own = bins(t, seg)
    owned = np.bincount(b_own, weights=w, minlength=total)
    inside = (t_near >= lo.take(seg_near)) & (t_near <= hi.take(seg_near))
    near = np.bincount(bins(t_near.compress(inside), seg_near.compress(inside)),
                       weights=w_near.compress(inside), minlength=total)
    good = (owned > 0) & (owned >= fraction * np.maximum(near, owned))
    owner = np.repeat(np.arange(k), nb)
    pos = np.arange(total) - off.take(owner)
    gi = np.flatnonzero(good)
    first = np.full(k, np.iinfo(np.intp).max, dtype=np.intp)
    last = np.full(k, -1, dtype=np.intp)
    owner_g, pos_g = owner.take(gi), pos.take(gi)
    np.minimum.at(first, owner_g, pos_g)
    np.maximum.at(last, owner_g, pos_g)
    b = b_own - off.take(seg)
    keep = (b >= first.take(seg)) & (b <= last.take(seg))
    new_lo, new_hi = _extent(t.compress(keep), seg.compress(keep), k,
                             None if spread is None else spread.compress(keep))
    gone = ~np.isfinite(new_lo)
    new_lo[gone] = new_hi[gone] = 0.0
    return new_lo, new_hi


def redundant_segments(est: EStep, segments: np.ndarray, r: float,
                       share: float = 0.9) -> np.ndarray:
    """
    Segments whose support another segment already explains.

    A segment is redundant when at least ``share`` of its MAP-support weight has another segment
    within ``r`` and the segment that most often provides that alternative is longer (for equal
    lengths, the one with the larger index survives). Twins lose their shorter member; a long
    chord laid over a chain of shorter ones that already follow the points is dropped, while a
    segment whose points only it explains is never dropped.

    Returns
    -------
    (K,) bool mask.

    """
    k = len(segments)
    p = est.pairs
    mine = est.support.take(p.pt)
    other = (mine >= 0) & (p.seg != mine) & (p.dist <= r)
    if not other.any():
        return np.zeros(k, dtype=bool)
    alt_d = np.full(len(est.support), np.inf)
    np.minimum.at(alt_d, p.pt.compress(other), p.dist.compress(other))
    win = other & (p.dist == alt_d.take(p.pt))
    alt = np.full(len(est.support), -1, dtype=np.intp)
    alt[p.pt.compress(win)] = p.seg.compress(win)
    sup = np.flatnonzero(est.support >= 0)
    owner = est.support.take(sup)
    alt_sup = alt.take(sup)
    has = alt_sup >= 0
    covered = np.bincount(owner, weights=has.astype(float), minlength=k)
    total = np.bincount(owner, minlength=k).astype(float)
    frac = covered / np.maximum(total, 1.0)
    # The most frequent alternative of each segment (mode over its support), via sorted keys.
    key, cnt = np.unique(owner.compress(has) * np.int64(k) + alt_sup.compress(has),
                         return_counts=True)
    seg_of = key // k
    order = np.lexsort((cnt, seg_of))
    last = np.ones(order.size, dtype=bool)
    last[:-1] = seg_of[order][1:] != seg_of[order][:-1]
    main = np.full(k, -1, dtype=np.intp)
    main[seg_of[order][last]] = (key % k)[order][last]
    length = lengths(segments)
    cand = (frac >= share) & (main >= 0)
    m = np.where(main >= 0, main, 0)
    longer = (length[m] > length) | ((length[m] == length) & (m > np.arange(k)))
    return cand & longer


def extend_for(index: PointIndex, r: float, sigma: float = None) -> float:
    """
    How far (m) the E-step extends segments at both ends: 0 without an old map, else r.

    With the beams known and ``sigma`` given, r plus ``END_SIGMAS`` times the largest noise
    scale of a point: trimming moves each point that far inwards at most (``_along_error``), so
    a wall still grows by up to r an update where only grazing beams see its continuation
    (with r alone its end stalled there and the points beyond seeded a second segment, apart).
    ``e_step(grow=r)`` keeps of the points past an end only those within r plus their own
    share of that.
    """
    if index.n_real >= len(index):
        return 0.0
    if sigma is not None and index.beams is not None and END_SIGMAS > 0:
        return r + END_SIGMAS * index.widest(sigma)
    return r


def _along(index: PointIndex, pt: np.ndarray, centre: np.ndarray, direction: np.ndarray,
           seg: np.ndarray) -> np.ndarray:
    """Position of points ``pt`` along the lines (centre, direction) of ``seg``, pair by pair."""
    return ((np.take(index.x, pt) - np.take(centre[:, 0], seg)) * np.take(direction[:, 0], seg)
            + (np.take(index.y, pt) - np.take(centre[:, 1], seg)) * np.take(direction[:, 1], seg))


def emsf_step(index: PointIndex, segments: np.ndarray, sigma: float, kappa: float,
              min_support: float, min_density: float = 0.0, r: float = 1.0,
              tail_fraction: float = 0.0, pairs: Pairs = None) -> tuple:
    """
    One EM iteration followed by MAP trimming.

    A trimmed segment survives when its supporting point weight is at least ``min_support`` and
    at least ``min_density`` per ``2 r`` of its length (sparse scattered points that merely line
    up over a long stretch do not make a wall). The batch fit passes 0 (see ``smemsf_iteration``).

    With ``tail_fraction > 0`` the ends ignore foreign tails of the support: along the new line,
    in bins 2r wide, an end bin is dropped while the segment owns (as MAP support) less than
    ``tail_fraction`` of the points the E-step paired with it (within kappa sigma). Where two
    segments meet at a shallow angle, noise hands a few points of one to the other, and plain
    min/max trimming would let them stretch it over its neighbour; a far, sparse end of a wall
    is kept, since there the wall owns all the points near it, however few. (Counting only the
    points within r of the line, as before, saw just the ones noise had pushed towards it: those
    it mostly owns, so a curve leaving a wall at 22 degrees stretched the wall 8-12 cm past the
    junction on the simulated office in 4 of 10 drives; counting all paired points, 3-5 cm.)

    ``pairs``: the E-step's pairs when the caller has them (see ``e_step``; the segments
    extended by ``extend_for(index, r)``).

    Returns
    -------
    segments : (K', 2, 2) the refitted, trimmed segments that survive; order follows the
        input.
    support_mass : (K',) supporting point weight of each returned segment.
    estep : the E-step (computed on the input segments).

    """
    k = len(segments)
    # Incremental mapping (an old map present as virtual points): walls grow as they come into
    # view, so distances are measured to segments extended by r. A batch fit grows walls by
    # going coarse to fine, and extending there would overshoot shallow corners.
    est = e_step(index, segments, sigma, kappa, extend=extend_for(index, r, sigma), pairs=pairs,
                 grow=r)
    if k == 0 or len(est.pairs.pt) == 0:
        est.kept = np.zeros(0, dtype=np.intp)
        return np.zeros((0, 2, 2)), np.zeros(0), est
    pt = est.pairs.pt
    pw = est.weight * index.weights.take(pt)
    centre, direction, mass = _lines(index.x.take(pt), index.y.take(pt), est.pairs.seg, pw, k)
    sup_pts = np.flatnonzero(est.support >= 0)
    sup_seg = est.support.take(sup_pts)
    sup_mass = np.bincount(sup_seg, weights=index.weights.take(sup_pts), minlength=k)
    t = _along(index, sup_pts, centre, direction, sup_seg)
    spread = (END_SIGMAS * _along_error(index, sup_pts, direction, sup_seg, sigma)
              if index.beams is not None and END_SIGMAS > 0 else None)
    lo, hi = group_minmax(t, sup_seg, k)
    if tail_fraction > 0:
        # Points near a segment that count against its ends: its own, and those of segments
        # meeting it at a shallow angle (< 45 deg). Points of a wall crossing at a steep angle
        # (a T-junction or a corner) say nothing about where this one ends.
        owner = est.support.take(pt)
        u_old, _ = directions(segments)
        o = np.where(owner >= 0, owner, est.pairs.seg)
        cos = np.abs(np.take(u_old[:, 0], est.pairs.seg) * np.take(u_old[:, 0], o)
                     + np.take(u_old[:, 1], est.pairs.seg) * np.take(u_old[:, 1], o))
        near = (owner >= 0) & (cos > np.cos(np.pi / 4))
        pn, sn = pt.compress(near), est.pairs.seg.compress(near)
        t_near = _along(index, pn, centre, direction, sn)
        lo, hi = _trim_foreign_tails(t, sup_seg, index.weights.take(sup_pts), t_near, sn,
                                     index.weights.take(pn), lo, hi, 2.0 * r, tail_fraction,
                                     spread)
    elif spread is not None:
        lo, hi = _extent(t, sup_seg, k, spread)
    extent = np.where(hi > lo, hi - lo, 0.0)
    keep = ((sup_mass >= min_support) & (sup_mass >= min_density * extent / (2.0 * r))
            & (mass > 0) & (hi > lo))
    if tail_fraction > 0:
        keep &= ~redundant_segments(est, segments, r)
    kept = np.flatnonzero(keep)
    c, u = np.take(centre, kept, axis=0), np.take(direction, kept, axis=0)
    new = np.empty((kept.size, 2, 2))
    new[:, 0] = c + lo.take(kept)[:, None] * u
    new[:, 1] = c + hi.take(kept)[:, None] * u
    est.kept = kept
    return new, sup_mass.take(kept), est
