"""
Scan-to-map registration: a scan's pose refined against the polyline map (ROS-free).

The E-step of SMEMSF pairs each point with the map's segments by distance; the same pairs,
weighted, give a least-squares rigid correction of the scan's pose (point-to-line ICP is that
M-step for the pose). ``match_scan`` runs a few Gauss-Newton steps on the signed distances of
the scan's points to the lines of their nearest segments:

- a coarse heading search first: a few heading offsets around the prediction, scored by how
  many points land near the map; a clearly better one replaces the predicted heading (wheel
  odometry errs most in heading, and a tenth of a radian moves a point 5 m away by 0.5 m,
  beyond the first association gate);
- association: each point (at the current pose) with its nearest map segment within a *gate*
  (a k-d tree over points sampled along the segments, built once per scan); the gate shrinks
  from ``gate`` to ``gate_min`` each time the steps at the current gate converge (a wrong
  prediction of a few decimetres is pulled in first, then outliers are cut);
- a robust (Cauchy) kernel down-weights what the map does not explain (people, clutter, new
  walls); its scale is ``kernel`` or a third of the current gate, whichever is larger, so a
  prediction decimetres off is still pulled in by the first, wide iterations;
- a degeneracy guard: the information matrix J^T W J (rotation scaled by the scan's median
  range, so a radian and a metre weigh alike) is split into eigen-directions; directions whose
  eigenvalue is below ``degenerate`` x the largest (a featureless corridor along its axis) keep
  the prediction, and only the others are corrected;
- a covariance of the result: sigma^2 (J^T W J)^-1 over the constrained directions, plus what
  the last scans' chords add when they are named (``chords``: each runs between two noisy
  readings and sits at its scan's matched pose, ``chord_cov``), and ``prior_std`` (the
  prediction's uncertainty) along the degenerate ones;
- or, with ``prediction_prior`` (the covariance of a constant-velocity prediction), a Gaussian
  prior on the pose instead of the hard guard: each step minimises the weighted squared
  distances plus sigma^2 times the prior's Mahalanobis term, so a weakly constrained direction
  moves as far as the scan's information there outweighs the prior's, and no direction flips
  between held and corrected on a threshold.

A result that explains fewer of the scan's points (within the final gate) than the prediction
does is not taken: the prediction is returned as the match. With ``relocalize``, a result that
puts few of the scan's points on the map (``RELOCALIZE_SHARE``) starts a wider search: shifts on
a grid within ``relocalize`` metres times the heading turns, scored at once through the k-d
tree, then Gauss-Newton from the best; it is taken when it lies beyond the first gate and puts
clearly more points on the map (a wheel slip or a bump beyond the gate); new ground has no
such pose and keeps the first result. A match with too few inliers or too large a correction
is refused (``ok`` False, with the reason): the caller keeps the prediction, and the map is not
corrupted by a scan placed wrong.

``search_after_gap`` is the widest search: every shift and heading the robot can have moved
during a gap in the scans (scan-only mapping), scored through a distance field of the map.
"""

import functools
import math
from typing import NamedTuple, Optional

import numpy as np
from scipy.ndimage import distance_transform_edt, median_filter
from scipy.spatial import cKDTree

from .geometry import (as_points, as_segments, is_number, lengths, sample_segments,
                       se2_compose, se2_inverse, wrap_angle)
from .noise import median


TURN_MARGIN = 1.1
"""``_best_turn`` leaves the predicted heading only for a turn scoring this much higher."""


TURN_POINTS = 90
"""``_best_turn`` scores at most this many of the scan's points (evenly spread)."""


WEAK_SHARE = 0.2
"""
A direction of (x, y, yaw) whose information is below this share of the strongest direction's
is *weakly constrained*: the scan pins it down through a few of its points only (a corridor
along its axis, seen with a door frame or a person walking ahead).
"""


WEAK_SIGMAS = 5.0
"""
With ``prediction_cov``, a correction along a weakly constrained direction beyond this many of
the prediction's standard deviations is not taken: the prediction holds along it. In a 2 m
corridor a person walking ahead of the robot (a tenth of the scan's points) pulled every match
8-12 cm back, 8 sigma of the step's odometry error, and the robot followed the person
(simulated office, true odometry: 1.6 m RMS). Until 2026-11-29 a correction was also taken
while under the kernel scale (2 sigma, about 3 cm); with short steps (a 5 Hz lidar at 0.2 m/s:
5 sigma of the step's error is 1 cm) such slides along a corridor added up, with *true*
odometry 16 cm along one 8 m side (a TurtleBot3-class lidar, ``benchmarks/cheap_lidar.py``).
"""


TRANSIENT_SHARE = 0.5
"""
A weakly constrained direction (``WEAK_SHARE``) is held at the prediction, whatever the size of
the correction, when *transient* map pieces (``match_scan``'s ``transient``: the last scans'
chords along free-standing person-sized runs, ``session.RecentChords``) carry at least this
share of its information. Along a corridor the walls say nothing, and a person walking ahead of
the robot, matched to their own arcs of the last scans, pulled each match back by less than
``WEAK_SIGMAS``, which added up. The simulated dynamic office (true odometry, drive seeds 1-8
at chord lengths 0.14, 0.15 and 0.16 m: 24 drives a setting, ``benchmarks/walker_chords.py``),
median / largest RMS: 0.130 / 0.238 m -> 0.053 / 0.191 m without the free-space evidence,
0.073 / 0.314 -> 0.047 / 0.125 m with the evidence per square. The drifted Radish logs map as
before (seeds 0-4: Intel and fr079 the same trajectories to the digit, CSAIL but for one seed,
ATE 0.141 -> 0.127 m).
"""


ESTABLISHED_SHARE = 0.5
"""
A weakly constrained direction is held (``WEAK_SIGMAS``) only when the *established* segments
(``match_scan``'s ``established``: long-seen walls) carry less than this share of its
information. On the drifted CSAIL log (seed 2) two corrections of 0.4 m along a corridor, back
onto walls mapped long before (78 and 58 % of the information from segments with a support of
100 points or more), were right; the walker's pulls rest on the last scans' chords and young
segments (at most 17 %).
"""


START_GATE = 0.2
"""
``match_scan``'s ``starts`` are scored within this many metres (at most the first gate). Within
0.5 m a cluttered place explains any of them nearly alike: fr079 scan 678 (ranges 1-3.5 m), 90
points, scores 82 / 87 / 88 at a start 0.24 / 0.07 / 0.09 rad off (89 at the true pose); within
0.2 m 53 / 72 / 81 (86).
"""


START_MARGIN = 1.0
"""
``match_scan``'s prediction gives way to one of its ``starts`` scoring this much higher. With
the heading search's 1.1, fr079 from its scans alone was lost at scan 1337: the prediction 8
deg off scored 79.5 of 90 points, the half-motion start 85.4.
"""


