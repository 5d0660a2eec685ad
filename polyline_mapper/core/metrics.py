"""The metrics reported everywhere: distances of points to the map, coverage, compression."""

import numpy as np

from .geometry import as_points, as_segments, se2_compose, se2_inverse, wrap_angle
from .index import nearest_distance, PointIndex
from .register import scan_chords, transform


def map_metrics(points: np.ndarray, segments: np.ndarray, index: PointIndex = None,
                coverage_radius: float = 0.10) -> dict:
    """
    Quality of a segment map over a point set.

    Returns
    -------
    dict with ``points``, ``segments``, ``mean_distance`` and ``p95_distance`` (metres, of each
    point to its nearest segment), ``coverage_0_10m`` (share of points within ``coverage_radius``
    of the map, 0..1) and ``compression`` (points / (2 x segments)).

    """
    points = as_points(points) if np.size(points) else np.zeros((0, 2))   # (bad input: one line)
    segments = as_segments(segments)
    n, k = len(points), len(segments)
    out = {'points': int(n), 'segments': int(k)}
    if n == 0 or k == 0:
        out.update(mean_distance=float('nan'), p95_distance=float('nan'), coverage_0_10m=0.0,
                   compression=float('nan'))
        return out
    d, _ = nearest_distance(points, segments, index=index, radius=0.5)
    out.update(mean_distance=float(d.mean()), p95_distance=float(np.percentile(d, 95)),
               coverage_0_10m=float(np.mean(d <= coverage_radius)),
               compression=float(n / (2.0 * k)))
    return out


def twin_fraction(segments: np.ndarray, distance: float = 0.10,
                  max_angle: float = np.deg2rad(10.0), min_overlap: float = 0.2) -> float:
    """
    Share of segments that have a near-parallel, overlapping twin closer than ``distance``.

    Two segments are twins when they differ in direction by less than ``max_angle``, their
    projections on the longer one overlap by at least ``min_overlap`` of the shorter one's
    length, and both ends of the shorter one lie within ``distance`` of the longer one's line.
    A doubled wall shows up as twins; pieces of one wall that meet end to end do not.
    """
    from .merge import candidate_pairs
    k = len(segments)
    if k < 2:
        return 0.0
    pairs = candidate_pairs(segments, distance)
    if len(pairs) == 0:
        return 0.0
    a, b = segments[pairs[:, 0]], segments[pairs[:, 1]]
    la = np.linalg.norm(a[:, 1] - a[:, 0], axis=1)
    lb = np.linalg.norm(b[:, 1] - b[:, 0], axis=1)
    swap = lb > la
    long_ = np.where(swap[:, None, None], b, a)
    short = np.where(swap[:, None, None], a, b)
    ll, ls = np.maximum(la, lb), np.minimum(la, lb)
    u = (long_[:, 1] - long_[:, 0]) / np.maximum(ll, 1e-12)[:, None]
    v = (short[:, 1] - short[:, 0]) / np.maximum(ls, 1e-12)[:, None]
    angle = np.arccos(np.clip(np.abs(np.einsum('ij,ij->i', u, v)), 0.0, 1.0))
    rel = short - long_[:, :1]
    t = np.einsum('mkj,mj->mk', rel, u)
    off = np.abs(rel[:, :, 0] * u[:, None, 1] - rel[:, :, 1] * u[:, None, 0]).max(axis=1)
    overlap = np.minimum(t.max(axis=1), ll) - np.maximum(t.min(axis=1), 0.0)
    twin = (angle < max_angle) & (off < distance) & (overlap >= min_overlap * ls)
    has = np.zeros(k, dtype=bool)
    has[pairs[twin].ravel()] = True
    return float(has.mean())


def rigid_alignment(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """
    Return the rigid 2D motion (x, y, yaw) that best lays ``estimate`` onto ``reference``.

    Least squares over corresponding (N, 2) positions, rotation and translation only (Horn's
    closed form, as the absolute trajectory error of the TUM RGB-D benchmark aligns).

    >>> ref = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    >>> np.round(rigid_alignment(ref[:, ::-1] * [1, -1], ref), 4) + 0.0
    array([0.    , 0.    , 1.5708])
    """
    est = np.asarray(estimate, dtype=np.float64).reshape(-1, 2)
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 2)
    if len(est) != len(ref) or len(est) == 0:
        raise ValueError(f'need equal, non-empty position lists, got {len(est)} and {len(ref)}')
    me, mr = est.mean(axis=0), ref.mean(axis=0)
    h = (est - me).T @ (ref - mr)
    yaw = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    t = mr - np.array([[c, -s], [s, c]]) @ me
    return np.array([t[0], t[1], yaw])


