"""
Clearing and cleanup rules: what takes segments out of an incremental map.

A segment in the incremental map keeps itself alive through its virtual points (its own past,
see ``incremental.py``), so evidence against it must come from the new scans:

- ``seen_through``: free-space clearing. The new scan's beams are traced through the short
  segments near them; a segment that beams pass through over much of its length, with returns
  beyond it, is gone (a person who stood still, a door since opened, a moved chair).
- ``beam_evidence``: the same beam geometry counted per LSS square (hits and passes), the
  free-space evidence the incremental mapper accumulates per square (``split.free_squares``).
- ``corner_chords``: a short chord across a corner, kept alive by its own virtual points, is
  dropped when the new points near it all lie on the two longer walls whose corner it cuts.

``as_origins`` and ``origin_runs`` validate the laser positions that clearing traces beams from
and split a group of scans into one run of points per position.
"""

import numpy as np

from .freespace import PAIR_BUDGET, run_bounds, span_pairs
from .geometry import directions, in_box, lengths, project
from .index import in_sorted, PointIndex


END_SHARE = 0.25
"""``beam_evidence`` ignores crossings within min(tol, this share of the length) of an end."""


def as_origins(origin, n: int):
    """
    Validate laser positions for ``n`` points: None, or an (n, 2) array (a view for a (2,) one).

    ``origin`` is None (bare points), (2,) (one scan) or (n, 2) (one row per point, for the
    points of several scans). Raises ValueError naming ``origin`` on a wrong shape, NaN or inf.
    """
    if origin is None:
        return None
    o = np.asarray(origin, dtype=np.float64)
    if o.shape not in ((2,), (n, 2)):
        raise ValueError(f'origin must have shape (2,) or ({n}, 2), got {o.shape}')
    if not np.isfinite(o).all():
        raise ValueError('origin has NaN or inf')
    return np.broadcast_to(o, (n, 2))


def origin_runs(origins) -> list:
    """
    Split points into runs seen from one laser position: ``[(first, stop, origin), ...]``.

    ``origins`` is the (n, 2) array of ``as_origins`` (or None: no runs). Consecutive rows with
    the same position form one run (one scan).
    """
    if origins is None or len(origins) == 0:
        return []
    starts, stops = run_bounds(origins)
    return [(int(a), int(b), np.array(origins[a])) for a, b in zip(starts, stops)]


