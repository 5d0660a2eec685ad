"""
Per-scan split-and-merge (iterative end-point fit) with segments merged across scans.

Each scan is broken into chains of consecutive valid readings at range jumps; each chain is
simplified with the iterative end-point fit (Douglas-Peucker; ``cv2.approxPolyDP`` in the
benchmark; the numpy version here gives the same vertices up to cv2's float32 rounding); each
piece between two vertices is
refitted by total least squares and cut to the projections of its first and last point; the
pieces go to the world frame with the scan pose and are merged into the map by SegmentMerger
(collinear and overlapping or nearly touching), from sufficient statistics, so a merged segment is
the exact least-squares line of all the points behind it.
"""

from collections import defaultdict

import numpy as np
from polyline_mapper.scan import valid_ranges

from .lines import fit_line


def break_at_jumps(ranges, angles, range_min: float, range_max: float, jump: float = 0.2,
                   jump_rel: float = 0.05, min_points: int = 4) -> list:
    """
    Chains of consecutive valid readings, broken at invalid readings and range jumps.

    A jump is |r_i - r_i+1| > jump + jump_rel * min(r_i, r_i+1) (metres).

    Returns
    -------
    List of index arrays into the scan, each with at least ``min_points`` readings.

    """
    r = np.asarray(ranges, dtype=np.float64).ravel()
    if r.shape != np.shape(np.ravel(angles)):
        raise ValueError('ranges and angles differ in length')
    ok = valid_ranges(r, range_min, range_max)
    rr = np.where(ok, r, 0.0)
    brk = (~ok[1:] | ~ok[:-1]
           | (np.abs(np.diff(rr)) > jump + jump_rel * np.minimum(rr[1:], rr[:-1])))
    cut = np.flatnonzero(brk) + 1
    chains = np.split(np.arange(r.size), cut)
    return [c for c in chains if c.size >= min_points and ok[c].all()]