RELOCALIZE_SHARE = 0.6
"""
``match_scan`` with ``relocalize`` searches wider when fewer than this share of the scan's
points lie within the final gate of the map at its result (by default; the session raises it
after a sudden drop, ``session.RELOCALIZE_DROP``). Matched drifted Radish logs, seed 0: median
100 %, 30 of Intel's 909 scans and 7 of CSAIL's 405 below 60 % (clutter, new rooms); a scan
0.8 m off after a wheel slip: 40 % on the test's office drive, 61 % on slips.py's.
"""


RELOCALIZE_GAIN = 1.5
"""A relocalized pose is taken only when it puts this many times more points on the map."""


RELOCALIZE_STEP = 0.1
"""Metres between the shifts the relocalization search tries (scored within 1.5 steps)."""


GAP_STEP, GAP_TURN_STEP, GAP_CELL = 0.2, 0.05, 0.05
"""``search_after_gap``: shift grid (m), heading grid (rad) and distance-field cell (m)."""
GAP_CANDIDATES = 6
"""``search_after_gap``: how many distinct poses it returns (by default)."""


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
    """RMS of the inliers' distances to their lines (within the final gate), metres."""
    degenerate: int
    """Number of directions of (x, y, yaw) kept at the prediction."""
    relocalized: bool = False
    """Whether the pose comes from the wider search (``relocalize``), not the prediction's."""
    proposal: Optional[np.ndarray] = None
    """With reason 'correction too large': the refused pose (x, y, yaw); with ``held``: the
    match before the hold; else None."""
    share: float = math.nan
    """Share of the scan's (matched) points within the final gate of the map at ``pose`` (NaN
    when there is no map)."""
    held: int = 0
    """Weakly constrained directions kept at the prediction because the match disagreed with it
    beyond ``WEAK_SIGMAS`` (``prediction_cov``); counted in ``degenerate`` too."""


MAX_SAMPLES = 1e7
"""``match_scan``: the most segment samples it builds (the incremental mapper's
``LOAD_LENGTH_LIMIT``, 100 km, at the default 5 cm is 2e6)."""


def transform(points: np.ndarray, pose) -> np.ndarray:
    """Return laser-frame points (N, 2) placed at ``pose`` (x, y, yaw)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.stack([pose[0] + c * points[:, 0] - s * points[:, 1],
                     pose[1] + s * points[:, 0] + c * points[:, 1]], axis=1)


class _SegmentSamples:
    """
    Points sampled along segments (each tagged with its segment) in a k-d tree.

    A point's nearest sample names (up to half the sample spacing) its nearest segment; built
    once per scan, it answers every Gauss-Newton iteration's association in O(N log S).
    """

    def __init__(self, segments: np.ndarray, spacing: float):
        samples, self.owner = sample_segments(segments, spacing)
        self.tree = cKDTree(samples)

    def pairs(self, points: np.ndarray, gate: float) -> tuple:
        """Return (point ids, segment ids) of each point's nearest segment within ``gate``."""
        return self.paired(*self.tree.query(points, k=1, distance_upper_bound=gate))

    def paired(self, dist: np.ndarray, idx: np.ndarray) -> tuple:
        """Return ``pairs``' (point ids, segment ids) from the answer of its k-d tree query."""
        pt = np.flatnonzero(np.isfinite(dist))
        return pt, self.owner.take(idx.take(pt))


def _fit(near: '_SegmentSamples', pts: np.ndarray, pose: np.ndarray, gate: float) -> tuple:
    """
    Return how well the map explains ``pts`` placed at ``pose``: (score, share).

    Score: sum over points of max(0, 1 - (d / gate)^2), d the distance to the map; share: the
    share of points with d < ``gate``. One k-d tree query.
    """
    d, _ = near.tree.query(transform(pts, pose), k=1, distance_upper_bound=gate)
    return _scored(d, gate)


def _scored(d: np.ndarray, gate: float) -> tuple:
    """Return ``_fit``'s (score, share) of the distances ``d`` of a query within ``gate``."""
    return float(np.clip(1.0 - (d / gate) ** 2, 0.0, None).sum()), float(np.isfinite(d).mean())


def _narrowed(d: np.ndarray, gate: float, narrow: float) -> Optional[np.ndarray]:
    """
    Return the distances a query within ``narrow`` <= ``gate`` gives, from one within ``gate``.

    The nearest sample within ``gate`` is the nearest within ``narrow`` when it lies there
    (the same distance, computed alike), and there is none when it does not: a query less. None
    when a distance lies within a billionth of ``narrow`` (where the tree's own test of the
    bound, on squared distances, could decide otherwise): query again then.
    """
    if narrow == gate:
        return d
    if (np.abs(d - narrow) <= 1e-9 * narrow).any():
        return None
    return np.where(d < narrow, d, np.inf)


def _placements(near: '_SegmentSamples', pts: np.ndarray, pose: np.ndarray, turns,
                shifts: np.ndarray, gate: float) -> np.ndarray:
    """
    Score ``pts`` placed at ``pose`` turned by each of ``turns`` and moved by each of ``shifts``.

    Returns (T, S): sum over points of max(0, 1 - (d / gate)^2), d the distance to the nearest
    segment sample. One k-d tree query for all T x S x N placed points.
    """
    ang = pose[2] + np.asarray(turns, dtype=np.float64).reshape(-1)[:, None, None]   # (T, 1, 1)
    c, s = np.cos(ang), np.sin(ang)
    bx = (pose[0] + shifts[:, 0])[:, None]                                  # (S, 1)
    by = (pose[1] + shifts[:, 1])[:, None]
    xs = bx + c * pts[:, 0] - s * pts[:, 1]                                 # (T, S, N)
    ys = by + s * pts[:, 0] + c * pts[:, 1]
    d, _ = near.tree.query(np.stack([xs.ravel(), ys.ravel()], axis=1), k=1,
                           distance_upper_bound=gate)
    return np.clip(1.0 - (d.reshape(xs.shape) / gate) ** 2, 0.0, None).sum(axis=2)


