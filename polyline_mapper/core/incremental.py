"""
Incremental SMEMSF: the map G(t) plus the points of the last few scans give G(t+1).

How G(t) takes part in EM without its old points (method.md leaves this open): every segment
near the new points is represented by *virtual points* sampled along it every 2r metres (one
per LSS square), each weighing the segment's past support per sample, capped at
``virtual_cap``. Virtual points

- hold an old wall in place: the M-step's weighted regression sees them like real points, so new
  points move a wall only as far as their weight against its history allows, and consistent new
  evidence wins after a few scans because the cap bounds the history;
- keep the old extent: trimming, LSS and the merge gap test count them, so a long wall seen only
  in part by the new scans is neither shortened nor split;
- need no bookkeeping through split and merge (sufficient statistics would have to be divided
  between pieces).

Only the part of the map near the new points is refit: a grid hash over the segments (cells
updated only for the segments that change) gives candidates, and a finer cell test over the
buffer's points keeps the *active* ones, those within ``REFIT_REACH`` (2) reaches of a point,
where the reach is the merge reach plus kappa sigma plus ``margin``. So a wall seen again after
a loop meets its old segments in the same fit, and merging examines every pair of the active
set, as batch does, so they join instead of doubling. Segments outside stay exactly as they
are. Memory is the map plus the buffer of the last ``buffer_scans`` scans: no point is kept
longer.

Free-space clearing (``clear_max_length``): a segment in the map keeps itself alive through its
virtual points, so a person who stood still for a few scans, or a door since opened, would stay
in the map for good. After each update, the new scan's beams are traced through the short
segments (up to ``clear_max_length``, 0.9 m: a person, a chair, a door leaf) near them; a
segment that beams pass through over much of its length, with returns beyond it, is dropped
(``seen_through``). Long walls are never cleared: a wall the scanner seems to see through is more
likely a registration error or glass. The limit is a length in metres, not in units of r, since
what it is for has a size of its own: at 16 r it was 0.45 m on fr079 but 1.5 m on the campus log
(r = 9.4 cm), where it cleared hedges and the sides of parked cars.
Refitting only near the new points makes this necessary: with a wider refit, clutter wore
away slowly under the fit of its neighbours, by accident rather than by evidence.

The noise scale sigma is ``SMEMSFConfig.sigma`` when given (then fixed). Otherwise it starts
from the local thickness of the first scans and then follows the scan-to-map spread: after every
update the robust residual scale (1.4826 x median distance) of the new points the map explains
feeds a running median over the last ``sigma_window`` updates, never below the first estimate
(a single scan's thickness is the range noise; registration error can only add to it). A map
built from many scans is as thick as their registration error; with sigma too small a wall seen
again a few centimetres off would be doubled. The running median has that spread as its fixed
point: when sigma is too small the truncated residuals look uniform and their scale is about
2 sigma, so sigma grows; when it is large enough the scale is the spread itself. Each update
runs ``iterations`` SMEMSF iterations.

The LSS half-size r is ``r_over_sigma`` x sigma as in batch, but the square side 2r is never
below the spacing of one scan's points (the upper quartile of each scan's nearest-neighbour
distances, running median over ``sigma_window`` scans). Batch sees every scan at once; the
mapper sees a window of a few, and with a sparse scanner (1 degree between beams: 5-9 cm between
points on a wall 3-5 m away) and low noise, squares of 2r = 5 sigma hold no point on most of a
real wall, so the density tests of trimming, seeding and LSS chop it into fragments.

A short chord across a corner, once in the map, is kept alive by its own virtual points; it is
dropped when the new points near it all lie on the two longer walls whose corner it cuts
(``_corner_chords``).
"""

from collections import deque
from dataclasses import dataclass, field, replace
import time
from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from .geometry import (as_points, cell_keys, dilate_cells, directions, in_sorted, lengths,
                       PointIndex, project, sample_segments)
from .merge import noise_stubs
from .noise import estimate_noise
from .polylines import assemble_polylines
from .smemsf import smemsf_iteration, SMEMSFConfig
from ..scan import scan_to_points


REFIT_REACH = 2.0
"""Segments within this many merge reaches of a point of the buffer are refit in an update."""

SPACING_QUANTILE = 75.0
"""Percentile of a scan's nearest-neighbour distances that one LSS square (2r) must span."""


