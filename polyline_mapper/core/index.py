"""
Spatial indexes: which points and segments lie near which.

- ``cell_keys`` / ``dilate_cells`` / ``in_sorted``: square-grid hashing of points into int64
  keys, neighbourhoods of cells, and sorted-table lookups;
- ``PointIndex`` (a k-d tree over a point set) with ``Pairs``, its point-segment pairs within a
  radius, ``piece_pairs`` and ``nearest_distance``: the queries every step of the fit makes;
- ``SegmentGrid`` (a grid hash over a changing segment map) and ``near_points``: which map
  segments an incremental update must refit.

Every query is vectorised; the k-d trees are scipy's ``cKDTree``.
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .geometry import as_points, directions, project, sample_segments


DILATE_BUDGET = 1 << 20
"""Most cell keys ``SegmentGrid.near`` builds by dilation (8 MB); wider queries use a k-d tree."""


def cell_keys(points: np.ndarray, cell: float) -> np.ndarray:
    """
    One int64 key per point for the square grid cell (side ``cell`` metres) that holds it.

    Keys order like the cells' (column, row) pairs, so sorting keys sorts cells
    lexicographically; cell indices up to +-2**30 are supported.
    """
    ij = np.floor(points / cell).astype(np.int64) + (1 << 30)
    return (ij[:, 0] << 32) | ij[:, 1]


def dilate_cells(keys: np.ndarray, rings: int) -> np.ndarray:
    """Keys (``cell_keys`` layout) of the cells within ``rings`` cells of any ``keys``, sorted."""
    offs = np.arange(-rings, rings + 1, dtype=np.int64)
    shift = ((offs[:, None] << 32) + offs[None]).ravel()
    return np.unique((np.asarray(keys)[:, None] + shift).ravel())


def _cell_ij(keys: np.ndarray) -> np.ndarray:
    """Return the (column, row) indices of ``cell_keys`` keys as an (M, 2) float array."""
    keys = np.asarray(keys, dtype=np.int64)
    return np.stack([keys >> 32, keys & 0xFFFFFFFF], axis=1).astype(np.float64)


def in_sorted(values: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``np.isin(values, table)`` for a sorted ``table``, by binary search (no sorting)."""
    if len(table) == 0:
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(table, values), len(table) - 1)
    return table.take(at) == values


COUNT_TABLE = 1 << 20
"""``unique_counts`` counts keys in a table of this many entries at most (8 MB), else sorts."""


def unique_counts(keys: np.ndarray, bound: int) -> tuple:
    """
    ``np.unique(keys, return_counts=True)`` for int keys in ``[0, bound)``.

    While ``bound`` is at most ``COUNT_TABLE`` the keys are counted in a table (``np.bincount``)
    instead of sorted: the same sorted keys and counts, in O(keys + bound).

    >>> [a.tolist() for a in unique_counts(np.array([7, 2, 7, 0, 2, 7]), 10)]
    [[0, 2, 7], [1, 2, 3]]
    """
    if bound > COUNT_TABLE:
        return np.unique(keys, return_counts=True)
    cnt = np.bincount(keys, minlength=bound)
    key = np.flatnonzero(cnt)
    return key, cnt.take(key)


@dataclass
class Pairs:
    """Point-segment pairs closer than a radius, with their projection geometry."""

    pt: np.ndarray
    seg: np.ndarray
    dist: np.ndarray
    along: np.ndarray
    normal: np.ndarray

    def where(self, keep: np.ndarray) -> 'Pairs':
        """Return the pairs where ``keep`` (bool, one per pair) is True; all: these pairs."""
        if keep.all():
            return self
        ids = np.flatnonzero(keep)
        return Pairs(*(np.take(a, ids) for a in (self.pt, self.seg, self.dist, self.along,
                                                 self.normal)))