def _best_turn(near: '_SegmentSamples', pts: np.ndarray, pose: np.ndarray, gate: float,
               turns: np.ndarray, dist: np.ndarray = None) -> float:
    """
    Return the heading offset (of ``turns``) whose placement of ``pts`` the map explains best.

    Score: sum over points of max(0, 1 - (d / gate)^2), d the distance to the nearest segment
    sample. A heading error of a tenth of a radian moves a point 5 m away by half a metre,
    beyond where Gauss-Newton's first association can pull it; this coarse search cannot miss it.
    ``dist``: the distances of ``pts`` at ``pose`` within ``gate`` when already queried.
    """
    if len(turns) < 2:
        return 0.0
    ids = _spread_ids(len(pts), TURN_POINTS)
    pts = pts if ids is None else pts[ids]
    # The score at the predicted heading first: when it reaches len(pts) / TURN_MARGIN no turn
    # can beat it by the margin (a score is at most len(pts)), so the other turns need no query.
    if dist is None:
        at_pose = _fit(near, pts, pose, gate)[0]
    else:
        at_pose = _scored(dist if ids is None else dist[ids], gate)[0]
    if at_pose * TURN_MARGIN >= len(pts):
        return 0.0
    scores = _placements(near, pts, pose, turns, np.zeros((1, 2)), gate)[:, 0]
    best = int(np.argmax(scores))
    at_zero = scores[int(np.argmin(np.abs(turns)))]
    # The prediction wins ties: a turn is taken only when it explains clearly more points.
    return float(turns[best]) if scores[best] > TURN_MARGIN * at_zero else 0.0


def _best_start(near: '_SegmentSamples', pts: np.ndarray, pred: np.ndarray,
                starts: np.ndarray, gate: float) -> np.ndarray:
    """
    Return the pose, of ``pred`` and ``starts`` (H, 3), whose placement the map explains best.

    Scored as ``_best_turn`` scores a heading (``TURN_POINTS`` of the points), within ``gate``;
    ``pred`` wins unless another scores ``START_MARGIN`` times more.
    """
    starts = starts.reshape(-1, 3)
    if not len(starts):
        return pred
    pts = spread(pts, TURN_POINTS)
    at_pred = _fit(near, pts, pred, gate)[0]
    scores = [_fit(near, pts, s, gate)[0] for s in starts]
    best = int(np.argmax(scores))
    return starts[best].copy() if scores[best] > START_MARGIN * at_pred else pred