def trajectory_error(estimate: np.ndarray, reference: np.ndarray) -> dict:
    """
    Position errors of an estimated trajectory against a reference (rows correspond).

    Returns
    -------
    dict with ``rms`` (metres, as the positions stand: both trajectories share their first
    pose), ``ate`` (metres, RMS after the rigid alignment ``rigid_alignment``: the absolute
    trajectory error, blind to a constant offset of the whole frame), ``final`` (metres, last
    pose, as they stand) and ``alignment`` (x, y, yaw of that alignment).

    """
    est = np.asarray(estimate, dtype=np.float64)[:, :2]
    ref = np.asarray(reference, dtype=np.float64)[:, :2]
    al = rigid_alignment(est, ref)
    c, s = np.cos(al[2]), np.sin(al[2])
    moved = est @ np.array([[c, s], [-s, c]]) + al[:2]
    err = np.hypot(*(est - ref).T)
    return {'rms': float(np.sqrt(np.mean(err ** 2))),
            'ate': float(np.sqrt(np.mean(np.sum((moved - ref) ** 2, axis=1)))),
            'final': float(err[-1]), 'alignment': al}


def relative_error(estimate: np.ndarray, reference: np.ndarray, delta: int = 1) -> dict:
    """
    Relative pose error: how far each motion over ``delta`` poses differs from the reference's.

    For each i, the error of the motion from pose i to pose i + ``delta`` (rows correspond;
    (N, 3) x, y, yaw): (ref_i^-1 ref_i+d)^-1 (est_i^-1 est_i+d). It measures a trajectory's
    local accuracy (the drift per step), blind to what went before, so a small error early on
    does not dominate it as it does the absolute error (Kuemmerle et al., "On measuring the
    accuracy of SLAM algorithms", 2009; the RPE of the TUM RGB-D benchmark).

    >>> ref = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    >>> est = ref + [[5.0, 5.0, 0.0], [5.0, 5.0, 0.0], [5.1, 5.0, 0.0]]
    >>> round(relative_error(est, ref)['translation'], 4)
    0.0707

    Returns
    -------
    dict with ``translation`` (metres, RMS), ``rotation`` (radians, RMS), ``translation_p50``,
    ``rotation_p50`` (medians) and ``pairs`` (motions compared).

    """
    est = np.asarray(estimate, dtype=np.float64).reshape(-1, 3)
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if len(est) != len(ref):
        raise ValueError(f'need corresponding poses, got {len(est)} and {len(ref)}')
    if not 0 < int(delta) < len(est):
        return {'translation': float('nan'), 'rotation': float('nan'),
                'translation_p50': float('nan'), 'rotation_p50': float('nan'), 'pairs': 0}
    d = int(delta)
    err = se2_compose(se2_inverse(se2_compose(se2_inverse(ref[:-d]), ref[d:])),
                      se2_compose(se2_inverse(est[:-d]), est[d:]))
    t = np.hypot(err[:, 0], err[:, 1])
    r = np.abs(wrap_angle(err[:, 2]))
    return {'translation': float(np.sqrt(np.mean(t ** 2))),
            'rotation': float(np.sqrt(np.mean(r ** 2))),
            'translation_p50': float(np.median(t)), 'rotation_p50': float(np.median(r)),
            'pairs': int(len(t))}


def scan_consistency(scans: list, poses: np.ndarray, gate: float = 0.10) -> dict:
    """
    How well consecutive scans agree where ``poses`` put them: a reference-free pose check.

    Each scan's points (``scans[k]``: (N_k, 2) in its laser frame, metres) are placed by the
    relative pose ``poses[k-1]``^-1 ∘ ``poses[k]`` (laser poses, (K, 3)) onto the previous
    scan's chords (``register.scan_chords``: its own polyline). Two trajectories of the same
    scans compare without ground truth: the one whose steps are right puts each scan closer to
    the one before.

    Returns
    -------
    dict with ``mean`` (metres: mean distance of the points within ``gate`` of the previous
    scan's chords), ``share`` (of all points, those within ``gate``) and ``pairs`` (scan pairs
    used: both scans with points, the previous with chords).

    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    if len(scans) != len(poses):
        raise ValueError(f'{len(scans)} scans for {len(poses)} poses')
    rel = se2_compose(se2_inverse(poses[:-1]), poses[1:])
    total, near, dist, pairs = 0, 0, 0.0, 0
    for k in range(1, len(scans)):
        chords = scan_chords(scans[k - 1])
        if not len(chords) or not len(scans[k]):
            continue
        d, _ = nearest_distance(transform(scans[k], rel[k - 1]), chords)
        inside = d < gate
        total, near, dist = total + len(d), near + int(inside.sum()), dist + float(d[inside].sum())
        pairs += 1
    return {'mean': dist / near if near else float('nan'),
            'share': near / total if total else float('nan'), 'pairs': pairs}
