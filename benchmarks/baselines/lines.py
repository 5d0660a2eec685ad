"""Weighted orthogonal regression, segments from supporting points, gap splitting."""

import numpy as np


def fit_line(points: np.ndarray, weights: np.ndarray = None) -> tuple:
    """
    Total least-squares line through weighted points.

    Parameters
    ----------
    points
        (N, 2) float array, metres, N >= 2.
    weights
        (N,) non-negative weights, or None for equal weights.

    Returns
    -------
    centre : (2,) weighted mean, metres.
    direction : (2,) unit vector along the line (major axis of the weighted scatter).

    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError(f'points must have shape (N >= 2, 2), got {pts.shape}')
    w = np.ones(len(pts)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.sum() <= 0:
        raise ValueError('weights must not all be zero')
    c = (w[:, None] * pts).sum(axis=0) / w.sum()
    d = pts - c
    sxx, syy = (w * d[:, 0] ** 2).sum(), (w * d[:, 1] ** 2).sum()
    sxy = (w * d[:, 0] * d[:, 1]).sum()
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return c, np.array([np.cos(theta), np.sin(theta)])


def line_segments(points: np.ndarray, labels: np.ndarray, k: int, weights: np.ndarray = None,
                  support: np.ndarray = None, trim: np.ndarray = None) -> tuple:
    """
    One weighted-regression line per label, trimmed to the projections of its support.

    Parameters
    ----------
    points
        (N, 2) metres.
    labels
        (M,) label in 0..k-1 of each (point, label) pair; ``points`` is indexed by
        ``support`` when given (pairs), else labels has one entry per point.
    k
        Number of labels.
    weights
        (M,) weights of the pairs (the M-step); None for 1.
    support
        (M,) point index of each pair, or None when labels are per point.
    trim
        (M,) bool, the pairs whose projections set the ends (the MAP support); None: all.

    Returns
    -------
    segments : (k, 2, 2) metres (NaN for labels without support).
    count : (k,) supporting weight of each label.

    """
    pi = np.arange(len(labels)) if support is None else support
    p = points[pi]
    w = np.ones(len(labels)) if weights is None else weights
    sw = np.bincount(labels, w, k)
    ok = sw > 0
    safe = np.where(ok, sw, 1.0)
    mx = np.bincount(labels, w * p[:, 0], k) / safe
    my = np.bincount(labels, w * p[:, 1], k) / safe
    dx, dy = p[:, 0] - mx[labels], p[:, 1] - my[labels]
    sxx = np.bincount(labels, w * dx * dx, k)
    syy = np.bincount(labels, w * dy * dy, k)
    sxy = np.bincount(labels, w * dx * dy, k)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    u = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    t = dx * u[labels, 0] + dy * u[labels, 1]
    sel = slice(None) if trim is None else trim
    lo = np.full(k, np.inf)
    hi = np.full(k, -np.inf)
    np.minimum.at(lo, labels[sel], t[sel])
    np.maximum.at(hi, labels[sel], t[sel])
    ok &= np.isfinite(lo)
    c = np.stack([mx, my], axis=1)
    with np.errstate(invalid='ignore'):
        seg = np.stack([c + lo[:, None] * u, c + hi[:, None] * u], axis=1)
    seg[~ok] = np.nan
    return seg, sw


def split_at_gaps(along: np.ndarray, gap: float, min_points: int) -> list:
    """
    Split positions along a line into runs separated by gaps wider than ``gap``.

    Parameters
    ----------
    along
        (N,) positions on the line, metres (any order).
    gap
        Largest gap (m) inside one run.
    min_points
        Runs with fewer points are dropped.

    Returns
    -------
    List of index arrays into ``along``, one per run, each sorted by position.

    """
    a = np.asarray(along, dtype=np.float64)
    if a.size == 0:
        return []
    order = np.argsort(a, kind='stable')
    cut = np.flatnonzero(np.diff(a[order]) > gap) + 1
    return [run for run in np.split(order, cut) if run.size >= min_points]