def _finite(name: str, value, shape: tuple, positive: bool = False) -> np.ndarray:
    """Return ``value`` as a float array of ``shape``; ValueError naming it if it is not one."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != shape or not np.isfinite(arr).all() or (
            positive and not (arr > 0).all()):
        what = 'x'.join(str(n) for n in shape)
        got = repr(value) if arr is None or arr.size <= 4 else f'shape {arr.shape}'
        raise ValueError(f'{name} must be {what} finite{" positive" if positive else ""} '
                         f'numbers, got {" ".join(got.split())}')
    return arr


def match_scan(points, prediction, segments, sigma: float, iterations: int = 15,
               gate: float = 0.5, gate_min: float = None, kernel: float = None,
               min_inliers: int = 20, min_share: float = 0.25, max_shift: float = 0.5,
               max_turn: float = 0.35, degenerate: float = 0.02,
               prior_std: tuple = (0.1, 0.1, 0.05),
               turns=np.linspace(-0.2, 0.2, 9), max_points: int = 240,
               spacing: float = 0.05, relocalize: float = 0.0,
               relocalize_share: float = RELOCALIZE_SHARE,
               prediction_cov=None, established=None, starts=None, transient=None,
               prediction_prior=None, relocalize_near: bool = False, chords=None,
               chord_cov=None) -> ScanMatch:
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
    turns : (T,) float array
        Heading offsets (rad) tried before Gauss-Newton (``_best_turn``); one value: none.
    max_points : int
        A scan with more points is matched with this many, evenly spread over its beams.
    spacing : float
        Sample spacing along the segments, metres: a point pairs with the segment of its nearest
        sample (exact point-to-line residuals; the choice between two segments closer than
        half the spacing may be off).
    relocalize : float
        0: off. Else, when fewer than ``relocalize_share`` of the points lie within the final
        gate at the result (or at the prediction, when refused), a search over shifts within
        this many metres (and ``turns``) and Gauss-Newton from its best pose; its result is
        taken (``relocalized``) when it lies more than ``gate`` from the prediction and
        ``RELOCALIZE_GAIN`` times more points lie on the map, at least ``relocalize_share`` of
        them. ``max_shift`` / ``max_turn`` then do not apply.
    relocalize_share : float
        See ``relocalize`` (default ``RELOCALIZE_SHARE``).
    prediction_cov : (3, 3) float array, optional
        Covariance of the prediction's error (m^2, rad^2; e.g. the odometry's over the motion
        since the last match, ``odometry_covariance``). When given, a weakly constrained
        direction (``WEAK_SHARE``) whose correction exceeds ``WEAK_SIGMAS`` of its standard
        deviations is held at the prediction (``held``): something the scan sees moved with
        the robot (a person walking ahead in a corridor), or the scan explains it by too few
        points to overrule the odometry.
    established : (K,) bool array, optional
        Per segment, whether it is an established wall (long seen). With ``prediction_cov``, a
        direction the established segments mostly constrain is never held
        (``ESTABLISHED_SHARE``). None: every segment counts as new.
    transient : (K,) bool array, optional
        Per segment, whether it may be something that moves (a chord along a person-sized run
        of the last scans). With ``prediction_cov``, a weakly constrained direction they
        mostly constrain is held at the prediction (``TRANSIENT_SHARE``).
    starts : (H, 3) float array, optional
        Other predictions of the pose (a constant-velocity prediction's alternatives: the
        robot stopped, or slowed down). When one of them places the scan better on the map
        than ``prediction`` (``_best_start``: within ``START_GATE``), the match starts from it
        and is judged against it (``max_shift``, ``max_turn``, ``relocalize``) as from the
        prediction.
    prediction_prior : (3, 3) float array, optional
        Covariance (m^2, rad^2) of the prediction's error, taken as a Gaussian prior on the
        pose, centred where Gauss-Newton starts (the prediction or the start taken, turned by
        the heading search): every step minimises sum w d^2 + sigma^2 (x - x0)^T P^-1 (x - x0).
        It replaces the degeneracy guard: ``degenerate`` must be 0 with it (ValueError
        otherwise; the guard would be read off the information with the prior in it, where
        no direction is degenerate), and the prior, not a threshold, keeps a direction the
        scan hardly constrains near the start. It must be finite and positive definite. None:
        no prior.
    relocalize_near : bool
        Take a relocalized pose within ``gate`` of the prediction too. From odometry the first
        result stands there (a loop's return onto older ground, below); from a
        constant-velocity prediction a turn that starts or speeds up between two scans can
        leave the first result in a wrong basin within the gate, and the search's pose puts
        ``RELOCALIZE_GAIN`` times more points on the map.
    chords : (K,) bool array, optional
        Per segment, whether it is one of the last scans' chords (``scan_chords``: between two
        of that scan's readings, placed at its matched pose) rather than a map segment fitted
        to many scans. The covariance then includes their error (``_chord_share``): each knot
        off by ``sigma``, and the chords' placement by ``chord_cov``. The match itself is the
        same. None: every segment is exact, as the covariance has always taken them.
    chord_cov : (3, 3) float array, optional
        Covariance (m^2, rad^2) of the pose the chords were placed at (the last matched scan's),
        with ``chords``. None: the knots' noise only.

    Returns
    -------
    ScanMatch

    """
    pts = as_points(points)
    pts = spread(pts, max_points)                # the time per scan stays bounded
    pred = _finite('prediction', prediction, (3,))
    segs = as_segments(segments)
    prior = np.diag(np.square(_finite('prior_std', prior_std, (3,), positive=True)))
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f'sigma must be a finite number > 0, got {sigma!r}')
    if not (is_number(spacing) and spacing > 0):
        raise ValueError(f'spacing must be a finite number > 0 (m), got {spacing!r}')
    samples = float(lengths(segs).sum()) / spacing
    if samples > MAX_SAMPLES:       # (an API audit: spacing 1e-7 m ran for minutes)
        raise ValueError(f'the segments sampled every {spacing:g} m give {samples:.3g} samples, '
                         f'more than {MAX_SAMPLES:g}: a larger spacing, or fewer segments')
    if prediction_cov is not None:
        prediction_cov = _finite('prediction_cov', prediction_cov, (3, 3))
    if chord_cov is not None:
        chord_cov = _finite('chord_cov', chord_cov, (3, 3))
    if prediction_prior is not None:
        prediction_prior = np.asarray(prediction_prior, dtype=np.float64).reshape(3, 3)
        if degenerate != 0:
            raise ValueError(f'prediction_prior replaces the degeneracy guard: pass '
                             f'degenerate=0 with it, got {degenerate!r}')
        if not (np.isfinite(prediction_prior).all()
                and np.allclose(prediction_prior, prediction_prior.T)
                and np.all(np.linalg.eigvalsh(prediction_prior) > 0)):
            raise ValueError('prediction_prior must be a finite, symmetric, positive definite '
                             '(3, 3) covariance')
    if len(segs) == 0 or len(pts) == 0:
        return ScanMatch(pred, prior, False, 'no map', 0, np.nan, 3)
    gate_min = 4.0 * sigma if gate_min is None else float(gate_min)
    kernel = 2.0 * sigma if kernel is None else float(kernel)
    gate = max(float(gate), gate_min)
    u = segs[:, 1] - segs[:, 0]
    length = np.hypot(u[:, 0], u[:, 1])
    keep = length > 1e-9
    segs, u, length = segs[keep], u[keep], length[keep]
    est = None if established is None else np.asarray(established, dtype=bool).reshape(-1)[keep]
    tra = None if transient is None else np.asarray(transient, dtype=bool).reshape(-1)[keep]
    own = None if chords is None else np.asarray(chords, dtype=bool).reshape(-1)[keep]
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1) / length[:, None]
    near = _SegmentSamples(segs, spacing=float(spacing))
    scale = max(median(np.hypot(pts[:, 0], pts[:, 1])), 1.0)   # metres per radian
    need = min(min_inliers, max(3, int(np.ceil(min_share * len(pts)))))
    if starts is not None:
        pred = _best_start(near, pts, pred, np.asarray(starts, dtype=np.float64),
                           min(gate, START_GATE))
    lines = np.concatenate([normal, segs[:, 0]], axis=1)
    anchor = None
    if prediction_prior is not None:      # sigma^2 P^-1 in the scaled coordinates (yaw x scale)
        scaled = np.array([1.0, 1.0, scale])
        anchor = float(sigma) ** 2 * np.linalg.inv(prediction_prior * scaled[:, None] * scaled)
    problem = _Problem(pts, lines, near, float(sigma), gate, gate_min, kernel, need,
                       scale, prior, int(iterations), float(degenerate), est, anchor, tra,
                       own, chord_cov, segs)
    m = _refine(problem, pred, turns, max_shift, max_turn, prediction_cov)
    if not relocalize or m.share >= relocalize_share:
        return m
    # Few of the scan's points are on the map where the prediction (or the match from it)
    # puts them: a wheel slip or a bump beyond the match gate, or new ground. A coarse search
    # over shifts within ``relocalize`` metres and the heading turns, then Gauss-Newton from
    # its best pose; taken only when it puts clearly more points on the map (new ground has
    # no such pose: the first result stands).
    # Only a pose beyond the first gate is taken: within it the first result stands, as a
    # better optimum there is a jump onto old ground the drifted recent map disagrees with (a
    # loop; without loop closure it bends the map: on the drifted CSAIL log, seed 0, one such
    # jump of 0.11 m and 0.30 rad doubled the trajectory error).
    start = _search(near, pts, pred, float(relocalize), turns)
    again = _refine(problem, start, (0.0,), np.inf, np.inf)
    shift = np.hypot(*(again.pose[:2] - pred[:2]))
    if (again.ok and (gate < shift or relocalize_near) and shift <= relocalize + max_shift
            and again.share >= relocalize_share
            and again.share >= RELOCALIZE_GAIN * m.share):
        return again._replace(relocalized=True)
    return m


class _Problem(NamedTuple):
    """One scan against one map, as ``match_scan`` prepared them for ``_refine``."""

    pts: np.ndarray
    lines: np.ndarray
    """(K, 4) per segment: its unit normal (x, y) and its first end (x, y)."""
    near: _SegmentSamples
    sigma: float
    gate: float
    gate_min: float
    kernel: float
    need: int
    scale: float
    prior: np.ndarray
    iterations: int
    degenerate: float
    established: Optional[np.ndarray] = None
    """(K,) bool per segment, or None (see ``match_scan``)."""
    anchor: Optional[np.ndarray] = None
    """(3, 3) sigma^2 times the prior's information (scaled coordinates), or None."""
    transient: Optional[np.ndarray] = None
    """(K,) bool per segment, or None (see ``match_scan``)."""
    chords: Optional[np.ndarray] = None
    """(K,) bool per segment, or None (see ``match_scan``)."""
    chord_cov: Optional[np.ndarray] = None
    """(3, 3) covariance of the chords' placement (see ``match_scan``), or None."""
    segments: Optional[np.ndarray] = None
    """(K, 2, 2) the segments of ``lines`` (with ``chords``)."""


