"""
Scan-to-map registration: a scan's pose refined against the polyline map (ROS-free).

The E-step of SMEMSF pairs each point with the map's segments by distance; the same pairs,
weighted, give a least-squares rigid correction of the scan's pose (point-to-line ICP is that
M-step for the pose). ``match_scan`` runs a few Gauss-Newton steps on the signed distances of
the scan's points to the lines of their nearest segments:

- association: each point (at the current pose) with its nearest map segment within a *gate*
  that shrinks from ``gate`` to ``gate_min`` over the iterations (a wrong prediction of a few
  decimetres is pulled in first, then outliers are cut);
- a robust (Cauchy) kernel down-weights what the map does not explain (people, clutter, new
  walls); its scale is ``kernel`` or a third of the current gate, whichever is larger, so a
  prediction decimetres off is still pulled in by the first, wide iterations;
- a degeneracy guard: the information matrix J^T W J (rotation scaled by the scan's median
  range, so a radian and a metre weigh alike) is split into eigen-directions; directions whose
  eigenvalue is below ``degenerate`` x the largest (a featureless corridor along its axis) keep
  the prediction, and only the others are corrected;
- a covariance of the result: sigma^2 (J^T W J)^-1 over the constrained directions, and
  ``prior_std`` (the prediction's uncertainty) along the degenerate ones.

A match with too few inliers or too large a correction is refused (``ok`` False, with the
reason): the caller keeps the prediction, and the map is not corrupted by a scan placed wrong.
"""

from typing import NamedTuple, Optional

import numpy as np

from .geometry import as_points, se2_compose, se2_inverse
from .index import PointIndex


class ScanMatch(NamedTuple):
    """The result of ``match_scan``."""

    pose: np.ndarray
    """(3,) x, y, yaw: the refined pose (the prediction when not ``ok``)."""
    covariance: np.ndarray
    """(3, 3) over (x, y, yaw), m^2 and rad^2."""
    ok: bool
    reason: str
    """'' when ok, else why the prediction was kept ('no map', 'too few inliers', ...)."""
    inliers: int
    """Points paired with a segment within the final gate."""
    residual: float
    """Robust RMS of the inliers' distances to their lines at the final pose, metres."""
    degenerate: int
    """Number of directions of (x, y, yaw) kept at the prediction."""


def transform(points: np.ndarray, pose) -> np.ndarray:
    """Return laser-frame points (N, 2) placed at ``pose`` (x, y, yaw)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.stack([pose[0] + c * points[:, 0] - s * points[:, 1],
                     pose[1] + s * points[:, 0] + c * points[:, 1]], axis=1)


def _pairs(points: np.ndarray, segments: np.ndarray, gate: float) -> tuple:
    """Return (point ids, segment ids) of each point's nearest segment within ``gate``."""
    p = PointIndex(points, sample_spacing=8.0).pairs(segments, gate)
    if len(p.pt) == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    order = np.lexsort((p.dist, p.pt))                # per point, nearest first
    pt, seg = p.pt[order], p.seg[order]
    first = np.ones(len(pt), dtype=bool)
    first[1:] = pt[1:] != pt[:-1]
    return pt[first], seg[first]


