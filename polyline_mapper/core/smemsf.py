"""
SMEMSF: split-and-merge EM segment fitting, the batch loop.

One iteration, at the current noise scale sigma (metres) and LSS half-size r = r_over_sigma *
sigma:

1. EMSF on the current segments; points no segment reaches (beyond kappa * sigma) are seeded
   (``seed.py``);
2. LSS with r and the per-segment threshold C (``split.py``);
3. EMSF again;
4. merging by perceptual grouping (``merge.py``).

Coarse to fine: sigma starts at 1/20 of the bounding-box diagonal (``start_box``; the paper's
diagonals can only move if they see points), then follows the data: sigma_next is the robust
scale (1.4826 x median) of the distances of supported points to their segments, but never
shrinks by more than ``shrink_fast`` nor by less than ``shrink_slow`` per iteration (a bad model
has residuals as wide as the window, so without forced shrinking it would stay coarse), and
never goes below the floor.
The floor is the sensor noise: ``config.sigma`` when given, otherwise the thickness of the
point cloud's local structure (``noise.py``), and never below ``sigma_min``. So r, and with it the
split resolution, the merge tolerance and the arc approximation error, all come from the data.

Stop: once sigma sits at its floor, when the mean truncated distance of points to their nearest
segment changes by less than ``tol`` (relative) between iterations; or at ``max_iterations``.
The result is refitted once more (so merged segments sit on their points), merged once more
(pieces the refit made collinear), and chained into polylines.
"""

from dataclasses import asdict, dataclass, field, fields
import time
from typing import Callable, Optional

import numpy as np

from .cleanup import as_origins, beam_evidence, origin_runs
from .emsf import emsf_step, extend_for
from .geometry import as_points, as_segments, config_of, is_number, is_real, lengths
from .index import piece_pairs, PointIndex
from .merge import merge_segments
from .noise import estimate_noise, median
from .polylines import map_geometry
from .seed import seed_segments
from .split import (accumulate_evidence, cut_squares, EVIDENCE_WINDOW, free_squares,
                    split_segments, square_layout)

EVIDENCE_ROUNDS = 3
"""A batch fit with beams: iterations after convergence that each start with the free-space cut
(``free_space_cut``). A single cut after the loop left each cut square's points unexplained,
those of real structure too (a square cut where the fitted line lay off the wall); the rounds
refit what the cut leaves and seed what it took again, to be judged again. Against one cut
(window 10, hit margin 0 / 0.03), mean distance fell on Intel 2.61 -> 2.49 / 2.51 -> 2.39 cm,
CSAIL 2.95 -> 2.87 / 2.52 -> 2.43, infinite corridor 4.53 -> 4.40 / 4.37 -> 4.25 and fr079
4.48 -> 4.43 / 4.05 -> 3.94, coverage rose on all eight; 6 rounds did no better than 3."""


BIG = 1e6
"""The upper end of ``RANGES`` for quantities without a natural one."""
RANGES = {
    'sigma': (0.0, 10.0), 'range_noise': (0.0, 1.0), 'sigma_min': (0.0, 10.0),
    'sigma_start': (0.0, 100.0), 'shrink_fast': (0.0, 1.0), 'shrink_slow': (0.0, 1.0),
    'kappa': (0.0, 100.0), 'r_over_sigma': (0.1, 100.0), 'split_fraction': (0.0, 1.0),
    'gap_p': (0.0, 1.0), 'merge_theta_ref': (0.0, 180.0), 'merge_threshold': (0.0, BIG),
    'merge_reach': (0.0, 1000.0), 'min_support': (2.0, BIG), 'min_density': (0.0, BIG),
    'tail_fraction': (0.0, 1.0), 'seed_cell': (0.0, 1000.0), 'seed_thickness': (0.0, 1000.0),
    'max_iterations': (1, 100000), 'tol': (0.0, 1.0), 'noise_radius': (0.0, 100.0),
    'join_over_r': (0.0, 1000.0), 'init_count': (1, 100000), 'seed': (0, 2 ** 31 - 1),
}
"""
Closed hull (lo, hi) of each number ``SMEMSFConfig`` accepts: its checks refuse what lies
outside, then apply the exact rules (kappa > 0 ...). The node's parameter descriptors show them
(``params.CORE_RANGES``). Before 2026-12-02 only the node and the command line held to the upper
ends: kappa 1e300 failed deep in the fit on an OverflowError, r_over_sigma 1e-300 on a negative
count (an API audit; r below a tenth of sigma has no use: LSS squares of 0.2 sigma).
"""