def _search(near: _SegmentSamples, pts: np.ndarray, pose: np.ndarray, radius: float,
            turns) -> np.ndarray:
    """
    Return the pose, of shifts within ``radius`` and heading ``turns``, that the map explains best.

    The shifts form a grid ``RELOCALIZE_STEP`` apart; each placement of (at most
    ``TURN_POINTS`` of) the points is scored as in ``_best_turn`` (``_placements``), within 1.5
    steps (a pose half a step off still scores).
    """
    pts = spread(pts, TURN_POINTS)
    shifts = _disk_grid(radius, RELOCALIZE_STEP)                        # (S, 2)
    turns = np.asarray(turns, dtype=np.float64).reshape(-1)
    score = _placements(near, pts, pose, turns, shifts, 1.5 * RELOCALIZE_STEP)
    t, i = np.unravel_index(int(np.argmax(score)), score.shape)
    return np.array([pose[0] + shifts[i, 0], pose[1] + shifts[i, 1], pose[2] + turns[t]])


def _disk_grid(radius: float, step: float) -> np.ndarray:
    """Return the points of a square grid ``step`` apart within ``radius`` of (0, 0): (S, 2)."""
    k = int(np.ceil(radius / step))
    grid = np.arange(-k, k + 1) * step
    dx, dy = (a.ravel() for a in np.meshgrid(grid, grid))
    inside = np.hypot(dx, dy) <= radius + 1e-9
    return np.column_stack([dx[inside], dy[inside]])


class _Steps(NamedTuple):
    """The state at the end of ``_gauss_newton``."""

    pose: np.ndarray
    """(3,) x, y, yaw; None when too few points paired."""
    info: np.ndarray
    """The last information matrix, in the coordinates of the free directions (yaw scaled)."""
    vals: np.ndarray
    """Its eigenvalues, ascending."""
    vecs: np.ndarray
    """(3, m) its eigen-directions in (x, y, yaw x scale)."""
    good: np.ndarray
    """(m,) whether each direction was corrected (not degenerate)."""
    res: np.ndarray
    """Signed distances of the paired points to their lines (last iteration)."""
    pairs: int
    """Points paired in the last iteration."""
    last: tuple = ()
    """(jacobian, weights, segment ids, point ids) of the last iteration's pairs (all
    directions)."""


def _gauss_newton(p: _Problem, pose: np.ndarray, free: np.ndarray = None,
                  first: tuple = None) -> _Steps:
    """
    Run ``match_scan``'s Gauss-Newton steps from ``pose``; return the final state.

    ``free``: (3, m) orthonormal directions in (x, y, yaw x scale) the steps may move along
    (None: all three); the pose keeps its component along the others. ``first``: the first
    step's pairs (``_SegmentSamples.pairs`` of the points at ``pose`` within the first gate)
    when already known.
    """
    near, gate, gate_min, kernel, scale = p.near, p.gate, p.gate_min, p.kernel, p.scale
    px, py = np.ascontiguousarray(p.pts[:, 0]), np.ascontiguousarray(p.pts[:, 1])
    world = np.empty(p.pts.shape)
    turned = np.empty(p.pts.shape)      # d world / d yaw, rotated a quarter turn back
    wx, wy, tx, ty = world[:, 0], world[:, 1], turned[:, 0], turned[:, 1]
    cx, sy, sx, cy = (np.empty(len(px)) for _ in range(4))
    info = np.zeros((3, 3))
    vals = np.zeros(3)
    good = np.zeros(3, dtype=bool)
    vecs = np.eye(3)
    res = np.zeros(0)
    pt = np.zeros(0)
    last = ()
    stage, at_stage = 0, 0
    origin = pose.copy()                # where the prior (``p.anchor``) is centred
    for it in range(int(p.iterations)):
        g = max(gate * 0.6 ** stage, gate_min)
        # transform(pts, pose) and its derivative along yaw, from the same four products
        # (written into the buffers: the same operations, in the same order, as
        # world = (pose[0] + c px - s py, pose[1] + s px + c py))
        c, s = np.cos(pose[2]), np.sin(pose[2])
        np.multiply(px, c, out=cx)
        np.multiply(py, s, out=sy)
        np.multiply(px, s, out=sx)
        np.multiply(py, c, out=cy)
        np.subtract(np.add(cx, pose[0], out=wx), sy, out=wx)
        np.add(np.add(sx, pose[1], out=wy), cy, out=wy)
        np.subtract(np.negative(sx, out=tx), cy, out=tx)
        np.subtract(cx, sy, out=ty)
        pt, sg = first if it == 0 and first is not None and g == gate else near.pairs(world, g)
        if len(pt) < p.need:
            return _Steps(None, info, vals, vecs, good, res, int(len(pt)))
        line = p.lines.take(sg, axis=0)             # (normal x, y, first end x, y) per pair
        n0, n1 = line[:, 0], line[:, 1]
        at = world.take(pt, axis=0)
        res = n0 * (at[:, 0] - line[:, 2]) + n1 * (at[:, 1] - line[:, 3])
        jac = np.empty((len(pt), 3))
        jac[:, :2] = line[:, :2]
        turn = turned.take(pt, axis=0)
        yaw = n0 * turn[:, 0]
        np.divide(np.add(yaw, n1 * turn[:, 1], out=yaw), scale, out=jac[:, 2])
        k = max(kernel, g / 3.0)          # the kernel widens with the gate: a far start pulls
        w = 1.0 / (1.0 + (res / k) ** 2)
        info = jac.T @ (w[:, None] * jac)
        grad = -jac.T @ (w * res)
        last = (jac, w, sg, pt)
        top = None
        if free is not None:            # the problem restricted to the free directions
            top = np.linalg.eigvalsh(info)[-1]
            info, grad = free.T @ info @ free, free.T @ grad
        if p.anchor is not None and free is None:
            toward = origin - pose
            toward[2] = wrap_angle(toward[2]) * scale
            info = info + p.anchor
            grad = grad + p.anchor @ toward
        vals, vecs = np.linalg.eigh(info)
        good = vals > p.degenerate * max(vals[-1] if top is None else top, 1e-12)
        if free is None:
            step = _step3(vals, vecs, grad, good)
        else:
            step = np.zeros(len(vals))
            for k in np.flatnonzero(good):
                step += (vecs[:, k] @ grad) / vals[k] * vecs[:, k]
            step, vecs = free @ step, free @ vecs
        step[2] /= scale
        pose = pose + step
        at_stage += 1
        small = np.hypot(step[0], step[1]) < 0.005 and abs(step[2]) < 0.002
        if small and g <= gate_min:
            break
        if small or at_stage >= 3:          # converged at this gate (or slow): narrow it
            stage, at_stage = stage + 1, 0
    return _Steps(pose, info, vals, vecs, good, res, int(len(pt)), last)


