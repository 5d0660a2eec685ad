"""
Sequential RANSAC line extraction (skimage.measure.ransac with LineModelND).

Lines are extracted one by one from the points not yet explained: the best RANSAC line, its
inliers (residual <= ``threshold``) split along the line at gaps wider than ``gap``, each run of
at least ``min_points`` refitted by total least squares and cut to its projections. All inliers
of the line are then removed (also those in runs too short to keep, so the same line is not found
again). Extraction stops when the best line has fewer than ``min_inliers`` inliers.

With ``tile`` set, the points are cut into square tiles and the extraction runs per tile; pieces
are joined across tile borders by the same SegmentMerger as the per-scan baseline. On maps with
hundreds of walls a global RANSAC rarely draws two points of the same wall (about one in the
number of walls), so tiling is what a user would do to make it work at all.
"""

import time

import numpy as np

from .lines import fit_line, split_at_gaps
from .scan_split import _stats, SegmentMerger


def _extract(points, threshold, min_inliers, gap, min_points, max_trials, rng, deadline):
    """Sequential RANSAC on one point set; return a list of (segment, stats)."""
    from skimage.measure import LineModelND, ransac
    out = []
    rest = np.arange(len(points))
    while rest.size >= max(min_inliers, 2):
        if deadline is not None and time.perf_counter() > deadline:
            return out, True
        model, inl = ransac(points[rest], LineModelND, min_samples=2,
                            residual_threshold=threshold, max_trials=max_trials,
                            stop_probability=0.99, rng=rng)
        if model is None or inl is None or inl.sum() < min_inliers:
            break
        idx = rest[inl]
        p = points[idx]
        origin = np.asarray(model.origin, dtype=np.float64)
        u = np.asarray(model.direction, dtype=np.float64)
        for run in split_at_gaps((p - origin) @ u, gap, min_points):
            q = p[run]
            c, v = fit_line(q)
            t = (q - c) @ v
            out.append((np.array([c + t.min() * v, c + t.max() * v]), _stats(q)))
        rest = rest[~inl]
    return out, False


def sequential_ransac(points, threshold: float = 0.05, min_inliers: int = 20, gap: float = 0.3,
                      min_points: int = 10, max_trials: int = 500, tile: float = None,
                      rng=0, deadline: float = None) -> tuple:
    """
    Segments by sequential RANSAC.

    Parameters
    ----------
    points
        (N, 2) metres.
    threshold
        Inlier residual (m).
    min_inliers
        Stop when the best line has fewer inliers.
    gap
        Largest gap (m) inside one segment.
    min_points
        Shortest kept run, in points.
    max_trials
        RANSAC iterations per line (fewer when 99 % confidence is reached earlier).
    tile
        Tile side (m), or None for one global extraction.
    rng
        Seed or numpy Generator.
    deadline
        A time.perf_counter() value after which extraction stops.

    Returns
    -------
    segments : (K, 2, 2) metres.
    timed_out : bool

    """
    pts = np.asarray(points, dtype=np.float64)
    rng = np.random.default_rng(rng)
    if tile is None:
        found, late = _extract(pts, threshold, min_inliers, gap, min_points, max_trials, rng,
                               deadline)
        segs = np.array([s for s, _ in found]) if found else np.zeros((0, 2, 2))
        return segs, late
    keys = np.floor((pts - pts.min(axis=0)) / tile).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.ravel()
    merger = SegmentMerger(max_angle=5.0, max_offset=threshold, max_gap=gap)
    late = False
    for t in range(inv.max() + 1 if inv.size else 0):
        found, late = _extract(pts[inv == t], threshold, min_inliers, gap, min_points,
                               max_trials, rng, deadline)
        for s, st in found:
            merger.add(s, st)
        if late:
            break
    return merger.segments(), late