def check_in_ranges(config, ranges: dict, integers=()) -> None:
    """
    Raise ValueError naming the first field of ``config`` that is not a number in its range.

    ``ranges``: name -> (lo, hi), closed; None passes (an optional field). Fields in
    ``integers`` must be whole numbers (a whole float, 20.0 from a YAML file, becomes an int).
    """
    for name, (lo, hi) in ranges.items():
        v = getattr(config, name)
        if v is None:
            continue
        kind = 'an integer' if name in integers else 'a finite number'
        if not (is_number(v) and lo <= v <= hi) or name in integers and int(v) != v:
            raise ValueError(f'{name} must be {kind} in [{lo!r}, {hi!r}], got {v!r}')
        if name in integers:
            setattr(config, name, int(v))


@dataclass
class SMEMSFConfig:
    """
    Every tunable of the batch and incremental fit, with units and defaults.

    Lengths are metres, angles degrees, everything else dimensionless.
    """

    sigma: Optional[float] = None
    """Sensor noise (m). None or 0: estimated from the points (local PCA thickness)."""
    range_noise: float = 0.0
    """The laser's range error that grows with the range, as a share of it (0.01: 1 cm at 1 m).
    A point at range d then has the noise scale hypot(sigma, range_noise x d), and its E-step
    kernel and cut-off (kappa times that) follow it, so the far, noisy returns of a cheap lidar
    support their wall instead of seeding stubs across it. Needs the beams' origins (replay,
    the node, ``fit`` with origins); 0: one noise scale for all points."""
    sigma_min: float = 0.005
    """Lower bound of the noise scale (m); below it registration error dominates any laser."""
    sigma_start: Optional[float] = None
    """First noise scale (m). None or 0: 1/20 of the bounding-box diagonal."""
    shrink_fast: float = 0.6
    """Sigma never shrinks faster than this factor per iteration."""
    shrink_slow: float = 0.8
    """Sigma shrinks at least by this factor per iteration until it reaches its floor."""
    kappa: float = 3.0
    """E-step cut-off in sigmas; the outlier class has the kernel density at the cut-off."""
    r_over_sigma: float = 2.5
    """LSS half-size r in sigmas (sub-segments are 2r long, squares 2r wide; +-2.5 sigma holds
    99% of a wall's Gaussian spread)."""
    split_fraction: float = 0.1
    """LSS threshold C_j as a fraction of segment j's typical sub-segment support."""
    gap_p: float = 1e-3
    """A run of low squares is a gap when this unlikely under the segment's own density."""
    merge_theta_ref: float = 10.0
    """Angle (deg) at which the parallelism term reaches 1."""
    merge_threshold: float = 1.0
    """Pairs with grouping cost below this merge."""
    merge_reach: float = 4.0
    """Segments closer than merge_reach * r are merge candidates."""
    min_support: float = 4.0
    """A segment needs at least this much supporting point weight to survive trimming."""
    min_density: float = 1.0
    """A seed (a segment grown from points no segment explains), and in the incremental mapper
    every segment, needs on average this much point weight per 2r of its length: clutter that
    happens to line up is not a wall."""
    tail_fraction: float = 0.5
    """Trimming drops end bins (2r wide) where a segment owns less than this share of the points
    near it (0 disables: the paper's plain min/max trimming)."""
    seed_cell: float = 8.0
    """Grid cell for seeding unexplained points, in units of r."""
    seed_thickness: float = 3.0
    """A seed cell's points must lie within this many sigmas (RMS) of their line."""
    max_iterations: int = 30
    """Iteration cap."""
    tol: float = 0.01
    """Stop when the mean truncated distance changes by less than this (relative)."""
    noise_radius: float = 0.2
    """Neighbourhood radius (m) for the noise estimate."""
    join_over_r: float = 2.0
    """Polyline ends closer than join_over_r * r are joined."""
    init: str = 'diagonals'
    """Initial segments: 'diagonals' (the paper), 'single' or 'random'."""
    init_count: int = 20
    """Number of segments for init='random'."""
    seed: int = 0
    """Seed for the batch fit's random choices (noise-estimate subsample, random init). The
    incremental mapper does not use it: its noise estimates are seeded by their count, so a
    replay gives the same map whatever the seed (an API audit found the old text claiming
    "every random choice")."""

    def __post_init__(self):
        """Reject values that cannot work, naming the field and the reason."""
        for name in ('sigma', 'sigma_start'):       # 0 is "automatic" (ROS params have no None)
            if getattr(self, name) == 0:
                setattr(self, name, None)
        positive = ['sigma_min', 'kappa', 'r_over_sigma', 'gap_p', 'merge_theta_ref',
                    'merge_threshold', 'merge_reach', 'seed_cell', 'seed_thickness', 'tol',
                    'noise_radius', 'join_over_r']
        for name in positive:
            v = getattr(self, name)
            if not (is_number(v) and v > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {v!r}')
        for name in ('sigma', 'sigma_start'):
            v = getattr(self, name)
            if v is not None and not (is_number(v) and v > 0):
                raise ValueError(f'{name} must be None or a finite number > 0, got {v!r}')
            if v is not None and v > RANGES[name][1]:
                raise ValueError(f'{name} must be at most {RANGES[name][1]:g} m, got {v!r}')
        rest = {k: v for k, v in RANGES.items() if k not in ('sigma', 'sigma_start')}
        check_in_ranges(self, rest, ('max_iterations', 'init_count', 'seed'))
        for name in ('shrink_fast', 'shrink_slow'):
            v = getattr(self, name)
            if not 0 < v < 1:
                raise ValueError(f'{name} must be in (0, 1), got {v!r}')
        if self.shrink_fast > self.shrink_slow:
            raise ValueError(f'shrink_fast ({self.shrink_fast}) must be <= shrink_slow '
                             f'({self.shrink_slow})')
        if not 0 <= self.split_fraction < 1:
            raise ValueError(f'split_fraction must be in [0, 1), got {self.split_fraction!r}')
        if not self.gap_p < 1:
            raise ValueError(f'gap_p must be in (0, 1), got {self.gap_p!r}')
        # (range_noise, min_density, min_support, max_iterations, init_count: their ranges,
        # checked above, are their whole rule)
        if self.init not in ('diagonals', 'single', 'random'):
            raise ValueError(f"init must be 'diagonals', 'single' or 'random', got {self.init!r}")

    @classmethod
    def from_dict(cls, values: dict) -> 'SMEMSFConfig':
        """Build from a mapping, rejecting unknown keys by name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f'unknown config key(s): {", ".join(unknown)} '
                             f'(known: {", ".join(sorted(known))})')
        return cls(**values)

    def to_dict(self) -> dict:
        """Plain-dict form, for JSON and YAML."""
        return asdict(self)


@dataclass
class FitResult:
    """The output of a fit: the map, its polylines, and how the fit went."""

    segments: np.ndarray
    """(K, 2, 2) metres, ends joined where polylines meet."""
    support: np.ndarray
    """(K,) supporting point weight of each segment."""
    polylines: list
    """List of (M, 2) vertex arrays, metres."""
    closed: list
    """One bool per polyline."""
    iterations: int
    converged: bool
    sigma: float
    """Final noise scale (m)."""
    r: float
    """Final LSS half-size (m)."""
    seconds: float
    history: list = field(default_factory=list)
    """One dict per iteration: sigma, r, segments, mean truncated distance, merges, seeds; with
    beams, the ``EVIDENCE_ROUNDS`` iterations after convergence follow, each with the squares its
    cut took (``free_squares``)."""
    beams: int = 0
    """Beams (laser origin -> point) whose free-space evidence the fit used; 0 for bare points
    (``fit`` without ``origins``): then no square was tested against free space."""
    free_squares: int = 0
    """LSS squares (2r) cut out because more beams passed through them than ended on them."""


OUTLIER_BOX = 4.0
"""``start_box``: a bounding box this many times the diagonal of the box of the 0.5-99.5th
percentiles is set by outliers."""
OUTLIER_BOX_POINTS = 200
"""``start_box``: fewer points keep their bounding box (a percentile of a few is one point)."""


def start_box(points: np.ndarray) -> tuple:
    """
    Return the box (lo, hi) the fit starts from: the points' bounding box, unless outliers set it.

    One stray point 2.7e5 m from the rest (a UTM file with a 0, 0 row) made sigma start at
    1/20 of that diagonal: 30 iterations at most 0.6x each could not bring it down to the
    noise, and the fit stopped at 7 segments, 8 % coverage (an audit). When the bounding box's
    diagonal exceeds ``OUTLIER_BOX`` times that of the box of each axis's 0.5-99.5th
    percentile, the latter is the box; any other point set keeps its bounding box (and its
    fit, bit for bit).
    """
    lo, hi = points.min(axis=0), points.max(axis=0)
    if len(points) < OUTLIER_BOX_POINTS:
        return lo, hi
    # (order statistics, not interpolated: with 200-400 points the 0.5th percentile lay
    # between the lowest two, so one stray point still stretched the box; an audit)
    qlo = np.percentile(points, 0.5, axis=0, method='higher')
    qhi = np.percentile(points, 99.5, axis=0, method='lower')
    if np.hypot(*(hi - lo)) > OUTLIER_BOX * np.hypot(*(qhi - qlo)):
        return qlo, qhi
    return lo, hi


def initial_segments(points: np.ndarray, how: str, count: int, rng,
                     box: tuple = None) -> np.ndarray:
    """
    Make initial segments from the bounding box of the points (or ``box``: (lo, hi)).

    'diagonals': its two diagonals (the paper); 'single': one segment along the longer axis
    through the centre; 'random': ``count`` segments with ends drawn uniformly in the box.
    """
    lo, hi = (points.min(axis=0), points.max(axis=0)) if box is None else box
    if how == 'diagonals':
        return np.array([[lo, hi], [[lo[0], hi[1]], [hi[0], lo[1]]]])
    if how == 'single':
        c = 0.5 * (lo + hi)
        if hi[0] - lo[0] >= hi[1] - lo[1]:
            return np.array([[[lo[0], c[1]], [hi[0], c[1]]]])
        return np.array([[[c[0], lo[1]], [c[0], hi[1]]]])
    return rng.uniform(lo, hi, size=(count, 2, 2))


def _noise_floor(points: np.ndarray, config: SMEMSFConfig, rng) -> float:
    if config.sigma is not None:
        return max(config.sigma, config.sigma_min)
    est = estimate_noise(points, radius=config.noise_radius, rng=rng)
    return max(est if np.isfinite(est) else config.sigma_min, config.sigma_min)


def range_noise_of(points: np.ndarray, origins: np.ndarray, share: float) -> np.ndarray:
    """Return each point's noise beyond sigma (m): ``share`` x its range from its origin."""
    rel = points - origins
    return share * np.hypot(rel[:, 0], rel[:, 1])


def beams_of(points: np.ndarray, origins: np.ndarray) -> np.ndarray:
    """Return each point's beam direction (N, 2): the unit vector from its origin (0 at it)."""
    rel = points - origins
    d = np.hypot(rel[:, 0], rel[:, 1])
    return rel / np.where(d > 0, d, 1.0)[:, None]


def check_fit_input(points, weights=None) -> tuple:
    """Validate points (and optional weights) for fitting; raise ValueError saying why."""
    pts = as_points(points)
    if len(pts) < 2:
        raise ValueError(f'need at least 2 points to fit segments, got {len(pts)}')
    if weights is not None:
        try:
            weights = np.asarray(weights, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            kind = type(weights).__name__
            raise ValueError(f'weights must be {len(pts)} finite values >= 0; a {kind} of them '
                             'does not convert to numbers') from exc
        if weights.shape != (len(pts),) or not np.isfinite(weights).all() or (weights < 0).any():
            raise ValueError(f'weights must be {len(pts)} finite values >= 0')
    span = pts.max(axis=0) - pts.min(axis=0)
    if not np.hypot(*span) > 0:
        raise ValueError('all points are identical; there is no line to fit')
    return pts, weights


def smemsf_iteration(index: PointIndex, segments: np.ndarray, sigma: float,
                     config: SMEMSFConfig, incremental: bool = False) -> tuple:
    """
    One SMEMSF iteration at noise scale ``sigma`` (seed, EMSF, LSS, EMSF, merge).

    Seeds always need ``config.min_density``. Trimming asks it of every segment only in an
    ``incremental`` update: there one iteration on a few scans (and the old map as virtual
    points) decides what enters the map for good, and without the test the incremental maps
    got worse (fr079 3.71 -> 3.79 cm, Intel 2.58 -> 2.66 cm). A batch fit iterates coarse to
    fine and LSS's gap test, which measures each segment against its own density, cuts walls
    where support thins out; a fixed density per 2r there dropped real walls whose points lie
    wider apart than the noise band (at 0.5 cm noise 2r is 2.5 cm: two box faces of the
    simulated clutter room, 0.8 m with 22 points and 0.6 m with 16).

    Returns
    -------
    segments : (K', 2, 2), support : (K',), info : dict with r, residual scale, mean truncated
    distance, seeds and merges.

    """
    r = config.r_over_sigma * sigma
    trim_density = config.min_density if incremental else 0.0
    segments, _, est = emsf_step(index, segments, sigma, config.kappa, config.min_support,
                                 trim_density, r)
    covered = np.zeros(len(index), dtype=bool)
    covered[est.pairs.pt] = True
    free = ~covered
    seeds = seed_segments(np.compress(free, index.points, axis=0), index.weights.compress(free),
                          config.seed_cell * r, config.min_support, config.min_density, r,
                          config.seed_thickness * sigma)
    segments = np.concatenate([segments, seeds])
    # The second E-step's pairs come from LSS's query, widened to reach them: a piece lies on
    # its parent's line, so a point within kappa sigma of a piece extended by e is within
    # kappa sigma + e of the parent (one k-d tree query fewer per iteration).
    extend = extend_for(index, r, sigma)
    rho = config.kappa * index.widest(sigma)
    segments, parent, parent_pairs, start = split_segments(
        index, segments, r, config.split_fraction, config.gap_p, query_radius=rho + extend,
        return_pairs=True)
    piece_len = lengths(segments)
    pairs = piece_pairs(parent_pairs, parent, start - extend, piece_len + 2.0 * extend, rho)
    segments, support, est = emsf_step(index, segments, sigma, config.kappa, config.min_support,
                                       trim_density, r, config.tail_fraction, pairs=pairs)
    segments, support, merges = merge_segments(
        index, segments, support, sigma, r, np.deg2rad(config.merge_theta_ref),
        config.merge_threshold, config.merge_reach * r, config.split_fraction, config.gap_p)
    # Residuals of supported points (to their MAP segment) and the truncated nearest distance;
    # a point of its own noise (``PointIndex.extra``) in units of it, times sigma.
    cap = config.kappa * sigma
    nearest = np.full(len(index), cap)
    if len(est.pairs.pt):
        dist = est.pairs.dist
        noisy = index.sigmas(sigma)
        if noisy is not None:
            dist = dist * (sigma / noisy.take(est.pairs.pt))
        np.minimum.at(nearest, est.pairs.pt, dist)
    sup = est.support >= 0
    sup[index.n_real:] = False                 # virtual points sit on their segments exactly
    resid = nearest.compress(sup)
    scale = 1.4826 * median(resid) if resid.size else sigma
    w = index.weights[:index.n_real]
    mean = float(np.sum(w * nearest[:index.n_real]) / max(np.sum(w), 1e-300))
    info = {'r': r, 'residual_scale': scale, 'seeds': int(len(seeds)), 'merges': int(merges),
            'mean_truncated': mean}
    return segments, support, info


def free_space_cut(segments: np.ndarray, support: np.ndarray, points: np.ndarray,
                   origins: np.ndarray, r: float, tol: float, min_support: float,
                   window: float = EVIDENCE_WINDOW, hit_margin: float = 0.0) -> tuple:
    """
    Cut out the LSS squares of ``segments`` that the beams see through (batch free space).

    Every beam (``origins[i]`` -> ``points[i]``, one run of equal origins per scan, in the
    order of the recording) is counted per 2r square as a hit or a pass
    (``cleanup.beam_evidence``, noise margin ``tol`` plus 3 % of the range; ``hit_margin`` > 0
    counts as hits the returns within ``tol`` + ``hit_margin`` x range of the line, as the
    incremental mapper's ``free_space_hit_margin``), scan after scan
    into decaying, capped counts exactly as the incremental mapper does
    (``split.accumulate_evidence`` over ``window`` looks, ``split.EVIDENCE_WINDOW`` unless
    given), so the map shows the scene as the recording leaves it: a door seen shut and later
    open is open. Squares whose
    passes outweigh their hits are removed (``split.free_squares``, ``split.cut_squares``).
    Pieces keep their share of the support and need ``min_support``. Returns (segments,
    support, squares cut).
    """
    if len(segments) == 0:
        return segments, support, 0
    n_sub, _ = square_layout(segments, r)
    counts = np.zeros((int(n_sub.sum()), 2))
    for a, b, o in origin_runs(origins):
        hits, passes = beam_evidence(segments, n_sub, o, points[a:b], tol,
                                     hit_range_tol=hit_margin or None)
        counts = accumulate_evidence(counts, hits, passes, window)
    free = free_squares(counts)
    if not free.any():
        return segments, support, 0
    pieces, parent, _, _ = cut_squares(segments, n_sub, ~free)
    share = lengths(pieces) / np.maximum(lengths(segments)[parent], 1e-12)
    sup = support[parent] * share
    keep = sup >= min_support
    return pieces[keep], sup[keep], int(free.sum())


def fit(points, config: SMEMSFConfig = None, init=None, weights=None,
        progress: Callable = None, origins=None,
        free_space_window: int = EVIDENCE_WINDOW,
        free_space_hit_margin: float = 0.0) -> FitResult:
    """
    Fit a segment map to 2D points with SMEMSF.

    Parameters
    ----------
    points : (N, 2) array_like
        Metres. Order is not used.
    config : SMEMSFConfig
        Default values when None.
    init : (K, 2, 2) array_like
        Initial segments; None uses ``config.init``.
    weights : (N,) array_like
        Point multiplicities (default 1).
    progress : callable
        ``progress(iteration, info)`` is called after each iteration.
    origins : (N, 2) array_like
        Where the laser was for each point (fixed frame, metres), for free-space evidence:
        once the fit has converged, squares that more beams pass through than end on are cut
        out (``free_space_cut``: doorways, people's tracks, things moved during the recording),
        and ``EVIDENCE_ROUNDS`` more iterations each start with that cut, so what the cut
        leaves is refit and what it took is seeded again and judged again; a last cut ends
        the fit. With ``config.range_noise``, the ranges set each point's noise scale too.
        None (bare points): nothing changes, and ``FitResult.beams`` is 0. A run of equal
        consecutive rows is one look (one scan): give each scan's points its one laser
        position, as ``MappingSession.origins`` and ``SimulatedDrive.origins(per_beam=False)``
        do. An origin per beam (a moving sensor's) makes every beam a look: the evidence decays
        beam by beam, and the fit is about 20 times slower (test_range_noise's two fits of 42k
        points: 36 s against 1.7 s).
    free_space_window : int
        With ``origins``: the looks at a square over which its evidence decays (>= 1; the
        incremental mapper's ``free_space_window``), by default ``split.EVIDENCE_WINDOW``; 0:
        no evidence (the origins then only give ``config.range_noise`` its ranges).
    free_space_hit_margin : float
        With ``origins``: the incremental mapper's ``free_space_hit_margin`` (>= 0; 0, the
        default, counts only crossing beams as a square's hits).

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        On invalid points, weights, init or config.

    Examples
    --------
    Two walls meeting at a corner, 200 points each with 1 cm noise:

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> t = rng.uniform(0.0, 1.0, 200)
    >>> points = np.concatenate([np.c_[4 * t, rng.normal(0, 0.01, 200)],
    ...                          np.c_[4 + rng.normal(0, 0.01, 200), 3 * t]])
    >>> result = fit(points)
    >>> len(result.segments), len(result.support), result.closed
    (2, 2, [False])
    >>> (result.polylines[0].round(1) + 0.0).tolist()     # metres, the corner joined
    [[4.0, 3.0], [4.0, 0.0], [0.0, 0.0]]

    """
    t0 = time.perf_counter()
    config = config_of(config, SMEMSFConfig)
    pts, weights = check_fit_input(points, weights)
    origins = as_origins(origins, len(pts))
    if not isinstance(free_space_window, (int, np.integer)) or isinstance(free_space_window,
                                                                          (bool, np.bool_)):
        raise TypeError(f'free_space_window must be an integer, got {free_space_window!r}')
    if not is_real(free_space_hit_margin):              # (NaN, inf: the ValueError below)
        raise TypeError('free_space_hit_margin must be a finite number >= 0, got '
                        f'{free_space_hit_margin!r}')
    if origins is not None and not (free_space_window >= 1 or free_space_window == 0):
        raise ValueError(f'free_space_window must be >= 1 (or 0: no evidence) with origins, '
                         f'got {free_space_window!r}')
    evidence = origins is not None and free_space_window >= 1
    if not (np.isfinite(free_space_hit_margin) and free_space_hit_margin >= 0):
        raise ValueError('free_space_hit_margin must be a finite number >= 0, got '
                         f'{free_space_hit_margin!r}')
    rng = np.random.default_rng(config.seed)
    extra = (range_noise_of(pts, origins, config.range_noise)
             if origins is not None and config.range_noise else None)
    # No beams (``PointIndex.beams``): trimming by each point's error along the line needs the
    # incremental mapper's growth (``emsf.extend_for``); here it pulled the pieces LSS split
    # apart, and merging left them apart (one stub more on the corridor loop of
    # test_range_noise, clutter walls F1 1.00 -> 0.96-0.98).
    index = PointIndex(pts, weights, extra=extra)
    floor = _noise_floor(pts, config, rng)
    box = start_box(pts)
    diag = float(np.hypot(*(box[1] - box[0])))
    sigma = max(config.sigma_start or diag / 20.0, floor)
    segments = (initial_segments(pts, config.init, config.init_count, rng, box) if init is None
                else as_segments(init, 'init'))
    history = []
    converged = False
    prev = None
    it = 0
    for it in range(1, int(config.max_iterations) + 1):
        at_floor = sigma <= floor * (1 + 1e-9)
        segments, support, info = smemsf_iteration(index, segments, sigma, config)
        info.update(iteration=it, sigma=sigma, segments=int(len(segments)))
        history.append(info)
        if progress is not None:
            progress(it, info)
        cur = info['mean_truncated']
        if at_floor and prev is not None and abs(cur - prev) <= config.tol * max(prev, 1e-12):
            converged = True
            break
        prev = cur if at_floor else None
        target = min(config.shrink_slow * sigma, max(config.shrink_fast * sigma,
                                                     info['residual_scale']))
        sigma = max(floor, target)
    r = config.r_over_sigma * sigma
    cut = 0
    if evidence:
        def cut_free(segments, support):
            return free_space_cut(segments, support, pts, origins, r, config.kappa * sigma,
                                  config.min_support, free_space_window, free_space_hit_margin)
        for k in range(1, EVIDENCE_ROUNDS + 1):
            segments, support, cut = cut_free(segments, support)
            segments, support, info = smemsf_iteration(index, segments, sigma, config)
            info.update(iteration=it + k, sigma=sigma, segments=int(len(segments)),
                        free_squares=cut)
            history.append(info)
            if progress is not None:
                progress(it + k, info)
    segments, support, _ = emsf_step(index, segments, sigma, config.kappa, config.min_support,
                                     0.0, r, config.tail_fraction)
    if evidence:
        segments, support, cut = cut_free(segments, support)
    # Pieces the refit made collinear are joined before chaining.
    segments, support, _ = merge_segments(
        index, segments, support, sigma, r, np.deg2rad(config.merge_theta_ref),
        config.merge_threshold, config.merge_reach * r, config.split_fraction, config.gap_p)
    geo = map_geometry(segments, support, sigma, r, config.kappa, config.join_over_r * r)
    return FitResult(segments=geo.segments, support=geo.support, polylines=geo.polylines,
                     closed=geo.closed, iterations=it, converged=converged, sigma=sigma, r=r,
                     seconds=time.perf_counter() - t0, history=history,
                     beams=len(pts) if evidence else 0, free_squares=cut)
