"""
Segment geometry on arrays.

Conventions used across the core:

- points: ``(N, 2)`` float64 array, metres, in one fixed frame.
- segments: ``(K, 2, 2)`` float64 array, ``segments[k] = [[x1, y1], [x2, y2]]``, metres.
- pairs: parallel 1-D arrays ``(pt, seg)`` naming a point and a segment that are close.

Nothing here loops over points in Python; the only index structure is a scipy ``cKDTree`` over
the points, built once per point set and reused for every segment set.

Rows of ``(N, 2)`` and ``(K, 2, 2)`` arrays are gathered with ``np.take(a, i, axis=0)`` (and
selected with ``np.compress``) rather than ``a[i]``: for thousands of rows NumPy's general
fancy indexing is 5-10x slower on them (measured with NumPy 2.4, 2 to 16 bytes per row).
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


def as_points(points, name: str = 'points') -> np.ndarray:
    """
    Validate and convert a point set.

    Parameters
    ----------
    points : array_like, shape (N, 2)
        Finite x, y coordinates in metres.
    name : str
        Argument name used in error messages.

    Returns
    -------
    (N, 2) float64 array (a copy only when conversion is needed).

    Raises
    ------
    ValueError
        On a wrong shape, non-numeric or non-finite values.

    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f'{name} must be numeric, got {type(points).__name__}') from exc
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f'{name} must have shape (N, 2), got {arr.shape}')
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise ValueError(f'{name} has {int(bad.sum())} row(s) with NaN or inf '
                         f'(first at row {int(np.argmax(bad))})')
    return arr


def as_segments(segments, name: str = 'segments') -> np.ndarray:
    """Validate and convert segments to a ``(K, 2, 2)`` float64 array (K may be 0)."""
    arr = np.asarray(segments, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 2, 2))
    if arr.ndim == 2 and arr.shape[1] == 4:
        arr = arr.reshape(-1, 2, 2)
    if arr.ndim != 3 or arr.shape[1:] != (2, 2):
        raise ValueError(f'{name} must have shape (K, 2, 2) or (K, 4), got {arr.shape}')
    if not np.isfinite(arr).all():
        raise ValueError(f'{name} contains NaN or inf')
    return arr


def lengths(segments: np.ndarray) -> np.ndarray:
    """Segment lengths, shape (K,), metres."""
    d = segments[:, 1] - segments[:, 0]
    return np.hypot(d[:, 0], d[:, 1])


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