def _step3(vals: np.ndarray, vecs: np.ndarray, grad: np.ndarray, good: np.ndarray) -> np.ndarray:
    """
    Return the Gauss-Newton step sum over the good k of (v_k . grad) / vals[k] v_k: (3,).

    In Python floats: the same products and sums, in the same order, as the NumPy loop over the
    good directions (``step += (vecs[:, k] @ grad) / vals[k] * vecs[:, k]`` from zeros; a dot of
    three sums its products in order), without a dozen small-array calls per iteration.
    """
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = vecs.tolist()
    g0, g1, g2 = grad.tolist()
    s0 = s1 = s2 = 0.0
    for ok, val, v0, v1, v2 in zip(good.tolist(), vals.tolist(), (a0, a1, a2), (b0, b1, b2),
                                   (c0, c1, c2)):
        if ok:
            t = (0.0 + v0 * g0 + v1 * g1 + v2 * g2) / val
            s0, s1, s2 = s0 + t * v0, s1 + t * v1, s2 + t * v2
    return np.array([s0, s1, s2])


def _along(directions: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Return d^T m d for each column d of ``directions`` (3, k): (k,)."""
    return np.einsum('ik,ij,jk->k', directions, m, directions)


def _disagreeing(p: _Problem, pred: np.ndarray, st: _Steps, cov: np.ndarray) -> np.ndarray:
    """
    Return which of ``st``'s directions are weakly constrained and disagree with ``pred``.

    Weak: eigenvalue below ``WEAK_SHARE`` of the largest. Disagree: the correction along the
    direction exceeds ``WEAK_SIGMAS`` standard deviations of the prediction (``cov``). Only
    directions the established map (``_Problem``'s ``established`` segments) carries less
    than ``ESTABLISHED_SHARE`` of count: a correction
    that long-seen walls make is drift the odometry carried (a loop's return), not something
    that moved with the robot.
    """
    scaled = np.array([1.0, 1.0, p.scale])
    d = st.pose - pred
    d[2] = wrap_angle(d[2])
    along = np.abs(st.vecs.T @ (d * scaled))
    sd = np.sqrt(_along(st.vecs, cov * scaled[:, None] * scaled))
    weak = st.vals < WEAK_SHARE * max(st.vals[-1], 1e-12)
    out = weak & (along > WEAK_SIGMAS * sd)
    if out.any() and p.established is not None:
        jac, w, sg, _ = st.last
        e = p.established[sg]
        est = _along(st.vecs, jac[e].T @ (w[e, None] * jac[e]))
        out &= est < ESTABLISHED_SHARE * np.maximum(st.vals, 1e-12)
    if weak.any() and p.transient is not None:
        jac, w, sg, _ = st.last
        t = p.transient[sg]
        if t.any():
            moving = _along(st.vecs, jac[t].T @ (w[t, None] * jac[t]))
            out |= weak & (moving >= TRANSIENT_SHARE * np.maximum(st.vals, 1e-12))
    return out


def _chord_share(p: _Problem, st: _Steps, pose: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """
    Return the covariance (scaled coordinates) the last scans' chords add to a match: (3, 3).

    ``sigma^2 (J^T W J)^-1`` holds when every line a point is matched to is exact. The chords
    are not: each runs between two of an earlier scan's readings (``scan_chords``' knots),
    each off by the noise, and that scan sits where its own match put it (``chord_cov``). The
    match moves by ``H^-1 sum_i w_i J_i e_i`` for line errors ``e_i`` (the estimating
    equations). With knot errors ``e = (1 - t) e_a + t e_b`` (t: where the point falls along
    its chord between knots a and b) and the chords' placement error ``delta`` (every chord
    moved with it, ``e_i = -J_i delta``, their scans being near this one), it adds
    ``H^-1 B H^-1`` with ``B = sigma^2 sum_k s_k s_k^T + H_c P H_c``: per knot k, ``s_k``
    sums ``(1 - t_i) w_i J_i`` over the pairs on chords starting there and ``t_i w_i J_i``
    over those ending there (two chords of a run share a knot); ``H_c`` is the information of
    the chords' pairs and ``P`` their placement's covariance. ``H^-1`` over the corrected
    directions only (the held or degenerate ones keep the prior's variance); ``vals``: the
    eigenvalues of ``st.info``, as ``_refine`` has them.
    """
    jac, w, sg, pt = st.last
    on = p.chords[sg]
    if not on.any():
        return np.zeros((3, 3))
    jac, w, sg = jac[on], w[on], sg[on]
    wj = jac * w[:, None]
    a, b = p.segments[sg, 0], p.segments[sg, 1]
    d = b - a
    t = np.clip(np.einsum('ij,ij->i', transform(p.pts[pt[on]], pose) - a, d)
                / np.maximum(np.einsum('ij,ij->i', d, d), 1e-18), 0.0, 1.0)
    # per knot (a reading; two chords of a run share the one between them), sum_i share_i w_i J_i
    at = np.concatenate([a, b])
    _, knot = np.unique(at[:, 0] + 1j * at[:, 1], return_inverse=True)
    share = np.concatenate([1.0 - t, t])[:, None] * np.concatenate([wj, wj])
    n = int(knot.max()) + 1
    s_k = np.stack([np.bincount(knot, weights=share[:, k], minlength=n) for k in range(3)])
    noise = p.sigma ** 2 * (s_k @ s_k.T)
    placed = 0.0
    if p.chord_cov is not None:
        scaled = np.array([1.0, 1.0, p.scale])
        h_c = jac.T @ wj
        placed = h_c @ (p.chord_cov * scaled[:, None] * scaled) @ h_c
    good = st.vecs[:, st.good]
    inv = (good / vals[st.good]) @ good.T
    return inv @ (noise + placed) @ inv


def _refine(p: _Problem, pred: np.ndarray, turns, max_shift: float,
            max_turn: float, prediction_cov: np.ndarray = None) -> ScanMatch:
    """
    Gauss-Newton from ``pred`` (``match_scan``'s steps); return the ScanMatch.

    Its ``share``: of the scan's points, those within the final gate of the map at its pose
    (the prediction when the match is refused). With ``prediction_cov``, directions
    ``_disagreeing`` with the prediction are held at it and the steps are run again.
    """
    near, pts, sigma, scale, prior = p.near, p.pts, p.sigma, p.scale, p.prior
    # The points at the prediction within the first gate: one query gives the turn search its
    # score there, the first step its pairs when it starts there, the fit of the prediction.
    d0, i0 = near.tree.query(transform(pts, pred), k=1, distance_upper_bound=p.gate)
    start = pred.copy()
    start[2] += _best_turn(near, pts, start, p.gate, turns, d0)
    st = _gauss_newton(p, start, first=(near.paired(d0, i0) if start.tobytes() == pred.tobytes()
                                        else None))
    at_pred = _narrowed(d0, p.gate, p.gate_min)
    fit_pred, on_pred = (_fit(near, pts, pred, p.gate_min) if at_pred is None else
                         _scored(at_pred, p.gate_min))
    held = np.zeros(0, dtype=bool)
    unheld = None
    if st.pose is not None and prediction_cov is not None:
        held = _disagreeing(p, pred, st, np.asarray(prediction_cov, dtype=np.float64))
        if held.any():
            unheld = st.pose
            hold_dirs = st.vecs[:, held]
            free = st.vecs[:, ~held]
            scaled = np.array([1.0, 1.0, scale])
            d = (start - pred) * scaled
            st = _gauss_newton(p, pred + (free @ (free.T @ d)) / scaled, free)
    if st.pose is None:
        return ScanMatch(pred, prior, False, 'too few inliers', st.pairs, np.nan, 3,
                         share=on_pred)
    pose, res, good = st.pose, st.res, st.good
    n_held = int(held.sum())
    degenerate = int((~good).sum()) + n_held
    # The match must explain the scan better than the prediction does (a slide along a
    # symmetric room or a corridor can lower the weighted residual while losing points):
    # else the prediction is the match (it explains the scan best).
    fit_pose, on_pose = _fit(near, pts, pose, p.gate_min)
    if fit_pose < fit_pred:
        pose, on_pose = pred.copy(), on_pred
    shift = np.hypot(*(pose[:2] - pred[:2]))
    turn = abs(wrap_angle(pose[2] - pred[2]))
    rms = float(np.sqrt(np.mean(res ** 2))) if len(res) else math.nan
    if shift > max_shift or turn > max_turn:
        return ScanMatch(pred, prior, False, 'correction too large', int(len(res)), rms,
                         degenerate, proposal=pose.copy(), share=on_pred, held=n_held)
    # Covariance in the scaled coordinates (yaw x scale): sigma^2 / eigenvalue along the
    # constrained directions, the prior's variance along the others; then metres and radians.
    vecs = st.vecs
    vals = np.linalg.eigvalsh(st.info)
    prior_scaled = prior * np.array([1.0, 1.0, scale])[:, None] * np.array([1.0, 1.0, scale])
    var = np.where(good, sigma ** 2 / np.maximum(vals, 1e-12),
                   _along(vecs, prior_scaled))
    unscale = np.diag([1.0, 1.0, 1.0 / scale])
    cov_scaled = (vecs * var) @ vecs.T
    if p.chords is not None:
        cov_scaled = cov_scaled + _chord_share(p, st, pose, vals)
    cov = unscale @ cov_scaled @ unscale
    if n_held:                          # the prior's variance along the held directions too
        vals_h = _along(hold_dirs, prior_scaled)
        cov += unscale @ ((hold_dirs * vals_h) @ hold_dirs.T) @ unscale
    return ScanMatch(pose, cov, True, '', int(len(res)), rms, degenerate, share=on_pose,
                     held=n_held, proposal=unheld)


def spread(points: np.ndarray, n: int) -> np.ndarray:
    """Return at most ``n`` of ``points``, evenly spaced in their order (beam order)."""
    ids = _spread_ids(len(points), n)
    return points if ids is None else points[ids]


@functools.lru_cache(maxsize=256)
def _spread_ids(count: int, n: int) -> Optional[np.ndarray]:
    """Return the indices ``spread`` keeps of ``count`` points (None: all; read-only, cached)."""
    if not n or count <= n:
        return None
    ids = np.linspace(0, count - 1, int(n)).astype(np.intp)
    ids.flags.writeable = False
    return ids


CHORD_MIN_EXTENT = 0.55
"""
Metres between a run's first and last reading below which a free-standing run may be a person
(a 0.5 m circle in the simulator), a leg or a post: its chords among the last scans' are
``transient`` to ``match_scan`` (``session.RecentChords``).
"""


CHORD_STEP_WINDOW = 31
"""
Neighbour steps whose median ``scan_chords`` counts for each step of a scan's arc with
``knots='median'`` (``SessionOptions.chord_knots``, the node's ``chord_knots``).
"""
CHORD_KNOTS = ('arc', 'median')
"""``scan_chords``'s knot rules: the raw arc, or the arc of median steps."""
DEFAULT_CHORD_KNOTS = 'median'
"""The session's and the node's default knot rule ('arc' before 2026-11-30)."""


def scan_chords(points: np.ndarray, gap: float = 0.5, length: float = 0.15,
                extents: bool = False, knots: str = 'arc'):
    """
    Return the chords of one scan: (K, 2, 2) segments along its points, about ``length`` long.

    A scan's points in beam order, joined where neighbours lie closer than ``gap`` metres, are
    the scan's own polyline (as PL-ICP uses the previous scan); its knots are taken every
    ``length`` metres of arc (and at each run's ends), so a chord's direction is the wall's,
    not that of two neighbouring readings' noise (two readings 2 cm apart with 1 cm noise
    would point anywhere, and a corridor wall would seem to constrain its own axis: a 60 m
    simulated corridor slid by up to 2 cm a scan with such chords, under 3 mm with these).
    ``knots``: 'arc' counts the raw steps between neighbouring readings; then a knot is the
    reading whose noise lengthened its own step, i.e. one displaced along the sweep, and with
    noise that grows with the range (a TurtleBot3's LDS-01: 1.5 cm + 1 %) the far end of every
    chord is displaced more: every chord turns the same way (-0.11 deg a match, +0.11 with the
    beams reversed; -0.03 / +0.03 with 1.5 cm alone), and a drive with perfect odometry ends
    1.9-4.9 deg off (benchmarks/cheap_lidar.py). 'median' counts each step as the median of the
    ``CHORD_STEP_WINDOW`` steps around it (steps across a break count 0), so whether a reading
    is a knot does not depend on its own noise.
    With ``extents`` it returns (chords, extent, first, last): per chord, the distance between
    its run's first and last reading (m) and their indices, each (K,). The
    last few scans' chords, placed at their matched poses, join the map G(t) for matching:
    where the robot turns into a new room G(t) has no segment yet (SMEMSF needs support from
    several scans), and a scan matched only to G(t) there would keep the drifting prediction.

    >>> scan_chords(np.array([[0.0, 0.0], [0.05, 0.0], [0.25, 0.0], [2.0, 0.0], [2.1, 0.0]]))
    array([[[0.  , 0.  ],
            [0.25, 0.  ]],
    <BLANKLINE>
           [[2.  , 0.  ],
            [2.1 , 0.  ]]])
    """
    if knots not in CHORD_KNOTS:
        raise ValueError(f'knots must be one of {CHORD_KNOTS}, got {knots!r}')
    pts = as_points(points)
    if len(pts) < 2:
        none = np.zeros(0, dtype=np.intp)
        return (np.zeros((0, 2, 2)), np.zeros(0), none, none) if extents else np.zeros((0, 2, 2))
    d = np.hypot(*np.diff(pts, axis=0).T)
    broken = np.concatenate([[True], d >= gap])            # a point that starts a run
    run = np.cumsum(broken)
    step = np.where(d < gap, d, 0.0)
    if knots == 'median':
        step = median_filter(step, size=CHORD_STEP_WINDOW, mode='nearest')
    arc = np.concatenate([[0.0], np.cumsum(np.where(d < gap, step, 0.0))])
    start = arc[np.flatnonzero(broken)][run - 1]             # each point's run's first arc
    bins = np.floor((arc - start) / length)
    last = np.concatenate([broken[1:], [True]])             # a point that ends a run
    knot = broken | last | np.concatenate([[False], bins[1:] != bins[:-1]])
    k = np.flatnonzero(knot)
    same = (run[k[1:]] == run[k[:-1]]) & (k[1:] > k[:-1])
    a, b = pts[k[:-1][same]], pts[k[1:][same]]
    keep = np.hypot(*(b - a).T) > 1e-9
    chords = np.stack([a[keep], b[keep]], axis=1)
    if not extents:
        return chords
    extent = np.hypot(*(pts[last] - pts[broken]).T)           # per run, first to last reading
    own = run[k[:-1][same]][keep] - 1                   # each chord's run
    return chords, extent[own], np.flatnonzero(broken)[own], np.flatnonzero(last)[own]


class OdometryNoise(NamedTuple):
    """Wheel odometry's error per step (issue 19's drift model; ``recordings.OdometryDrift``)."""

    translation: float = 0.05
    """Std of each axis's error, as a share of the step's length."""
    rotation: float = 0.02
    """Std of the heading error of every step, radians (``OdometryDrift.apply`` with stamps:
    per ``period`` seconds, a random walk)."""
    rotation_per_m: float = math.radians(1.0)
    """Std of the heading error per metre travelled, radians."""
    period: float = 1.0
    """Seconds ``rotation`` is given for."""


ODOMETRY_NOISE = OdometryNoise()


def odometry_covariance(step, noise: OdometryNoise = ODOMETRY_NOISE) -> np.ndarray:
    """
    Return the (3, 3) covariance (m^2, rad^2) of odometry's error over one motion.

    ``step``: the motion (x, y, yaw; only its length d counts). Each axis ``translation`` x d,
    the heading ``rotation`` + ``rotation_per_m`` x d (the drift model's step, whatever its
    duration: on the safe side for odometry sampled faster); the two axes alike, so the
    covariance holds in any frame.

    >>> np.sqrt(np.diag(odometry_covariance((0.3, 0.4, 0.0)))).round(4)
    array([0.025 , 0.025 , 0.0287])
    """
    d = math.hypot(float(step[0]), float(step[1]))
    t = noise.translation * d
    r = noise.rotation + noise.rotation_per_m * d
    return np.diag([t * t, t * t, r * r])


def predict_constant_velocity(previous: Optional[np.ndarray], last: Optional[np.ndarray]):
    """Return last * (previous^-1 * last): the next pose at constant velocity (or ``last``)."""
    if last is None:
        return np.zeros(3)
    if previous is None:
        return np.asarray(last, dtype=np.float64).copy()
    return se2_compose(last, se2_compose(se2_inverse(previous), last))


def search_after_gap(points: np.ndarray, segments: np.ndarray, center, radius: float,
                     turn: float = math.pi, count: int = GAP_CANDIDATES) -> np.ndarray:
    """
    Return the poses (x, y, yaw) where the map best explains a scan, best first: (K, 3).

    ``points`` (N, 2): the scan in the laser frame, metres (at most 120 of them are used);
    ``segments`` (S, 2, 2): the map. The poses tried are the shifts on a ``GAP_STEP`` grid
    within ``radius`` metres of ``center`` (3,) at the headings within ``turn`` radians of its
    own (``GAP_TURN_STEP``); a placement scores the points through a distance field of the
    segments (``GAP_CELL`` cells): sum of max(0, 1 - (d / tol)^2), tol 1.5 grid steps. K <=
    ``count`` poses at least 0.5 m or 0.3 rad apart.
    """
    pts = spread(np.asarray(points, dtype=np.float64), 120)
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    center = np.asarray(center, dtype=np.float64)
    if not len(pts) or not len(segs):
        return np.zeros((0, 3))
    tol = 1.5 * GAP_STEP
    reach = radius + float(np.hypot(pts[:, 0], pts[:, 1]).max()) + tol
    lo = center[:2] - reach
    size = int(np.ceil(2 * reach / GAP_CELL)) + 1     # a square field around the center
    # the segments rasterized (samples every half cell), then the distance to them
    cells = np.floor((sample_segments(segs, 0.5 * GAP_CELL)[0] - lo) / GAP_CELL).astype(np.intp)
    inside = ((cells >= 0) & (cells < size)).all(axis=1)
    free = np.ones((size, size), dtype=bool)
    free[cells[inside, 0], cells[inside, 1]] = False
    if free.all():
        return np.zeros((0, 3))
    dist = distance_transform_edt(free) * GAP_CELL
    field = np.clip(1.0 - (dist / tol) ** 2, 0.0, None).ravel()
    shifts = _disk_grid(radius, GAP_STEP) + center[:2]                  # (P, 2)
    k = int(np.ceil(min(turn, np.pi) / GAP_TURN_STEP))
    headings = center[2] + np.arange(-k, k + (turn < np.pi)) * GAP_TURN_STEP     # (T,)
    scores = np.empty((len(headings), len(shifts)))
    base = (shifts - lo) / GAP_CELL
    for i, h in enumerate(headings):        # (P, N) placements per heading
        c, s = math.cos(h), math.sin(h)
        rx = (c * pts[:, 0] - s * pts[:, 1]) / GAP_CELL
        ry = (s * pts[:, 0] + c * pts[:, 1]) / GAP_CELL
        ix = np.floor(base[:, :1] + rx).astype(np.intp)
        iy = np.floor(base[:, 1:] + ry).astype(np.intp)
        scores[i] = field[ix * size + iy].sum(axis=1)
    order = np.argsort(scores, axis=None)[::-1][:50 * count]
    ti, pi = np.unravel_index(order, scores.shape)
    poses = np.column_stack([shifts[pi], headings[ti]])
    out = []
    for pose in poses:                      # the best, then the best far from those taken
        if all(math.hypot(*(pose[:2] - q[:2])) > 0.5 or abs(wrap_angle(pose[2] - q[2])) > 0.3
               for q in out):
            out.append(pose)
            if len(out) == count:
                break
    return np.array(out).reshape(-1, 3)
