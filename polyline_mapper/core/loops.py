"""
Loop closure for a scan-matched trajectory: loops between keyframes, a robust pose graph.

Scan matching against the map built so far (``register.match_scan``) keeps a trajectory
consistent where the robot sees what it mapped a moment ago, but over a large loop the small
errors add up: on the drifted Intel log the robot comes back to its corridors 0.1-0.7 m off and
the map bends and doubles its walls. Offline, once the whole trajectory is known:

1. ``find_loops``: every keyframe (a matched scan, ``replay.LOOP_KEYFRAME`` from the last) is
   matched against the keyframe the trajectory passed nearest, within ``radius`` metres, after
   at least ``min_travel`` metres of travel: its chords and its neighbours'
   (``register.scan_chords``), placed in the older keyframe's frame by the trajectory. A loop
   is taken only when the match holds (``match_scan`` with its relocalization search within
   ``radius``), puts ``min_share`` of the scan on those chords and constrains every direction.
2. ``settle``: a loop that agrees with the trajectory within ``BAND`` (0.1 m, 0.1 rad) says
   nothing the matcher had not seen: its relative pose is replaced by the trajectory's own, so
   it holds that part of the trajectory as it is. Where the robot came back within the match
   gate the matcher has already pulled the pose onto the old map, and a loop's match is no
   more accurate than the trajectory there (drifted CSAIL, seed 0: the 21 loops' relative
   poses are 3.2 cm median, at most 13 cm, from the corrected poses' ones, the trajectory's
   3.1 cm, at most 14 cm); closed on that noise, a 1 deg yaw on a 25 m loop turned the 37 m
   after it by 0.5 m (ATE 0.235 -> 0.251 m). Only loops beyond the band move the trajectory.
3. ``optimize``: the keyframe poses are refined by least squares over the steps between
   consecutive keyframes (the matched motion, with the odometry's noise for that motion:
   ``register.odometry_covariance``) and the loops (the match's covariance, floored), with a
   robust (Cauchy) loss; loops whose whitened error stays beyond ``outlier`` are dropped and
   the graph is solved again.
4. ``corrections``: the change of every keyframe pose, interpolated at any stamps, to move every
   scan (and the odometry) by it.
"""

from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import spsolve

from .geometry import se2_compose, se2_inverse, wrap_angle
from .register import match_scan, odometry_covariance, scan_chords, transform


class Edge(NamedTuple):
    """A constraint between keyframes ``a`` and ``b``: the pose of ``b`` in ``a``'s frame."""

    a: int
    b: int
    z: np.ndarray
    """(3,) x, y, yaw of ``b`` seen from ``a`` (m, rad)."""
    cov: np.ndarray
    """(3, 3) covariance of ``z`` (m^2, rad^2)."""