def _percentile(x: np.ndarray, q: float) -> float:
    """``np.percentile(x, q)`` (linear method, finite x) by partial sort, 10x faster."""
    v = (x.size - 1) * (q / 100.0)
    lo = int(np.floor(v))
    hi = min(lo + 1, x.size - 1)
    part = np.partition(x, (lo, hi))
    a, b, t = part[lo], part[hi], v - lo
    return float(b - (b - a) * (1 - t)) if t >= 0.5 else float(a + (b - a) * t)


def _median(values) -> float:
    """``np.median`` of a few finite values (a deque of per-scan numbers), by partial sort."""
    x = np.fromiter(values, dtype=np.float64)
    mid = x.size // 2
    if x.size % 2:
        return float(np.partition(x, mid)[mid])
    part = np.partition(x, (mid - 1, mid))
    return float((part[mid - 1] + part[mid]) / 2.0)


def _corner_chords(index: PointIndex, segs: np.ndarray, reach: float, near: float,
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
    box = ((lo[:, 0] <= shi[:, :1]) & (hi[:, 0] >= slo[:, :1])
           & (lo[:, 1] <= shi[:, 1:]) & (hi[:, 1] >= slo[:, 1:]))
    si, k = np.nonzero(box)
    s = sid[si]
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
    """
    k_all = len(segs)
    out = np.zeros(k_all, dtype=bool)
    n = len(points)
    if k_all == 0 or n == 0:
        return out
    rel = points - origin
    rng = np.hypot(rel[:, 0], rel[:, 1])
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    order = np.argsort(ang)
    ang2 = np.concatenate([ang[order], ang[order] + 2 * np.pi])
    w = segs[:, 0] - origin                                   # (K, 2) first end from the laser
    e = segs[:, 1] - segs[:, 0]
    ea = np.arctan2(w[:, 1], w[:, 0])
    eb = np.arctan2(w[:, 1] + e[:, 1], w[:, 0] + e[:, 0])
    lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
    wrap = hi - lo > np.pi                                    # the span crosses +-pi
    lo, hi = np.where(wrap, hi, lo), np.where(wrap, lo + 2 * np.pi, hi)
    first = np.searchsorted(ang2, lo, 'left')
    count = np.minimum(np.searchsorted(ang2, hi, 'right'), first + n) - first
    k = np.repeat(np.arange(k_all), count)
    if k.size == 0:
        return out
    beam = np.take(order, (np.repeat(first - (np.cumsum(count) - count), count)
                           + np.arange(k.size)) % n)
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
    inside = ok & (t > 0) & (s >= tol) & (s <= elen - tol)
    through = inside & (past > tol + range_tol * r)
    hit = inside & (np.abs(past) <= tol)
    n_through = np.bincount(k[through], minlength=k_all)
    n_hit = np.bincount(k[hit], minlength=k_all)
    # the crossings must spread over at least `share` of the segment's length
    lo_s = np.full(k_all, np.inf)
    hi_s = np.full(k_all, -np.inf)
    np.minimum.at(lo_s, k[through], s[through])
    np.maximum.at(hi_s, k[through], s[through])
    spread = hi_s - lo_s >= share * (lengths(segs) - 2 * tol)
    return (n_through >= min_beams) & (n_through >= share * (n_through + n_hit)) & spread


def near_points(points: np.ndarray, segs: np.ndarray, dist: float) -> np.ndarray:
    """
    Segments that pass within ``dist`` of some point: a (K,) bool mask.

    A superset by at most a factor of about 4 in distance: the points' cells (side 1.5 dist),
    dilated by one cell, against samples along each segment at most ``dist`` apart (a sample
    lies within dist / 2 of every point of its segment, so a point within dist of the segment
    lies within 1.5 dist of a sample, inside the dilated cells).
    """
    if len(segs) == 0 or len(points) == 0:
        return np.zeros(len(segs), dtype=bool)
    cell = 1.5 * dist
    keys = dilate_cells(np.unique(cell_keys(points, cell)), 1)
    samples, owner = sample_segments(segs, dist)
    hit = in_sorted(cell_keys(samples, cell), keys)
    return np.bincount(owner[hit], minlength=len(segs)) > 0


def _views(origin, n: int) -> list:
    """Validate ``origin`` ((2,) or (n, 2)); return (first, stop, origin) per run of points."""
    if origin is None:
        return []
    o = np.asarray(origin, dtype=np.float64)
    if o.shape not in ((2,), (n, 2)):
        raise ValueError(f'origin must have shape (2,) or ({n}, 2), got {o.shape}')
    if not np.isfinite(o).all():
        raise ValueError('origin has NaN or inf')
    if n == 0:
        return []
    if o.shape == (2,):
        return [(0, n, o)]
    starts = np.concatenate([[0], np.flatnonzero(np.any(o[1:] != o[:-1], axis=1)) + 1])
    stops = np.append(starts[1:], n)
    return [(int(a), int(b), o[a]) for a, b in zip(starts, stops)]


@dataclass
class IncrementalConfig:
    """Tunables of the incremental mapper (lengths in metres)."""

    buffer_scans: int = 3
    """Scans whose points take part in each update (k)."""
    iterations: int = 1
    """SMEMSF iterations per update."""
    margin: float = 0.0
    """Extra distance (m) around the new points within which segments are refit (added to the
    merge reach, which is always included)."""
    virtual_cap: float = 10.0
    """Largest weight of one virtual point (points per 2r of wall)."""
    cell: float = 2.0
    """Cell size (m) of the grid hash over the map."""
    noise_updates: int = 5
    """Updates whose thickness estimates are pooled (median) for the first sigma."""
    sigma_window: int = 50
    """Updates whose residual scales are pooled (running median) for sigma."""
    clear_max_length: float = 0.9
    """Segments up to this long (m) that the new scan's beams pass through are dropped
    (free-space clearing: people, moved chairs, opened door leaves); 0 turns clearing off. Needs
    the laser position of each scan (update_scan, replay and the node give it)."""
    smemsf: SMEMSFConfig = field(default_factory=SMEMSFConfig)
    """The fit parameters (sigma, r_over_sigma, merge and split thresholds ...)."""

    def __post_init__(self):
        """Reject values that cannot work, naming the field."""
        for name in ('buffer_scans', 'iterations', 'noise_updates', 'sigma_window'):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f'{name} must be an integer >= 1, got {v!r}')
        for name, lo in (('margin', 0.0), ('virtual_cap', 1e-9), ('cell', 1e-9),
                         ('clear_max_length', 0.0)):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= lo):
                raise ValueError(f'{name} must be a finite number >= {lo:g}, got {v!r}')


class SegmentGrid:
    """
    A grid hash from cells to segment ids, vectorised.

    Entries ``(cell key, id, generation)`` live in a sorted array (queried by binary search) plus
    a small unsorted tail of recent additions. Removing or re-adding an id bumps its generation,
    which invalidates its old entries without touching them; the tail is sorted into the main
    array, dropping invalid entries, once it holds a quarter as many entries as the main array
    (or 1024), so each entry is sorted O(1) times on average and memory stays proportional to
    the live map. An update costs about the cells of the changed segments and of the query,
    not the map size.
    """

    _TAIL_MIN = 1024

    def __init__(self, cell: float):
        self.cell = float(cell)
        self._gen = np.zeros(0, dtype=np.int64)
        empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.intp),
                 np.zeros(0, dtype=np.int64))
        self._main = self._tail = empty

    def _keys(self, points: np.ndarray) -> np.ndarray:
        return cell_keys(points, self.cell)

    def _bump(self, ids: np.ndarray) -> None:
        if ids.size and ids.max() >= self._gen.size:
            grow = max(int(ids.max()) + 1, 2 * self._gen.size) - self._gen.size
            self._gen = np.concatenate([self._gen, np.zeros(grow, dtype=np.int64)])
        self._gen[ids] += 1

    def add(self, ids, segments) -> None:
        """Register segments under their ids (in every cell they pass through)."""
        ids = np.asarray(ids, dtype=np.intp)
        self._bump(ids)
        if len(segments) == 0:
            return
        pts, owner = sample_segments(np.asarray(segments), 0.5 * self.cell)
        key = self._keys(pts)
        # Samples are half a cell apart, and a straight segment never re-enters a cell, so
        # repeated cells are consecutive.
        new = np.ones(len(key), dtype=bool)
        new[1:] = (key[1:] != key[:-1]) | (owner[1:] != owner[:-1])
        sid = ids[owner[new]]
        added = (key[new], sid, self._gen[sid])
        self._tail = tuple(np.concatenate(a) for a in zip(self._tail, added))
        if len(self._tail[0]) > max(self._TAIL_MIN, len(self._main[0]) // 4):
            self._compact()

    def remove(self, ids) -> None:
        """Forget segments."""
        self._bump(np.asarray(ids, dtype=np.intp))

    def _compact(self) -> None:
        key, sid, gen = (np.concatenate(a) for a in zip(self._main, self._tail))
        ok = gen == self._gen[sid]
        order = np.argsort(key[ok], kind='stable')
        self._main = (key[ok][order], sid[ok][order], gen[ok][order])
        self._tail = tuple(a[:0] for a in self._tail)

    def cells(self, points: np.ndarray) -> np.ndarray:
        """Keys of the cells holding the points (sorted, unique), for ``near``."""
        return np.unique(self._keys(points))

    def near(self, points: np.ndarray, dist: float, cells: np.ndarray = None) -> np.ndarray:
        """
        Ids of segments registered in cells within ``dist`` of any point (a superset).

        ``cells``: the points' cell keys (``cells(points)``, or a union of them) when known.
        """
        if cells is None:
            cells = self.cells(points)
        if len(cells) == 0:
            return np.zeros(0, dtype=np.intp)
        cells = dilate_cells(cells, int(np.ceil(dist / self.cell)))
        key, sid, gen = self._main
        lo = np.searchsorted(key, cells, 'left')
        cnt = np.searchsorted(key, cells, 'right') - lo
        at = np.repeat(lo - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))
        found = sid[at][gen[at] == self._gen[sid[at]]]
        tkey, tsid, tgen = self._tail
        if len(tkey):
            hit = in_sorted(tkey, cells) & (tgen == self._gen[tsid])
            found = np.concatenate([found, tsid[hit]])
        return np.unique(found)


@dataclass
class UpdateInfo:
    """What one update did."""

    points: int
    active: int
    segments: int
    seconds: float
    skipped: Optional[str] = None


class IncrementalMapper:
    """
    Online SMEMSF: feed scans (or point sets) one by one, read the map at any time.

    >>> mapper = IncrementalMapper()
    >>> info = mapper.update_scan(ranges, angles, pose, range_min, range_max)
    >>> mapper.segments          # (K, 2, 2) metres
    """

    def __init__(self, config: IncrementalConfig = None):
        self.config = config or IncrementalConfig()
        self._seg = np.zeros((64, 2, 2))
        self._sup = np.zeros(64)
        self._alive = np.zeros(64, dtype=bool)
        self._grid = SegmentGrid(self.config.cell)
        self._buffer = deque(maxlen=int(self.config.buffer_scans))
        self._cells = deque(maxlen=int(self.config.buffer_scans))   # grid cells of each scan
        self._noise = []
        self._scales = deque(maxlen=int(self.config.sigma_window))
        self._spacings = deque(maxlen=int(self.config.sigma_window))
        self.sigma = self.config.smemsf.sigma
        self._sigma0 = self.sigma
        self._fit_config = None
        self.updates = 0

    # -- the map -------------------------------------------------------------------------------
    @property
    def segments(self) -> np.ndarray:
        """Return the map's segments, (K, 2, 2) metres (a copy)."""
        return self._seg[self._alive].copy()

    @property
    def support(self) -> np.ndarray:
        """Return the accumulated, capped point weight behind each segment, shape (K,)."""
        return self._sup[self._alive].copy()

    def polylines(self) -> tuple:
        """
        Chain the current map: (segments with joined ends, polylines, closed flags).

        Short stubs inside a wall's noise band (``merge.noise_stubs``) are left out, as in a
        batch fit; they stay in ``segments``, where later scans may still grow them.
        """
        segs = self.segments
        if self.sigma is not None:
            segs = segs[~noise_stubs(segs, self.sigma, self.r, self.config.smemsf.kappa)]
        return assemble_polylines(segs, self.config.smemsf.join_over_r * self.r)

    def load(self, segments, support=None) -> None:
        """
        Replace the map by given segments (K, 2, 2) metres, e.g. a saved map to extend.

        ``support`` (K,) defaults to the cap (a loaded map is trusted like a long-seen one).
        """
        from .geometry import as_segments
        segs = as_segments(segments)
        r = self.r
        cap = self.config.virtual_cap * np.maximum(lengths(segs) / (2.0 * r), 1.0)
        sup = cap if support is None else np.asarray(support, dtype=np.float64)
        if sup.shape != (len(segs),) or not np.all(np.isfinite(sup)) or np.any(sup < 0):
            raise ValueError(f'support must be {len(segs)} finite values >= 0')
        self._replace(np.flatnonzero(self._alive), segs, sup)

    def reset(self) -> None:
        """Forget the map and the buffer (sigma, once estimated, is kept)."""
        self.__init__(self.config)

    def nbytes(self) -> int:
        """Bytes held by the map arrays and the scan buffer."""
        return (self._seg.nbytes + self._sup.nbytes + self._alive.nbytes
                + sum(p.nbytes for p in self._buffer) + sum(c.nbytes for c in self._cells))

    # -- updates -------------------------------------------------------------------------------
    def update_scan(self, ranges, angles, pose, range_min: float = 0.0,
                    range_max: float = np.inf) -> UpdateInfo:
        """
        Add one laser scan: ranges (m) at angles (rad) from a laser at pose (x, y, yaw).

        NaN, inf and out-of-range readings are dropped (REP 117). Raises ValueError on
        mismatched lengths or a bad pose, leaving the map unchanged.
        """
        return self.update(scan_to_points(ranges, angles, pose, range_min, range_max),
                           ordered=True, origin=np.asarray(pose, dtype=np.float64)[:2])

    def update(self, points, ordered: bool = False, origin=None) -> UpdateInfo:
        """
        Add the points of one scan (N, 2, fixed frame, metres) and refit the map near them.

        ``ordered``: the points are in beam order (as ``scan_to_points`` returns them, or such
        runs concatenated), so a point's nearest neighbour in its scan is the one before or after
        it; the point spacing is then read off in order instead of from a k-d tree.

        ``origin``: where the laser was, fixed frame, metres: (2,) for one scan, or (N, 2), one
        row per point, for the points of several scans. With it, the beams clear the short
        segments they pass through (``IncrementalConfig.clear_max_length``); without it (bare
        points) nothing is cleared.

        An empty point set changes nothing. Raises ValueError on NaN / inf / wrong shapes,
        leaving the map unchanged.
        """
        t0 = time.perf_counter()
        pts = as_points(points)
        views = _views(origin, len(pts))
        if len(pts) == 0:
            return UpdateInfo(0, 0, int(self._alive.sum()), 0.0, skipped='no valid points')
        self._buffer.append(pts)
        self._cells.append(self._grid.cells(pts))
        self._note_spacing(pts, ordered)
        window = np.concatenate(self._buffer)
        if not self._sigma_ready(window):
            return UpdateInfo(len(pts), 0, int(self._alive.sum()),
                              time.perf_counter() - t0, skipped='estimating noise')
        sigma = self.sigma
        r = self.r
        cfg = self._config_for(r, sigma)
        reach = cfg.merge_reach * r + cfg.kappa * sigma + self.config.margin
        active = self._grid.near(window, REFIT_REACH * reach,
                                 np.unique(np.concatenate(self._cells)))
        active = active[self._alive[active]]
        active = active[near_points(window, self._seg[active], REFIT_REACH * reach)]
        old = self._seg[active]
        virt, vw = self._virtual_points(old, self._sup[active], r)
        index = PointIndex(np.concatenate([window, virt]),
                           np.concatenate([np.ones(len(window)), vw]), virtual=len(virt),
                           sample_spacing=8.0)
        segs = old
        for _ in range(int(self.config.iterations)):
            segs, sup, info = smemsf_iteration(index, segs, sigma, cfg, incremental=True)
        # A short chord across a corner (e.g. a T-junction seen from few angles) is kept alive by
        # its own virtual points; the new points decide whether the walls explain it.
        keep = ~_corner_chords(index, segs, cfg.kappa * sigma, 2.0 * sigma, 8.0 * r,
                               np.deg2rad(20.0))
        segs, sup = segs[keep], sup[keep]
        # Free-space clearing: a short segment the new scan sees through is gone.
        if self.config.clear_max_length > 0:
            short = lengths(segs) <= self.config.clear_max_length
            for lo, hi, o in views:
                if short.any():
                    gone = short & seen_through(segs, o, pts[lo:hi], cfg.kappa * sigma)
                    segs, sup, short = segs[~gone], sup[~gone], short[~gone]
        if cfg.sigma is None and np.isfinite(info['residual_scale']):
            self._scales.append(info['residual_scale'])
            self.sigma = max(_median(self._scales), self._sigma0)
        cap = self.config.virtual_cap * np.maximum(lengths(segs) / (2.0 * r), 1.0)
        self._replace(active, segs, np.minimum(sup, cap))
        self.updates += 1
        return UpdateInfo(len(pts), int(active.size), int(self._alive.sum()),
                          time.perf_counter() - t0)

    @property
    def r(self) -> float:
        """
        Return the LSS half-size in metres.

        That is ``r_over_sigma`` x sigma, but the square side 2r is never below the point
        spacing of a scan: the running median, over the last ``sigma_window`` scans, of the
        upper quartile of each scan's nearest-neighbour distances.
        """
        cfg = self.config.smemsf
        r = cfg.r_over_sigma * (self.sigma or cfg.sigma_min)
        if self._spacings:
            r = max(r, 0.5 * _median(self._spacings))
        return r

    # -- internals -----------------------------------------------------------------------------
    def _note_spacing(self, pts: np.ndarray, ordered: bool = False) -> None:
        """Pool the upper quartile of one scan's point spacing (nearest neighbour within it)."""
        if len(pts) < 3:
            return
        if ordered:
            # On the shared logs the upper quartile of these equals the k-d tree's to 1.000x
            # (median over scans; 1.02x at the 90th percentile on fr079).
            gap = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
            nearest = np.minimum(np.append(gap, np.inf), np.insert(gap, 0, np.inf))
            self._spacings.append(_percentile(nearest, SPACING_QUANTILE))
            return
        # At most about 256 query points (a scan's upper quartile needs no more; the running
        # median over scans smooths it further), so the cost stays far below the fit's.
        probe = pts[::max(1, len(pts) // 256)]
        d, _ = cKDTree(pts, balanced_tree=False, compact_nodes=False).query(probe, k=2)
        self._spacings.append(_percentile(d[:, 1], SPACING_QUANTILE))

    def _config_for(self, r: float, sigma: float) -> SMEMSFConfig:
        cfg = self.config.smemsf
        ratio = r / sigma
        if ratio == cfg.r_over_sigma:
            return cfg
        if self._fit_config is None or self._fit_config.r_over_sigma != ratio:
            self._fit_config = replace(cfg, r_over_sigma=ratio)
        return self._fit_config

    def _sigma_ready(self, window: np.ndarray) -> bool:
        if self.sigma is not None:
            return True
        cfg = self.config.smemsf
        est = estimate_noise(window, radius=cfg.noise_radius, rng=len(self._noise))
        if np.isfinite(est):
            self._noise.append(est)
        if len(self._noise) >= self.config.noise_updates:
            self.sigma = self._sigma0 = max(float(np.median(self._noise)), cfg.sigma_min)
            return True
        return False

    def _virtual_points(self, segs: np.ndarray, sup: np.ndarray, r: float) -> tuple:
        if len(segs) == 0:
            return np.zeros((0, 2)), np.zeros(0)
        pts, owner = sample_segments(segs, 2.0 * r)
        per = np.bincount(owner, minlength=len(segs))
        w = np.minimum(sup / per, self.config.virtual_cap)
        return pts, w[owner]

    def _replace(self, old_ids: np.ndarray, segs: np.ndarray, sup: np.ndarray) -> None:
        self._grid.remove(old_ids)
        self._alive[old_ids] = False
        free = np.flatnonzero(~self._alive)
        if free.size < len(segs):
            grow = max(len(self._alive), len(segs) - free.size)
            self._seg = np.concatenate([self._seg, np.zeros((grow, 2, 2))])
            self._sup = np.concatenate([self._sup, np.zeros(grow)])
            self._alive = np.concatenate([self._alive, np.zeros(grow, dtype=bool)])
            free = np.flatnonzero(~self._alive)
        ids = free[:len(segs)]
        self._seg[ids] = segs
        self._sup[ids] = sup
        self._alive[ids] = True
        self._grid.add(ids, segs)