def in_sorted(values: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``np.isin(values, table)`` for a sorted ``table``, by binary search (no sorting)."""
    if len(table) == 0:
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(table, values), len(table) - 1)
    return table.take(at) == values


def directions(segments: np.ndarray) -> tuple:
    """
    Return unit directions and lengths of segments.

    Returns
    -------
    u : (K, 2) unit vectors from the first to the second end point ([1, 0] for zero length).
    length : (K,) metres.

    """
    d = segments[:, 1] - segments[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 0
    u = d / np.where(ok, length, 1.0)[:, None]
    u[~ok] = (1.0, 0.0)
    return u, length


def project(points: np.ndarray, segments: np.ndarray) -> tuple:
    """
    Project points onto segments, element by element.

    Parameters
    ----------
    points : (M, 2) array
        Points, metres.
    segments : (M, 2, 2) array
        Segment m is paired with point m.

    Returns
    -------
    dist : (M,) distance from the point to the segment (not the infinite line), metres.
    along : (M,) signed position of the projection on the line, metres from the first end.
    normal : (M,) signed offset from the infinite line, metres (left of the direction > 0).

    """
    u, length = directions(segments)
    rel = points - segments[:, 0]
    along = np.einsum('ij,ij->i', rel, u)
    normal = u[:, 0] * rel[:, 1] - u[:, 1] * rel[:, 0]
    beyond = np.clip(along, 0.0, length) - along
    dist = np.hypot(normal, beyond)
    return dist, along, normal


def sample_segments(segments: np.ndarray, step: float) -> tuple:
    """
    Sample points along segments, at most ``step`` apart, end points included.

    Returns
    -------
    samples : (S, 2) metres.
    owner : (S,) index of the segment each sample lies on.

    """
    if len(segments) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.intp)
    length = lengths(segments)
    n = np.maximum(1, np.ceil(length / step).astype(np.intp)) + 1
    owner = np.repeat(np.arange(len(segments)), n)
    first = np.cumsum(n) - n
    frac = (np.arange(owner.size) - first[owner]) / (n[owner] - 1)
    a = np.take(segments[:, 0], owner, axis=0)
    b = np.take(segments[:, 1], owner, axis=0)
    return a + (b - a) * frac[:, None], owner


@dataclass
class Pairs:
    """Point-segment pairs closer than a radius, with their projection geometry."""

    pt: np.ndarray
    seg: np.ndarray
    dist: np.ndarray
    along: np.ndarray
    normal: np.ndarray


class PointIndex:
    """
    A point set with a k-d tree, answering segment queries.

    Building costs O(N log N) once; every query costs about the number of pairs it returns
    plus the number of segment samples, so fitting scales with points, not points x segments.
    """

    def __init__(self, points: np.ndarray, weights: np.ndarray = None, virtual: int = 0,
                 sample_spacing: float = 3.0):
        """
        Index points with optional multiplicities.

        The last ``virtual`` points are virtual (they stand for an old map, see
        ``incremental.py``); the rest are measurements. ``sample_spacing`` (in query radii) is
        how far apart ``pairs`` samples the segments: coarser samples mean fewer samples to
        index and a wider reach, so more candidates to discard. 3 suits large dense point sets
        (a batch fit, scoring a map); on the incremental mapper's small queries (2-4k points,
        tens of segments) 8 was fastest of 2-12, 0.8x the time at 3.
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
        samples, owner = sample_segments(segments, spacing)
        first = np.cumsum(n + 1) - (n + 1)
        reach = np.hypot(radius, 0.5 * step.max()) * (1 + 1e-9)
        hits = cKDTree(samples, balanced_tree=False, compact_nodes=False).sparse_distance_matrix(
            self.tree, reach, output_type='ndarray')
        si = hits['i']
        seg = owner.take(si)
        pt = hits['j'].astype(np.intp)
        ux, uy, a = u[:, 0].take(seg), u[:, 1].take(seg), segments[:, 0]
        rx = self.x.take(pt) - a[:, 0].take(seg)
        ry = self.y.take(pt) - a[:, 1].take(seg)
        along = rx * ux + ry * uy
        clipped = np.clip(along, 0.0, length.take(seg))
        safe_step = np.where(step > 0, step, 1.0).take(seg)
        home = first.take(seg) + np.rint(clipped / safe_step).astype(np.intp)
        # Most hits are another sample's: drop them before the distances.
        h = np.flatnonzero(si == home)
        ux, uy, rx, ry, along, clipped = (v.take(h) for v in (ux, uy, rx, ry, along, clipped))
        normal = ux * ry - uy * rx
        dist = np.hypot(normal, clipped - along)
        k = np.flatnonzero(dist <= radius)
        keep = h.take(k)
        return Pairs(pt.take(keep), seg.take(keep), dist.take(k), along.take(k), normal.take(k))

    def count_in_disks(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """Total point weight within ``radius`` of each centre, shape (len(centres),)."""
        if len(centres) == 0:
            return np.zeros(0)
        if np.all(self.weights == 1.0):
            return self.tree.query_ball_point(centres, radius, return_length=True).astype(float)
        hits = cKDTree(centres).sparse_distance_matrix(self.tree, radius, output_type='ndarray')
        return np.bincount(hits['i'], weights=self.weights[hits['j']], minlength=len(centres))


def piece_pairs(p: Pairs, parent: np.ndarray, start: np.ndarray, length: np.ndarray,
                radius: float) -> Pairs:
    """
    Pairs of pieces of segments, derived from the pairs of the segments without a new query.

    Piece ``j`` lies on the line of segment ``parent[j]`` from along-position ``start[j]`` (metres
    from that segment's first end, may be negative) over ``length[j]`` metres, in the same
    direction. ``p`` must hold every pair of the parent segments within ``radius`` plus the
    farthest any piece reaches past its parent's ends; then the result is exactly what
    ``PointIndex.pairs(pieces, radius)`` returns, up to rounding and order.
    """
    order = np.argsort(parent, kind='stable')
    n_seg = int(max(parent.max(initial=-1), p.seg.max(initial=-1))) + 1
    first = np.searchsorted(parent[order], np.arange(n_seg), 'left')
    count = np.searchsorted(parent[order], np.arange(n_seg), 'right') - first
    c = np.take(count, p.seg)
    row = np.repeat(np.arange(p.seg.size), c)
    piece = np.take(order, np.repeat(np.take(first, p.seg) - (np.cumsum(c) - c), c)
                    + np.arange(int(c.sum())))
    along = np.take(p.along, row) - np.take(start, piece)
    normal = np.take(p.normal, row)
    dist = np.hypot(normal, np.clip(along, 0.0, np.take(length, piece)) - along)
    keep = np.flatnonzero(dist <= radius)
    return Pairs(np.take(np.take(p.pt, row), keep), np.take(piece, keep), np.take(dist, keep),
                 np.take(along, keep), np.take(normal, keep))


def nearest_distance(points: np.ndarray, segments: np.ndarray, index: PointIndex = None,
                     radius: float = 0.5, chunk: int = 4_000_000,
                     segment_chunk: int = 2000) -> tuple:
    """
    Exact distance from every point to its nearest segment.

    Points within ``radius`` of some segment are resolved through the index, ``segment_chunk``
    segments per query (so a map of many overlapping segments cannot make one query's pair list
    exhaust memory); the rest (usually few) are compared with every segment, in chunks of at
    most ``chunk`` point-segment pairs.

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


def end_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Distance between segments matched pair by pair, end to end, either way round.

    Returns
    -------
    (K,) the larger of the two end-point distances, for the better orientation, metres.

    """
    a = np.broadcast_to(a, np.broadcast_shapes(np.shape(a), np.shape(b)))
    b = np.broadcast_to(b, a.shape)
    same = np.maximum(np.linalg.norm(a[:, 0] - b[:, 0], axis=1),
                      np.linalg.norm(a[:, 1] - b[:, 1], axis=1))
    swap = np.maximum(np.linalg.norm(a[:, 0] - b[:, 1], axis=1),
                      np.linalg.norm(a[:, 1] - b[:, 0], axis=1))
    return np.minimum(same, swap)


def label_runs(flag: np.ndarray, group: np.ndarray) -> tuple:
    """
    Label runs of equal ``flag`` inside each ``group`` (items ordered by group).

    Returns
    -------
    run : (M,) run id of each item, from 0.
    n_runs : int

    """
    start = np.ones(flag.size, dtype=bool)
    start[1:] = (flag[1:] != flag[:-1]) | (group[1:] != group[:-1])
    run = np.cumsum(start) - 1
    return run, int(run[-1]) + 1 if run.size else 0


def group_minmax(values: np.ndarray, groups: np.ndarray, n_groups: int) -> tuple:
    """Per-group minimum and maximum of ``values`` (inf / -inf for empty groups)."""
    lo = np.full(n_groups, np.inf)
    hi = np.full(n_groups, -np.inf)
    np.minimum.at(lo, groups, values)
    np.maximum.at(hi, groups, values)
    return lo, hi
