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

from .geometry import group_minmax, Pairs, PointIndex


@dataclass
class EStep:
    """Responsibilities of the candidate pairs and each point's MAP segment."""

    pairs: Pairs
    weight: np.ndarray       # (P,) responsibility w_ij of each pair, in [0, 1]
    support: np.ndarray      # (N,) MAP segment of each point, -1 for outliers / no candidate


def e_step(index: PointIndex, segments: np.ndarray, sigma: float, kappa: float) -> EStep:
    """
    Compute responsibilities of the segments for the points.

    Parameters
    ----------
    index : PointIndex
        The points (and their multiplicities).
    segments : (K, 2, 2) metres.
    sigma : float
        Kernel width in metres.
    kappa : float
        Cut-off in units of sigma; the outlier class has the kernel's density at the cut-off.

    """
    n = len(index)
    pairs = index.pairs(segments, kappa * sigma)
    if len(pairs.pt) == 0:
        return EStep(pairs, np.zeros(0), np.full(n, -1, dtype=np.intp))
    g = np.exp(-0.5 * (pairs.dist / sigma) ** 2)
    norm = np.bincount(pairs.pt, weights=g, minlength=n) + np.exp(-0.5 * kappa ** 2)
    w = g / norm[pairs.pt]
    # MAP support: the pair with the largest weight of its point, if it beats the outlier class.
    order = np.lexsort((-w, pairs.pt))
    first = np.ones(order.size, dtype=bool)
    first[1:] = pairs.pt[order][1:] != pairs.pt[order][:-1]
    best = order[first]
    outlier_w = np.exp(-0.5 * kappa ** 2) / norm[pairs.pt[best]]
    support = np.full(n, -1, dtype=np.intp)
    win = w[best] >= outlier_w
    support[pairs.pt[best[win]]] = pairs.seg[best[win]]
    return EStep(pairs, w, support)


def weighted_lines(points: np.ndarray, seg: np.ndarray, w: np.ndarray, k: int) -> tuple:
    """
    Weighted orthogonal regression lines for ``k`` groups (the M-step).

    Parameters
    ----------
    points : (P, 2) the point of each weighted pair.
    seg : (P,) group of each pair, in [0, k).
    w : (P,) non-negative weights.
    k : number of groups.

    Returns
    -------
    centre : (k, 2) weighted mean, metres.
    direction : (k, 2) unit vector along the line (eigenvector of the largest eigenvalue of the
        weighted scatter, i.e. orthogonal to the smallest one).
    mass : (k,) total weight.

    """
    mass = np.bincount(seg, weights=w, minlength=k)
    safe = np.where(mass > 0, mass, 1.0)
    cx = np.bincount(seg, weights=w * points[:, 0], minlength=k) / safe
    cy = np.bincount(seg, weights=w * points[:, 1], minlength=k) / safe
    dx = points[:, 0] - cx[seg]
    dy = points[:, 1] - cy[seg]
    sxx = np.bincount(seg, weights=w * dx * dx, minlength=k)
    syy = np.bincount(seg, weights=w * dy * dy, minlength=k)
    sxy = np.bincount(seg, weights=w * dx * dy, minlength=k)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    direction = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    return np.stack([cx, cy], axis=1), direction, mass


def emsf_step(index: PointIndex, segments: np.ndarray, sigma: float, kappa: float,
              min_support: float, min_density: float = 0.0, r: float = 1.0) -> tuple:
    """
    One EM iteration followed by MAP trimming.

    A trimmed segment survives when its supporting point weight is at least ``min_support`` and
    at least ``min_density`` per ``2 r`` of its length (sparse scattered points that merely line
    up over a long stretch do not make a wall).

    Returns
    -------
    segments : (K', 2, 2) the refitted, trimmed segments that survive; order follows the
        input.
    support_mass : (K',) supporting point weight of each returned segment.
    estep : the E-step (computed on the input segments).

    """
    k = len(segments)
    est = e_step(index, segments, sigma, kappa)
    if k == 0 or len(est.pairs.pt) == 0:
        return np.zeros((0, 2, 2)), np.zeros(0), est
    pw = est.weight * index.weights[est.pairs.pt]
    centre, direction, mass = weighted_lines(index.points[est.pairs.pt], est.pairs.seg, pw, k)
    sup_pts = np.flatnonzero(est.support >= 0)
    sup_seg = est.support[sup_pts]
    sup_mass = np.bincount(sup_seg, weights=index.weights[sup_pts], minlength=k)
    t = np.einsum('ij,ij->i', index.points[sup_pts] - centre[sup_seg], direction[sup_seg])
    lo, hi = group_minmax(t, sup_seg, k)
    keep = ((sup_mass >= min_support) & (sup_mass >= min_density * (hi - lo) / (2.0 * r))
            & (mass > 0) & (hi > lo))
    c, u = centre[keep], direction[keep]
    new = np.stack([c + lo[keep, None] * u, c + hi[keep, None] * u], axis=1)
    return new, sup_mass[keep], est