def match_scan(points, prediction, segments, sigma: float, iterations: int = 8,
               gate: float = 0.5, gate_min: float = None, kernel: float = None,
               min_inliers: int = 20, min_share: float = 0.25, max_shift: float = 0.5,
               max_turn: float = 0.35, degenerate: float = 0.02,
               prior_std: tuple = (0.1, 0.1, 0.05)) -> ScanMatch:
    """
    Refine a scan's pose against map segments.

    Parameters
    ----------
    points : (N, 2) float array
        The scan's points in the laser frame, metres.
    prediction : (3,) float
        Predicted laser pose (x, y, yaw) in the map frame (odometry, TF or constant velocity).
    segments : (K, 2, 2) float array
        Map segments near the scan, metres.
    sigma : float
        The map's noise scale, metres (sets the final gate and the kernel by default).
    iterations : int
        Gauss-Newton steps (each re-associates).
    gate, gate_min : float
        First and last association gate, metres (``gate_min`` default 4 sigma).
    kernel : float
        Cauchy kernel scale, metres (default 2 sigma).
    min_inliers, min_share : int, float
        Fewer paired points than both ``min_inliers`` and ``min_share`` x N: refused.
    max_shift, max_turn : float
        A correction beyond these (m, rad) is refused.
    degenerate : float
        Eigenvalue share (of the largest) below which a direction keeps the prediction.
    prior_std : (3,) float
        Std (m, m, rad) reported along degenerate directions.

    Returns
    -------
    ScanMatch

    """
    pts = as_points(points)
    pred = np.asarray(prediction, dtype=np.float64).reshape(3)
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    prior = np.diag(np.square(np.asarray(prior_std, dtype=np.float64)))
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f'sigma must be a finite number > 0, got {sigma!r}')
    if len(segs) == 0 or len(pts) == 0:
        return ScanMatch(pred, prior, False, 'no map', 0, np.nan, 3)
    gate_min = 4.0 * sigma if gate_min is None else float(gate_min)
    kernel = 2.0 * sigma if kernel is None else float(kernel)
    gate = max(float(gate), gate_min)
    u = segs[:, 1] - segs[:, 0]
    length = np.hypot(u[:, 0], u[:, 1])
    keep = length > 1e-9
    segs, u, length = segs[keep], u[keep], length[keep]
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1) / length[:, None]
    scale = max(float(np.median(np.hypot(pts[:, 0], pts[:, 1]))), 1.0)   # metres per radian
    need = min(min_inliers, max(3, int(np.ceil(min_share * len(pts)))))
    pose = pred.copy()
    info = np.zeros((3, 3))
    good = np.zeros(3, dtype=bool)
    vecs = np.eye(3)
    res = np.zeros(0)
    w = np.zeros(0)
    for it in range(int(iterations)):
        g = max(gate * 0.6 ** it, gate_min)
        world = transform(pts, pose)
        pt, sg = _pairs(world, segs, g)
        if len(pt) < need:
            return ScanMatch(pred, prior, False, 'too few inliers', int(len(pt)), np.nan, 3)
        n = normal[sg]
        res = np.einsum('ij,ij->i', n, world[pt] - segs[sg, 0])
        c, s = np.cos(pose[2]), np.sin(pose[2])
        lp = pts[pt]
        dworld = np.stack([-s * lp[:, 0] - c * lp[:, 1], c * lp[:, 0] - s * lp[:, 1]], axis=1)
        jac = np.column_stack([n, np.einsum('ij,ij->i', n, dworld) / scale])
        k = max(kernel, g / 3.0)          # the kernel widens with the gate: a far start pulls
        w = 1.0 / (1.0 + (res / k) ** 2)
        info = jac.T @ (w[:, None] * jac)
        grad = -jac.T @ (w * res)
        vals, vecs = np.linalg.eigh(info)
        good = vals > degenerate * max(vals[-1], 1e-12)
        step = np.zeros(3)
        for k in np.flatnonzero(good):
            step += (vecs[:, k] @ grad) / vals[k] * vecs[:, k]
        step[2] /= scale
        pose = pose + step
        if np.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-6 and g <= gate_min:
            break
    shift = np.hypot(*(pose[:2] - pred[:2]))
    turn = abs((pose[2] - pred[2] + np.pi) % (2 * np.pi) - np.pi)
    rms = float(np.sqrt(np.sum(w * res ** 2) / max(np.sum(w), 1e-12)))
    if shift > max_shift or turn > max_turn:
        return ScanMatch(pred, prior, False, 'correction too large', int(len(res)), rms,
                         int((~good).sum()))
    # Covariance in the scaled coordinates (yaw x scale): sigma^2 / eigenvalue along the
    # constrained directions, the prior's variance along the others; then metres and radians.
    vals = np.linalg.eigvalsh(info)
    prior_scaled = prior * np.array([1.0, 1.0, scale])[:, None] * np.array([1.0, 1.0, scale])
    var = np.where(good, sigma ** 2 / np.maximum(vals, 1e-12),
                   np.einsum('ik,ij,jk->k', vecs, prior_scaled, vecs))
    unscale = np.diag([1.0, 1.0, 1.0 / scale])
    cov = unscale @ ((vecs * var) @ vecs.T) @ unscale
    return ScanMatch(pose, cov, True, '', int(len(res)), rms, int((~good).sum()))


def predict_constant_velocity(previous: Optional[np.ndarray], last: Optional[np.ndarray]):
    """Return last * (previous^-1 * last): the next pose at constant velocity (or ``last``)."""
    if last is None:
        return np.zeros(3)
    if previous is None:
        return np.asarray(last, dtype=np.float64).copy()
    return se2_compose(last, se2_compose(se2_inverse(previous), last))