def relative(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Return poses ``pb`` seen from ``pa`` ((..., 3) each), the yaw wrapped."""
    r = se2_compose(se2_inverse(pa), pb)
    r[..., 2] = wrap_angle(r[..., 2])
    return r


def chain(poses: np.ndarray, floor=(0.01, 0.01, 0.005)) -> list:
    """
    Return the edges between consecutive ``poses`` (K, 3): their relative poses as they are.

    Covariance: the odometry's over that motion (``odometry_covariance``), at least ``floor``
    (m, m, rad, standard deviations): what scan matching may have missed per step.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    rel = relative(poses[:-1], poses[1:])
    base = np.diag(np.square(floor))
    return [Edge(k, k + 1, rel[k], np.maximum(odometry_covariance(rel[k]), base))
            for k in range(len(rel))]


def find_loops(poses: np.ndarray, points: list, sigma: float, radius: float = 1.0,
               min_travel: float = 10.0, min_share: float = 0.7, min_inliers: int = 60,
               window: int = 2, floor=(0.02, 0.02, 0.01)) -> list:
    """
    Return loop edges between keyframes (see the module docstring).

    Parameters
    ----------
    poses : (K, 3) float array
        The keyframes' laser poses (x, y, yaw) in the map frame, in recording order.
    points : list of (N_k, 2) float arrays
        Each keyframe's points in its laser frame, metres.
    sigma : float
        The map's noise scale, metres (``match_scan``'s).
    radius : float
        Keyframes nearer than this (m) are candidates; the search reaches as far.
    min_travel : float
        Metres of trajectory between the two keyframes of a loop, at least.
    min_share, min_inliers : float, int
        Share of the scan's points on the candidate's chords, and paired points, at least.
    window : int
        The candidate's chords with those of ``window`` keyframes either side.
    floor : (3,) float
        Least standard deviations (m, m, rad) of a loop's relative pose.

    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])
    chords = [scan_chords(p) for p in points]
    edges = []
    base = np.diag(np.square(floor))
    for i in range(len(poses)):
        far = np.flatnonzero(travel[i] - travel >= min_travel)
        if not len(far):
            continue
        d = np.hypot(*(poses[far, :2] - poses[i, :2]).T)
        if d.min() >= radius:
            continue
        j = int(far[np.argmin(d)])
        around = [k for k in range(max(0, j - window), min(len(poses), j + window + 1))
                  if travel[i] - travel[k] >= 0.5 * min_travel]     # never the scan itself
        near = [transform(chords[k].reshape(-1, 2), relative(poses[j], poses[k])).reshape(-1, 2, 2)
                for k in around if len(chords[k])]
        if not near:
            continue
        m = match_scan(points[i], relative(poses[j], poses[i]), np.concatenate(near), sigma,
                       max_shift=radius, relocalize=radius, relocalize_share=min_share)
        if m.ok and m.share >= min_share and m.inliers >= min_inliers and not m.degenerate:
            edges.append(Edge(j, i, m.pose, np.maximum(m.covariance, base)))
    return edges


BAND = (0.1, 0.1)
"""``settle``: a loop whose relative pose is within this (m, rad) of the trajectory's holds it."""


def settle(poses: np.ndarray, loops: list, band=BAND) -> tuple:
    """
    Return (loops, active): each loop within ``band`` of ``poses`` with the trajectory's pose.

    ``poses``: (K, 3) keyframe poses; ``loops``: Edge list (``find_loops``). A loop whose
    relative pose differs from the trajectory's (``relative(poses[a], poses[b])``) by less than
    ``band`` (m, rad) in translation and in yaw gets the trajectory's relative pose (an anchor:
    it keeps that part as it is); the others are kept as found. ``active``: (L,) bool, True for
    those.
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    out, active = [], np.zeros(len(loops), dtype=bool)
    for k, e in enumerate(loops):
        now = relative(poses[e.a], poses[e.b])
        d = relative(now, e.z)
        active[k] = np.hypot(d[0], d[1]) >= band[0] or abs(d[2]) >= band[1]
        out.append(e if active[k] else e._replace(z=now))
    return out, active


def _linearize(p: np.ndarray, a: np.ndarray, b: np.ndarray, z: np.ndarray) -> tuple:
    """
    Return each edge's error (E, 3) and its Jacobians (E, 3, 3) by ``p[a]`` and ``p[b]``.

    Error: the pose ``z``^-1 ∘ (``p[a]``^-1 ∘ ``p[b]``) (x, y, wrapped yaw): zero when the two
    poses are as the edge says.
    """
    pa, pb = p[a], p[b]
    ca, sa = np.cos(pa[:, 2]), np.sin(pa[:, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    e = relative(z, relative(pa, pb))
    d = pb[:, :2] - pa[:, :2]
    # R(z)^T R(a)^T = R(a + z)^T, and R(z)^T times the derivative of R(a)^T d by a's yaw
    c, s = np.cos(pa[:, 2] + z[:, 2]), np.sin(pa[:, 2] + z[:, 2])
    m = np.stack([np.stack([c, s], axis=1), np.stack([-s, c], axis=1)], axis=1)
    r_at_d = np.stack([-sa * d[:, 0] + ca * d[:, 1], -ca * d[:, 0] - sa * d[:, 1]], axis=1)
    dyaw = np.stack([cz * r_at_d[:, 0] + sz * r_at_d[:, 1],
                     -sz * r_at_d[:, 0] + cz * r_at_d[:, 1]], axis=1)
    ja = np.zeros((len(a), 3, 3))
    jb = np.zeros((len(a), 3, 3))
    ja[:, :2, :2], ja[:, :2, 2], ja[:, 2, 2] = -m, dyaw, -1.0
    jb[:, :2, :2], jb[:, 2, 2] = m, 1.0
    return e, ja, jb


def optimize(poses: np.ndarray, edges: list, outlier: float = 5.0, scale: float = 2.0,
             iterations: int = 30) -> tuple:
    """
    Refine ``poses`` (K, 3) over ``edges``; the first pose stays fixed.

    Each edge's error (``_linearize``) is whitened by its covariance; Gauss-Newton steps with
    Cauchy weights (``scale``, in standard deviations) on the whitened errors, one sparse solve
    each. Loop edges (``b != a + 1``) whose whitened error exceeds ``outlier`` after the solve
    are dropped and the graph is solved again (until none is).

    Returns (poses (K, 3), kept loop edges: list of Edge).
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    edges = list(edges)
    n = len(poses)
    if n < 2 or not edges:
        return poses.copy(), [e for e in edges if e.b != e.a + 1]
    while True:
        a = np.array([e.a for e in edges])
        b = np.array([e.b for e in edges])
        z = np.array([e.z for e in edges])
        w = np.linalg.cholesky(np.linalg.inv(np.array([e.cov for e in edges]))).transpose(0, 2, 1)
        p = poses.copy()
        rows = np.repeat(np.arange(3 * len(edges)).reshape(-1, 3, 1), 3, axis=2)
        for _ in range(int(iterations)):
            e, ja, jb = _linearize(p, a, b, z)
            r = np.einsum('kij,kj->ki', w, e)
            weight = 1.0 / (1.0 + np.sum(r * r, axis=1) / scale ** 2)      # Cauchy (IRLS)
            sw = np.sqrt(weight)[:, None, None]
            wa, wb = sw * (w @ ja), sw * (w @ jb)
            cols_a = 3 * a[:, None, None] + np.arange(3)[None, None, :] + 0 * rows[:len(a)]
            cols_b = 3 * b[:, None, None] + np.arange(3)[None, None, :] + 0 * rows[:len(a)]
            jac = coo_matrix((np.concatenate([wa.ravel(), wb.ravel()]),
                              (np.concatenate([rows.ravel(), rows.ravel()]),
                               np.concatenate([cols_a.ravel(), cols_b.ravel()]))),
                             shape=(3 * len(edges), 3 * n)).tocsc()[:, 3:]
            rhs = -(jac.T @ (np.sqrt(weight)[:, None] * r).ravel())
            step = spsolve((jac.T @ jac).tocsc(), rhs)
            p[1:] += step.reshape(-1, 3)
            if np.abs(step).max() < 1e-6:
                break
        e, _, _ = _linearize(p, a, b, z)
        err = np.linalg.norm(np.einsum('kij,kj->ki', w, e), axis=1)
        bad = (b != a + 1) & (err > outlier)
        if not bad.any():
            return p, [e for e, loop in zip(edges, b != a + 1) if loop]
        edges = [e for e, drop in zip(edges, bad) if not drop]


def corrections(before: np.ndarray, after: np.ndarray, stamps: np.ndarray,
                at: np.ndarray) -> np.ndarray:
    """
    Return the correction (map <- map, (M, 3)) at stamps ``at``: ``after`` ∘ ``before``^-1.

    ``before``, ``after``: (K, 3) keyframe poses at ``stamps`` (K,), increasing; between them
    the correction is interpolated linearly (x, y and unwrapped yaw), beyond them held.
    """
    c = se2_compose(np.asarray(after, dtype=np.float64), se2_inverse(before))
    c[:, 2] = np.unwrap(wrap_angle(c[:, 2]))
    at = np.asarray(at, dtype=np.float64)
    return np.column_stack([np.interp(at, stamps, c[:, k]) for k in range(3)])