class PointIndex:
    """
    A point set with a k-d tree, answering segment queries.

    Building costs O(N log N) once; every query costs about the number of pairs it returns
    plus the number of segment samples, so fitting scales with points, not points x segments.
    """

    def __init__(self, points: np.ndarray, weights: np.ndarray = None, virtual: int = 0,
                 sample_spacing: float = 3.0, extra: np.ndarray = None,
                 beams: np.ndarray = None):
        """
        Index points with optional multiplicities.

        The last ``virtual`` points are virtual (they stand for an old map, see
        ``incremental.py``); the rest are measurements. ``sample_spacing`` (in query radii) is
        how far apart ``pairs`` samples the segments: coarser samples mean fewer samples to
        index and a wider reach, so more candidates to discard. 3 suits large dense point sets
        (a batch fit, scoring a map); on the incremental mapper's small queries (2-4k points,
        tens of segments) 8 was fastest of 2-12, 0.8x the time at 3.

        ``extra`` (N,): each point's noise beyond the map's noise scale, metres (a lidar's error
        that grows with the range: ``SMEMSFConfig.range_noise`` x the range; 0 for virtual
        points). A point's own noise scale is then hypot(sigma, extra) (``sigmas``); None: every
        point has the map's sigma.

        ``beams`` (N, 2): the unit vector of each point's beam, from the laser to the point (0
        for virtual points and bare points). With it, a laser's range error, which moves a
        point along its beam, counts along a line as much as the beam runs along it: trimming
        takes each end from the supporting points' positions moved inwards by ``END_SIGMAS``
        times that error (``emsf.emsf_step``). None: ends from the positions as they are (the
        incremental mapper passes beams only with ``SMEMSFConfig.range_noise`` > 0).
        """
        self.points = as_points(points)
        self.weights = (np.ones(len(self.points)) if weights is None
                        else np.asarray(weights, dtype=np.float64))
        if self.weights.shape != (len(self.points),):
            raise ValueError(f'weights must have shape ({len(self.points)},), '
                             f'got {self.weights.shape}')
        self.n_real = len(self.points) - int(virtual)
        self.sample_spacing = float(sample_spacing)
        self.x, self.y = self.points[:, 0].copy(), self.points[:, 1].copy()
        self.tree = cKDTree(self.points, balanced_tree=False, compact_nodes=False)
        self.extra = None
        if extra is not None:
            extra = np.asarray(extra, dtype=np.float64)
            if extra.shape != (len(self.points),) or not (np.isfinite(extra) & (extra >= 0)).all():
                raise ValueError(f'extra must be {len(self.points)} finite values >= 0')
            if extra.size and extra.max() > 0:
                self.extra = extra
        self.beams = None
        if beams is not None:
            beams = np.asarray(beams, dtype=np.float64)
            if beams.shape != (len(self.points), 2) or not np.isfinite(beams).all():
                raise ValueError(f'beams must be ({len(self.points)}, 2) finite values')
            if beams.size and np.abs(beams).max() > 0:
                self.beams = beams

    def __len__(self) -> int:
        return len(self.points)

    def pairs(self, segments: np.ndarray, radius: float) -> Pairs:
        """
        All (point, segment) pairs with point-to-segment distance <= radius.

        Each segment is sampled at ``n + 1`` evenly spaced points at most ``sample_spacing x
        radius`` apart (see ``__init__``). A point within ``radius`` of a segment is within
        ``reach = hypot(radius, step / 2)`` of the sample nearest to its projection (its *home*
        sample), so one k-d tree query of all samples with ``reach`` finds every pair; keeping
        only hits on the home sample leaves each pair exactly once, without sorting.
        """
        if len(segments) == 0 or len(self.points) == 0 or radius <= 0:
            return Pairs(*(np.zeros(0, dtype=np.intp),) * 2, *(np.zeros(0),) * 3)
        u, length = directions(segments)
        spacing = self.sample_spacing * radius
        n = np.maximum(1, np.ceil(length / spacing).astype(np.intp))
        step = length / n
        # The samples of ``sample_segments(segments, spacing)`` (the same arithmetic), with each
        # one's position ``pos`` on its segment; per-sample copies of the segment quantities
        # then serve every hit through its sample index alone.
        owner = np.repeat(np.arange(len(segments)), n + 1)
        pos = np.arange(owner.size) - np.take(np.cumsum(n + 1) - (n + 1), owner)
        a = np.take(segments[:, 0], owner, axis=0)
        samples = a + (np.take(segments[:, 1], owner, axis=0) - a) * (pos / n.take(owner))[:, None]
        reach = np.hypot(radius, 0.5 * step.max()) * (1 + 1e-9)
        hits = cKDTree(samples, balanced_tree=False, compact_nodes=False).sparse_distance_matrix(
            self.tree, reach, output_type='ndarray')
        # The query reaches as far as the longest step needs; a hit beyond its own segment's
        # reach cannot be a home pair within radius: dropped first, few hits on another sample
        # are left, so the distances are computed for all the rest (the kept pairs, their order
        # and values are the same).
        own = np.hypot(radius, 0.5 * step) * (1 + 1e-9)
        mine = np.flatnonzero(hits['v'] <= own.take(owner).take(hits['i']))
        si, pt = hits['i'].take(mine), hits['j'].take(mine)
        ux, uy = u[:, 0].take(owner).take(si), u[:, 1].take(owner).take(si)
        rx = self.x.take(pt) - a[:, 0].take(si)
        ry = self.y.take(pt) - a[:, 1].take(si)
        along = rx * ux + ry * uy
        clipped = np.clip(along, 0.0, length.take(owner).take(si))
        safe_step = np.where(step > 0, step, 1.0).take(owner)
        home = np.rint(clipped / safe_step.take(si)) == pos.take(si)
        normal = ux * ry - uy * rx
        dist = np.hypot(normal, clipped - along)
        keep = np.flatnonzero(home & (dist <= radius))
        return Pairs(pt.take(keep).astype(np.intp, copy=False), owner.take(si.take(keep)),
                     dist.take(keep), along.take(keep), normal.take(keep))

    def sigmas(self, sigma: float):
        """Return each point's noise scale (N,) at the map's ``sigma`` (m); None: all ``sigma``."""
        return None if self.extra is None else np.hypot(sigma, self.extra)

    def widest(self, sigma: float) -> float:
        """Return the largest noise scale of a point (m) at the map's ``sigma``."""
        return sigma if self.extra is None else float(np.hypot(sigma, self.extra.max()))

    def count_in_disks(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """Total point weight within ``radius`` of each centre, shape (len(centres),)."""
        if len(centres) == 0:
            return np.zeros(0)
        if np.all(self.weights == 1.0):
            return self.tree.query_ball_point(centres, radius, return_length=True).astype(float)
        hits = cKDTree(centres).sparse_distance_matrix(self.tree, radius, output_type='ndarray')
        return np.bincount(hits['i'], weights=self.weights[hits['j']], minlength=len(centres))


PIECE_SCAN = 8
"""Pieces of one parent that ``piece_pairs`` tests against every pair of it; more are searched."""


def _first_at_least(values: np.ndarray, lo: np.ndarray, hi: np.ndarray, x: np.ndarray,
                    strict: bool = False) -> np.ndarray:
    """
    Find, per query, the first index in ``[lo, hi)`` where ``values >= x`` (``> x`` if ``strict``).

    ``values`` must be non-decreasing over each query's range; ``hi`` when there is none. A
    binary search of all queries at once: about log2(longest range) vectorised steps.
    """
    lo, hi = lo.copy(), hi.copy()
    live = np.flatnonzero(lo < hi)
    while live.size:
        mid = (lo[live] + hi[live]) >> 1
        v = values.take(mid)
        xs = x.take(live)
        up = v > xs if strict else v >= xs
        hi[live] = np.where(up, mid, hi[live])
        lo[live] = np.where(up, lo[live], mid + 1)
        live = live[lo.take(live) < hi.take(live)]
    return lo


def _group_running_max(values: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Take the running maximum of ``values`` within each run of equal ``group`` (doubling)."""
    out = values.copy()
    step = 1
    while step < out.size:
        same = group[step:] == group[:-step]
        if not same.any():
            break
        shifted = np.maximum(out[step:], np.where(same, out[:-step], -np.inf))
        out[step:] = shifted
        step *= 2
    return out


def piece_pairs(p: Pairs, parent: np.ndarray, start: np.ndarray, length: np.ndarray,
                radius: float) -> Pairs:
    """
    Pairs of pieces of segments, derived from the pairs of the segments without a new query.

    Piece ``j`` lies on the line of segment ``parent[j]`` from along-position ``start[j]`` (metres
    from that segment's first end, may be negative) over ``length[j]`` metres, in the same
    direction. ``p`` must hold every pair of the parent segments within ``radius`` plus the
    farthest any piece reaches past its parent's ends; then the result is exactly what
    ``PointIndex.pairs(pieces, radius)`` returns, up to rounding and order.

    A pair of a parent with at most ``PIECE_SCAN`` pieces is tested against each of them; with
    more, only against the pieces whose along-span comes within ``radius`` of the point (found
    by binary search), so memory follows the pairs, not pairs times pieces (a 10 km line of
    5000 points cut into 5000 pieces had asked for 25 M candidate rows, 1.2 GB).
    """
    order = np.lexsort((start, parent))            # by parent, then along it
    n_seg = int(max(parent.max(initial=-1), p.seg.max(initial=-1))) + 1
    count = np.bincount(parent, minlength=n_seg)
    first = np.cumsum(count) - count              # where each segment's pieces start in order
    n = count.take(p.seg)                          # pieces of each pair's parent
    lo = first.take(p.seg)
    hi = lo + n
    many = np.flatnonzero(n > PIECE_SCAN)
    if many.size:
        s = start.take(order)
        end = _group_running_max(s + length.take(order), parent.take(order))
        a = p.along.take(many)
        # Candidates only need to include every piece the exact test below keeps; the slack
        # covers rounding between the two ways of computing the along-gap.
        reach = radius + 1e-9 * (1.0 + np.abs(a) + radius)
        lo_m, hi_m = lo.take(many), hi.take(many)
        lo[many] = _first_at_least(end, lo_m, hi_m, a - reach)
        hi[many] = _first_at_least(s, lo_m, hi_m, a + reach, strict=True)
    c = np.maximum(hi - lo, 0)
    row = np.repeat(np.arange(p.seg.size), c)
    piece = order.take(np.repeat(lo - (np.cumsum(c) - c), c) + np.arange(int(c.sum())))
    along = p.along.take(row) - start.take(piece)
    normal = p.normal.take(row)
    dist = np.hypot(normal, np.clip(along, 0.0, length.take(piece)) - along)
    keep = np.flatnonzero(dist <= radius)
    return Pairs(p.pt.take(row.take(keep)), piece.take(keep), dist.take(keep), along.take(keep),
                 normal.take(keep))


def nearest_distance(points: np.ndarray, segments: np.ndarray, index: PointIndex = None,
                     radius: float = 0.5, chunk: int = 4_000_000,
                     segment_chunk: int = 2000, point_chunk: int = 100_000) -> tuple:
    """
    Exact distance from every point to its nearest segment.

    Points within ``radius`` of some segment are resolved through the index, ``segment_chunk``
    segments per query (so a map of many overlapping segments cannot make one query's pair list
    exhaust memory); the rest (usually few) are compared with every segment, in chunks of at
    most ``chunk`` point-segment pairs. More than ``point_chunk`` points are resolved that many
    at a time (``index`` is then not used), so memory is bounded whatever the point count.

    Returns
    -------
    dist : (N,) metres (inf when there are no segments).
    nearest : (N,) index of the nearest segment (-1 when there are no segments).

    """
    n = len(points)
    dist = np.full(n, np.inf)
    nearest = np.full(n, -1, dtype=np.intp)
    if len(segments) == 0 or n == 0:
        return dist, nearest
    if n > point_chunk:
        # The pairs within ``radius`` of a cluttered map are many per point (about 1 kB a point
        # on fr079: 1.9 GB for its 1.7 M points at once); a chunk of points at a time bounds
        # them. Each point's distance is its own, so the chunks give the same distances.
        points = as_points(points)
        for p0 in range(0, n, point_chunk):
            dist[p0:p0 + point_chunk], nearest[p0:p0 + point_chunk] = nearest_distance(
                points[p0:p0 + point_chunk], segments, None, radius, chunk, segment_chunk,
                point_chunk)
        return dist, nearest
    index = index if index is not None else PointIndex(points)
    for s0 in range(0, len(segments), segment_chunk):
        p = index.pairs(segments[s0:s0 + segment_chunk], radius)
        if len(p.pt):
            closer = p.dist < dist[p.pt]
            pt, d, seg = p.pt[closer], p.dist[closer], p.seg[closer] + s0
            np.minimum.at(dist, pt, d)
            win = d == dist[pt]
            nearest[pt[win]] = seg[win]
    rest = np.flatnonzero(~np.isfinite(dist))
    k = len(segments)
    step = max(1, chunk // k)
    for s in range(0, rest.size, step):
        ix = rest[s:s + step]
        d, _, _ = project(np.repeat(points[ix], k, axis=0), np.tile(segments, (ix.size, 1, 1)))
        d = d.reshape(ix.size, k)
        j = np.argmin(d, axis=1)
        dist[ix] = d[np.arange(ix.size), j]
        nearest[ix] = j
    return dist, nearest


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
        The query cells are dilated by ceil(dist / cell) rings while that makes at most
        ``DILATE_BUDGET`` keys; beyond (a large ``dist`` or many cells) each registered cell is
        tested against the query cells with a k-d tree in the max norm instead, with the same
        result in memory proportional to the map and the query.
        """
        if cells is None:
            cells = self.cells(points)
        if len(cells) == 0:
            return np.zeros(0, dtype=np.intp)
        rings = int(np.ceil(dist / self.cell))
        if len(cells) * (2 * rings + 1) ** 2 > DILATE_BUDGET:
            return self._near_by_tree(cells, rings)
        cells = dilate_cells(cells, rings)
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

    def _near_by_tree(self, cells: np.ndarray, rings: int) -> np.ndarray:
        """Return ``near`` for a wide reach: live ids within ``rings`` cells (max norm)."""
        key, sid, gen = (np.concatenate(a) for a in zip(self._main, self._tail))
        live = gen == self._gen[sid]
        key, sid = key[live], sid[live]
        if key.size == 0:
            return np.zeros(0, dtype=np.intp)
        tree = cKDTree(_cell_ij(cells))
        d, _ = tree.query(_cell_ij(key), p=np.inf, distance_upper_bound=rings + 0.5)
        return np.unique(sid[np.isfinite(d)])


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
