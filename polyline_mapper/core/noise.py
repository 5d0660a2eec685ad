"""Estimate the range noise of a point set from the thickness of its local structure."""

import numpy as np
from scipy.spatial import cKDTree


def estimate_noise(points: np.ndarray, radius: float = 0.2, sample: int = 4000,
                   min_neighbours: int = 8, target_neighbours: int = 60, rng=None) -> float:
    """
    Robust noise scale of 2D laser points, in metres.

    For a random subset of points, the neighbours within ``radius`` are fitted by PCA; the
    square root of the smallest eigenvalue is the local thickness (the normal spread about a
    wall). The median over the subset ignores corners and clutter, which are thicker, as long as
    most neighbourhoods lie on walls. Straight structure over ``radius`` is assumed: a noise above
    about radius / 4 is underestimated. Dense clouds are thinned at random (the same noise, fewer
    points) so that a neighbourhood holds about ``target_neighbours`` points; the cost is then
    about ``sample * target_neighbours`` whatever the density.

    Returns
    -------
    float, or nan when fewer than 10 neighbourhoods have ``min_neighbours`` points.

    """
    rng = np.random.default_rng(rng)
    n = len(points)
    if n < min_neighbours:
        return float('nan')
    pick = rng.choice(n, size=min(sample, n), replace=False)
    tree = cKDTree(points)
    probe = tree.query_ball_point(points[pick[:200]], radius, return_length=True)
    keep = min(1.0, target_neighbours / max(float(np.median(probe)), 1.0))
    if keep < 1.0:
        pool = points[rng.random(n) < keep]
        tree = cKDTree(pool)
    else:
        pool = points
    hits = cKDTree(points[pick]).sparse_distance_matrix(tree, radius, output_type='ndarray')
    grp = hits['i']
    m = len(pick)
    cnt = np.bincount(grp, minlength=m).astype(float)
    p = pool[hits['j']]
    safe = np.maximum(cnt, 1.0)
    mx = np.bincount(grp, p[:, 0], minlength=m) / safe
    my = np.bincount(grp, p[:, 1], minlength=m) / safe
    dx = p[:, 0] - mx[grp]
    dy = p[:, 1] - my[grp]
    sxx = np.bincount(grp, dx * dx, minlength=m) / safe
    syy = np.bincount(grp, dy * dy, minlength=m) / safe
    sxy = np.bincount(grp, dx * dy, minlength=m) / safe
    lam_min = 0.5 * (sxx + syy) - np.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
    ok = cnt >= min_neighbours
    if ok.sum() < 10:
        return float('nan')
    # Unbiased variance: n points, 2 parameters of the line.
    var = np.maximum(lam_min[ok], 0.0) * cnt[ok] / np.maximum(cnt[ok] - 2.0, 1.0)
    return float(np.sqrt(np.median(var)))