def corner_chords(index: PointIndex, segs: np.ndarray, reach: float, near: float,
                  short: float, min_angle: float, share: float = 0.9) -> np.ndarray:
    """
    Short segments cutting across a corner of longer ones that explain their points.

    A segment no longer than ``short`` is a corner chord when (1) its two ends lie within
    ``reach`` of two different longer segments, each at an angle of at least ``min_angle``
    (rad) to it, and (2) measured points lie within ``reach`` of it and at least ``share`` of
    them lie within ``near`` of such a segment. Its virtual points (its own past) keep a chord
    alive through trimming, LSS and the redundancy test, which is why it is judged on the new
    points only. Condition (1) spares short clutter pieces beside a single wall. Returns a (K,)
    bool mask.

    Memory: the bounding-box test runs over blocks of short segments so that no block tests
    more than ``PAIR_BUDGET`` (short, any) pairs.
    """
    k_all = len(segs)
    chord = np.zeros(k_all, dtype=bool)
    length = lengths(segs)
    sid = np.flatnonzero(length <= short)
    if sid.size == 0:
        return chord
    # Candidate (stub, segment) pairs: longer, at an angle, bounding boxes within 2 reach
    # (>= reach + near, so every segment that can explain a stub's point is among them).
    lo, hi = segs.min(axis=1), segs.max(axis=1)
    slo, shi = lo[sid] - 2 * reach, hi[sid] + 2 * reach
    block = max(1, PAIR_BUDGET // k_all)
    s, k = [], []
    for b0 in range(0, sid.size, block):
        b = slice(b0, b0 + block)
        box = ((lo[:, 0] <= shi[b, :1]) & (hi[:, 0] >= slo[b, :1])
               & (lo[:, 1] <= shi[b, 1:]) & (hi[:, 1] >= slo[b, 1:]))
        bi, bk = np.nonzero(box)
        s.append(sid[b][bi])
        k.append(bk)
    s, k = np.concatenate(s), np.concatenate(k)
    u, _ = directions(segs)
    fit = (length[k] > length[s]) & (np.abs(np.sum(u[s] * u[k], axis=1)) <= np.cos(min_angle))
    s, k = s[fit], k[fit]
    if s.size == 0:
        return chord
    # (1) each end within reach of a different one of them.
    on = []
    for end in (0, 1):
        d = project(segs[s, end], segs[k])[0]
        best = np.full(k_all, np.inf)
        np.minimum.at(best, s, d)
        hit = (d == best[s]) & (d <= reach)
        which = np.full(k_all, -1)
        which[s[hit]] = k[hit]
        on.append(which)
    cand = np.flatnonzero((on[0] >= 0) & (on[1] >= 0) & (on[0] != on[1]))
    if cand.size == 0:
        return chord
    # (2) the new points near each candidate, on those segments.
    keep = in_sorted(s, cand)
    s, k = s[keep], k[keep]
    p = index.pairs(segs[cand], reach)
    real = p.pt < index.n_real
    pt, stub = p.pt[real], cand[p.seg[real]]
    if pt.size == 0:
        return chord
    # every (point, stub) pair against each of the stub's partners
    order = np.argsort(s, kind='stable')
    s, k = s[order], k[order]
    first = np.searchsorted(s, stub, 'left')
    count = np.searchsorted(s, stub, 'right') - first
    row = np.repeat(np.arange(pt.size), count)
    col = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(int(count.sum()))
    d = project(index.points[pt[row]], segs[k[col]])[0]
    explained = np.zeros(pt.size, dtype=bool)
    explained[row[d <= near]] = True
    seen = np.bincount(stub, minlength=k_all)
    good = np.bincount(stub, weights=explained.astype(float), minlength=k_all)
    chord[cand] = (seen[cand] > 0) & (good[cand] >= share * seen[cand])
    return chord


def seen_through(segs: np.ndarray, origin: np.ndarray, points: np.ndarray, tol: float,
                 range_tol: float = 0.03, min_beams: int = 3, share: float = 0.5,
                 min_sin: float = np.sin(np.deg2rad(20.0))) -> np.ndarray:
    """
    Segments that one scan's beams pass through: free-space evidence against them.

    ``points`` are the scan's returns (fixed frame) measured from ``origin`` (the laser's
    position, (2,)). A beam *passes through* a segment when it crosses the segment's line more
    than ``tol`` from either end and its return lies beyond that line by more than ``tol +
    range_tol x range`` (measured perpendicular to the line, so the test is as strict at a slant
    as head-on; the range term allows for a heading error of the pose, about 1.7 degrees at
    0.03). It *hits* the segment when its return lies within ``tol`` of the line where it crosses.
    Beams meeting the line at less than asin(``min_sin``) are not counted (at grazing incidence
    a small pose error moves the crossing far), nor are beams that end before the segment
    (occlusion says nothing). A segment is seen through when at least ``min_beams`` beams pass,
    they are at least ``share`` of the beams that pass or hit, and their crossings spread over
    at least ``share`` of its length (a long wall seen past at one end, a doorway in it, is not
    contradicted as a whole). Returns a (K,) bool mask.

    Memory: every (segment, beam in its angular span) pair is tested, in blocks of segments
    holding at most ``PAIR_BUDGET`` pairs (or one segment's beams, at most ``len(points)``).
    """
    k_all = len(segs)
    out = np.zeros(k_all, dtype=bool)
    if k_all == 0 or len(points) == 0:
        return out
    n_through = np.zeros(k_all, dtype=np.intp)
    n_hit = np.zeros(k_all, dtype=np.intp)
    lo_s = np.full(k_all, np.inf)                             # spread of the crossings
    hi_s = np.full(k_all, -np.inf)
    for c0, c1, k, through, hit, s in _beam_blocks(segs, origin, points, tol, range_tol,
                                                   min_sin):
        n_through[c0:c1] = np.bincount(k[through], minlength=c1 - c0)
        n_hit[c0:c1] = np.bincount(k[hit], minlength=c1 - c0)
        np.minimum.at(lo_s[c0:c1], k[through], s[through])
        np.maximum.at(hi_s[c0:c1], k[through], s[through])
    # the crossings must spread over at least `share` of the segment's length
    spread = hi_s - lo_s >= share * (lengths(segs) - 2 * tol)
    return (n_through >= min_beams) & (n_through >= share * (n_through + n_hit)) & spread


def beam_evidence(segs: np.ndarray, n_sub: np.ndarray, origin: np.ndarray, points: np.ndarray,
                  tol: float, range_tol: float = 0.03,
                  min_sin: float = np.sin(np.deg2rad(20.0)), hit_range_tol=None) -> tuple:
    """
    Count one scan's beams that end on and that pass through each square of each segment.

    Segment k is cut into ``n_sub[k]`` equal squares (the LSS layout, ``split.square_layout``),
    flattened in segment order. A beam from ``origin`` to its return in ``points`` *passes*
    a square when it crosses the segment inside it, more than ``tol`` from the segment's ends
    (or ``END_SHARE`` of its length, if less: a person's 5 cm segment must be seen through too),
    at >= asin(``min_sin``) to it, and returns beyond its line by more than ``tol + range_tol x
    range`` (perpendicular: as strict at a slant as head-on).

    With ``hit_range_tol`` None it *hits* the square when it crosses there the same way and
    its return lies within ``tol`` of the line (the same geometry as ``seen_through``). With a
    number it hits the square its return projects into when the return lies within ``tol +
    hit_range_tol x range`` of the segment's line, abreast of the stretch where passes count
    (the same distance from the ends), at any angle: a return the margin cannot tell from the
    surface is evidence for it. (Summed over every 5th fr079 scan against its default replay
    map, passes outnumber hits on 19 % of the map's length with the crossing hits, on 9.8 %
    with the margin at 0.03, where the map -> beams metric finds 5.8 % contradicted.) Beams
    ending before the segment, beyond the margin, are not counted. Returns (hits, passes),
    two int arrays of ``n_sub.sum()``.

    Memory: as ``seen_through`` (blocks of at most ``PAIR_BUDGET`` pairs).
    """
    total = int(np.sum(n_sub))
    hits = np.zeros(total, dtype=np.intp)
    passes = np.zeros(total, dtype=np.intp)
    if len(segs) == 0 or len(points) == 0:
        return hits, passes
    offset = np.cumsum(n_sub) - n_sub
    length = lengths(segs)
    sub_len = np.maximum(length / np.maximum(n_sub, 1), 1e-12)
    if hit_range_tol is None:
        for c0, c1, k, through, hit, s in _beam_blocks(segs, origin, points, tol, range_tol,
                                                       min_sin, END_SHARE):
            g = k + c0
            sq = offset[g] + np.clip((s / sub_len[g]).astype(np.intp), 0, n_sub[g] - 1)
            hits += np.bincount(sq[hit], minlength=total)
            passes += np.bincount(sq[through], minlength=total)
        return hits, passes
    rel = points - origin
    rng = np.hypot(rel[:, 0], rel[:, 1])
    w = segs[:, 0] - origin                                   # (K, 2) first end from the laser
    e = segs[:, 1] - segs[:, 0]
    ee = np.maximum(length * length, 1e-300)
    edge = np.minimum(tol, END_SHARE * length) / np.maximum(length, 1e-300)
    # a return off the line abreast of the segment near an end can lie outside its angular
    # span: widen the span by tol
    # (no segment is when none's bounding box, grown by tol, holds the laser)
    reach = tol * (1.0 + 1e-6)
    laser_near = np.zeros(len(segs), dtype=bool)
    if in_box(segs, origin - reach, origin + reach).any():
        laser_near = project(np.broadcast_to(origin, (len(segs), 2)), segs)[0] <= tol
    for c0, c1, k, beam in span_pairs(w, e, rel, tol, laser_near):
        through, _, s = _crossings(rel, rng, beam, e[c0:c1], w[c0:c1], k, tol, range_tol,
                                   min_sin, END_SHARE)
        g = k + c0
        n_g = np.take(n_sub, g)
        first = np.take(offset, g)
        sq = first + np.clip((s / np.take(sub_len, g)).astype(np.intp), 0, n_g - 1)
        passes += np.bincount(sq[through], minlength=total)
        qx = np.take(rel[:, 0], beam) - np.take(w[:, 0], g)
        qy = np.take(rel[:, 1], beam) - np.take(w[:, 1], g)
        ex, ey = np.take(e[:, 0], g), np.take(e[:, 1], g)
        u = (qx * ex + qy * ey) / np.take(ee, g)
        lo = np.take(edge, g)
        hit = ((u >= lo) & (u <= 1.0 - lo) & (np.hypot(qx - u * ex, qy - u * ey)
                                              <= tol + hit_range_tol * np.take(rng, beam)))
        sq = first + np.clip((u * n_g).astype(np.intp), 0, n_g - 1)
        hits += np.bincount(sq[hit], minlength=total)
    return hits, passes


def _beam_blocks(segs, origin, points, tol, range_tol, min_sin, end_share=None):
    """
    Yield every (segment, beam in its angular span) pair, in blocks of segments.

    Each block is ``(c0, c1, k, through, hit, s)``: segments ``c0:c1``, ``k`` the pair's segment
    relative to ``c0`` and the outputs of ``_crossings`` per pair (``freespace.span_pairs``
    picks the pairs, as for the map -> beams metric).
    """
    rel = points - origin
    rng = np.hypot(rel[:, 0], rel[:, 1])
    w = segs[:, 0] - origin                                   # (K, 2) first end from the laser
    e = segs[:, 1] - segs[:, 0]
    for c0, c1, k, beam in span_pairs(w, e, rel):
        through, hit, s = _crossings(rel, rng, beam, e[c0:c1], w[c0:c1], k, tol, range_tol,
                                     min_sin, end_share)
        yield c0, c1, k, through, hit, s


def _crossings(rel, rng, beam, e, w, k, tol, range_tol, min_sin, end_share=None) -> tuple:
    """
    Beams ``beam`` against segments ``k`` (pair by pair): (passes, hits, crossing in m).

    Crossings within ``tol`` of a segment's end do not count, or within ``end_share`` x its
    length when that is less (so a segment shorter than 2 ``tol`` can still be seen through).
    """
    dx, dy = np.take(rel[:, 0], beam), np.take(rel[:, 1], beam)
    ex, ey = np.take(e[:, 0], k), np.take(e[:, 1], k)
    wx, wy = np.take(w[:, 0], k), np.take(w[:, 1], k)
    den = dx * ey - dy * ex
    elen = np.hypot(ex, ey)
    r = np.take(rng, beam)
    sin = np.abs(den) / np.maximum(r * elen, 1e-12)
    ok = sin >= min_sin
    den = np.where(ok, den, 1.0)
    t = (wx * ey - wy * ex) / den                             # crossing, in units of the range
    s = (wx * dy - wy * dx) / den * elen                      # crossing, metres from the first end
    past = (1.0 - t) * r * sin                                # return beyond the line (m, perp.)
    end = tol if end_share is None else np.minimum(tol, end_share * elen)
    inside = ok & (t > 0) & (s >= end) & (s <= elen - end)
    through = inside & (past > tol + range_tol * r)
    hit = inside & (np.abs(past) <= tol)
    return through, hit, s
