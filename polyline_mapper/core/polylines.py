"""Order segments into polylines: chain segments whose ends meet."""

import numpy as np
from scipy.spatial import cKDTree


def _line_intersection(p, u, q, v):
    """Intersection of lines p + s u and q + t v, rows at a time; nan where near-parallel."""
    den = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    w = q - p
    s = (w[:, 0] * v[:, 1] - w[:, 1] * v[:, 0]) / np.where(np.abs(den) > 1e-12, den, np.nan)
    return p + s[:, None] * u


def assemble_polylines(segments: np.ndarray, join: float,
                       min_angle: float = np.deg2rad(10.0)) -> tuple:
    """
    Chain segments into polylines.

    Two segment ends closer than ``join`` are joined, closest pairs first, each end at most once.
    The shared vertex is the intersection of the two lines when they meet at an angle of at least
    ``min_angle`` and the intersection lies within ``join`` of both ends (a corner); otherwise it
    is the midpoint of the two ends.

    Parameters
    ----------
    segments : (K, 2, 2) metres.
    join : float, metres.

    Returns
    -------
    segments : (K, 2, 2) the same segments with joined ends moved to their shared vertex.
    polylines : list of (M, 2) vertex arrays (M >= 2).
    closed : list of bool, True when the chain returns to its first vertex.

    """
    segments = np.array(segments, dtype=np.float64, copy=True)
    k = len(segments)
    if k == 0:
        return segments, [], []
    ends = segments.reshape(-1, 2)
    partner = np.full(2 * k, -1, dtype=np.intp)
    pairs = cKDTree(ends).query_pairs(join, output_type='ndarray')
    pairs = pairs[pairs[:, 0] // 2 != pairs[:, 1] // 2]
    if len(pairs):
        gap = np.linalg.norm(ends[pairs[:, 0]] - ends[pairs[:, 1]], axis=1)
        pairs = pairs[np.argsort(gap, kind='stable')]
        for a, b in pairs:                      # greedy over end pairs (segments, not points)
            if partner[a] < 0 and partner[b] < 0:
                partner[a], partner[b] = b, a
        a = np.flatnonzero(partner >= 0)
        a = a[a < partner[a]]
        b = partner[a]
        sa, sb = a // 2, b // 2
        ua = segments[sa, 1] - segments[sa, 0]
        ub = segments[sb, 1] - segments[sb, 0]
        na = np.linalg.norm(ua, axis=1)
        nb = np.linalg.norm(ub, axis=1)
        sin = np.abs(ua[:, 0] * ub[:, 1] - ua[:, 1] * ub[:, 0]) / np.maximum(na * nb, 1e-300)
        x = _line_intersection(segments[sa, 0], ua, segments[sb, 0], ub)
        mid = 0.5 * (ends[a] + ends[b])
        near = (np.linalg.norm(x - ends[a], axis=1) <= join) & \
               (np.linalg.norm(x - ends[b], axis=1) <= join)
        corner = (sin >= np.sin(min_angle)) & near & np.isfinite(x).all(axis=1)
        vertex = np.where(corner[:, None], x, mid)
        ends[a] = vertex
        ends[b] = vertex
    segments = ends.reshape(-1, 2, 2)

    polylines, closed = [], []
    visited = np.zeros(k, dtype=bool)

    def walk(e_in):
        verts = [ends[e_in]]
        start = e_in
        while True:
            s = e_in // 2
            visited[s] = True
            e_out = e_in ^ 1
            verts.append(ends[e_out])
            p = partner[e_out]
            if p < 0:
                return np.array(verts), False
            if p == start:
                return np.array(verts), True
            if visited[p // 2]:
                return np.array(verts), False
            e_in = p

    free = np.flatnonzero(partner < 0)
    for e in free:                              # open chains start at a free end
        if not visited[e // 2]:
            verts, cl = walk(e)
            polylines.append(verts)
            closed.append(cl)
    for s in np.flatnonzero(~visited):          # what is left are cycles
        if not visited[s]:
            verts, cl = walk(2 * s)
            polylines.append(verts[:-1] if cl else verts)
            closed.append(cl)
    return segments, polylines, closed