def iterative_end_point_fit(chain: np.ndarray, epsilon: float) -> np.ndarray:
    """
    Douglas-Peucker / iterative end-point fit of an open chain.

    Parameters
    ----------
    chain
        (M, 2) ordered points, metres.
    epsilon
        Largest allowed distance (m) of a point to its piece's chord.

    Returns
    -------
    Sorted vertex indices into ``chain`` (first and last included).

    """
    pts = np.asarray(chain, dtype=np.float64)
    m = len(pts)
    if m < 3:
        return np.arange(m)
    keep = np.zeros(m, dtype=bool)
    keep[[0, m - 1]] = True
    stack = [(0, m - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        d = pts[b] - pts[a]
        rel = pts[a + 1:b] - pts[a]
        norm = np.hypot(*d)
        if norm > 0:
            dist = np.abs(d[0] * rel[:, 1] - d[1] * rel[:, 0]) / norm
        else:
            dist = np.hypot(rel[:, 0], rel[:, 1])
        j = int(np.argmax(dist))
        if dist[j] > epsilon:
            keep[a + 1 + j] = True
            stack += [(a, a + 1 + j), (a + 1 + j, b)]
    return np.flatnonzero(keep)


def approx_poly(chain: np.ndarray, epsilon: float, use_cv2: bool = True) -> np.ndarray:
    """Vertex indices of ``cv2.approxPolyDP(chain, epsilon, closed=False)`` (numpy fallback)."""
    if not use_cv2 or len(chain) < 3:
        return iterative_end_point_fit(chain, epsilon)
    import cv2
    c32 = np.ascontiguousarray(chain, dtype=np.float32)
    verts = cv2.approxPolyDP(c32.reshape(-1, 1, 2), float(epsilon), False).reshape(-1, 2)
    idx, j = [], 0
    for v in verts:
        while j < len(c32) and not (c32[j] == v).all():
            j += 1
        idx.append(j)
    return np.array(idx, dtype=np.intp)


def _stats(p: np.ndarray) -> np.ndarray:
    """Sufficient statistics of a point set: n, sum x, sum y, sum xx, sum xy, sum yy."""
    x, y = p[:, 0], p[:, 1]
    return np.array([len(p), x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()])


def _line_from_stats(s: np.ndarray) -> tuple:
    """Centre and unit direction of the total least-squares line of sufficient statistics."""
    n = s[0]
    c = s[1:3] / n
    sxx = s[3] / n - c[0] ** 2
    sxy = s[4] / n - c[0] * c[1]
    syy = s[5] / n - c[1] ** 2
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    return c, np.array([np.cos(theta), np.sin(theta)])


def scan_segments(ranges, angles, pose, range_min: float, range_max: float,
                  epsilon: float = 0.05, jump: float = 0.2, jump_rel: float = 0.05,
                  min_points: int = 5, use_cv2: bool = True) -> tuple:
    """
    Segments of one scan in the world frame.

    Returns
    -------
    segments : (S, 2, 2) metres, world frame.
    stats : (S, 6) sufficient statistics of each segment's points (world frame).

    """
    r = np.asarray(ranges, dtype=np.float64).ravel()
    a = np.asarray(angles, dtype=np.float64).ravel()
    x, y, yaw = (float(v) for v in pose)
    cy, sy = np.cos(yaw), np.sin(yaw)
    segs, stats = [], []
    for idx in break_at_jumps(r, a, range_min, range_max, jump, jump_rel, min_points):
        local = np.stack([r[idx] * np.cos(a[idx]), r[idx] * np.sin(a[idx])], axis=1)
        world = np.stack([x + cy * local[:, 0] - sy * local[:, 1],
                          y + sy * local[:, 0] + cy * local[:, 1]], axis=1)
        verts = approx_poly(local, epsilon, use_cv2)
        for v0, v1 in zip(verts[:-1], verts[1:]):
            piece = world[v0:v1 + 1]
            if len(piece) < min_points:
                continue
            c, u = fit_line(piece)
            t0, t1 = (piece[0] - c) @ u, (piece[-1] - c) @ u
            segs.append([c + t0 * u, c + t1 * u])
            stats.append(_stats(piece))
    if not segs:
        return np.zeros((0, 2, 2)), np.zeros((0, 6))
    return np.array(segs), np.array(stats)


class SegmentMerger:
    """
    A segment map that merges each new segment with collinear, overlapping map segments.

    Two segments merge when their directions differ by less than ``max_angle`` (deg), both ends
    of the shorter lie within ``max_offset`` (m) of the longer one's line, and along that line
    they overlap or leave a gap of at most ``max_gap`` (m). The merged segment is the
    least-squares line of all their points (from summed sufficient statistics), cut to the
    projections of the four ends; it is then tested again until nothing merges. Candidates come
    from a grid of ``cell`` metres.
    """

    def __init__(self, max_angle: float = 5.0, max_offset: float = 0.05, max_gap: float = 0.10,
                 cell: float = 1.0):
        """Set the merge thresholds (degrees, metres) and the grid cell (m)."""
        self.cos_max = float(np.cos(np.deg2rad(max_angle)))
        self.max_offset = float(max_offset)
        self.max_gap = float(max_gap)
        self.cell = float(cell)
        self.seg, self.stats = {}, {}
        self.cells = defaultdict(set)
        self.owned = {}
        self.next_id = 0

    def __len__(self) -> int:
        return len(self.seg)

    def _keys(self, s: np.ndarray, pad: float) -> list:
        lo = np.floor((s.min(axis=0) - pad) / self.cell).astype(int)
        hi = np.floor((s.max(axis=0) + pad) / self.cell).astype(int)
        return [(i, j) for i in range(lo[0], hi[0] + 1) for j in range(lo[1], hi[1] + 1)]

    def _mergeable(self, a: np.ndarray, b: np.ndarray) -> bool:
        da, db = a[1] - a[0], b[1] - b[0]
        la, lb = np.hypot(*da), np.hypot(*db)
        if la <= 0 or lb <= 0:
            return True
        if abs(da @ db) / (la * lb) < self.cos_max:
            return False
        long_, short, ll = (a, b, la) if la >= lb else (b, a, lb)
        u = (long_[1] - long_[0]) / ll
        rel = short - long_[0]
        off = np.abs(u[0] * rel[:, 1] - u[1] * rel[:, 0])
        if off.max() > self.max_offset:
            return False
        t = rel @ u
        return max(0.0, t.min() - ll, -t.max()) <= self.max_gap

    def _remove(self, i: int) -> None:
        for key in self.owned.pop(i):
            self.cells[key].discard(i)
        del self.seg[i], self.stats[i]

    def add(self, segment: np.ndarray, stats: np.ndarray) -> None:
        """Merge one segment (2, 2) with its sufficient statistics (6,) into the map."""
        seg = np.asarray(segment, dtype=np.float64)
        st = np.asarray(stats, dtype=np.float64)
        pad = self.max_gap + self.max_offset
        while True:
            cand = set()
            for key in self._keys(seg, pad):
                cand |= self.cells.get(key, set())
            hit = next((j for j in sorted(cand) if self._mergeable(seg, self.seg[j])), None)
            if hit is None:
                break
            st = st + self.stats[hit]
            ends = np.concatenate([seg, self.seg[hit]])
            self._remove(hit)
            c, u = _line_from_stats(st)
            t = (ends - c) @ u
            seg = np.array([c + t.min() * u, c + t.max() * u])
        i = self.next_id
        self.next_id += 1
        self.seg[i], self.stats[i] = seg, st
        self.owned[i] = self._keys(seg, 0.0)
        for key in self.owned[i]:
            self.cells[key].add(i)

    def add_many(self, segments: np.ndarray, stats: np.ndarray) -> None:
        """Merge several segments, one after the other."""
        for s, st in zip(segments, stats):
            self.add(s, st)

    def segments(self, min_points: int = 0) -> np.ndarray:
        """Return the map (K, 2, 2), metres: segments backed by at least ``min_points`` points."""
        out = [s for i, s in self.seg.items() if self.stats[i][0] >= min_points]
        return np.array(out) if out else np.zeros((0, 2, 2))
