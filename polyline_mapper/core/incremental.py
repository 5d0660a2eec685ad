"""
Incremental SMEMSF: the map G(t) plus the points of the last few scans give G(t+1).

How G(t) takes part in EM without its old points (method.md leaves this open): every segment near
the new points is represented by *virtual points* sampled along it every 2r metres (one per LSS
square), each weighing the segment's past support per sample, capped at ``virtual_cap``. Virtual
points

- hold an old wall in place: the M-step's weighted regression sees them like real points, so new
  points move a wall only as far as their weight against its history allows, and consistent new
  evidence wins after a few scans because the cap bounds the history;
- keep the old extent: trimming, LSS and the merge gap test count them, so a long wall seen only in
  part by the new scans is neither shortened nor split;
- need no bookkeeping through split and merge (sufficient statistics would have to be divided
  between pieces).

Only the part of the map near the new points is refit: a grid hash over the segments
(``index.SegmentGrid``, cells updated only for the segments that change) gives candidates, and a
finer cell test over the buffer's points (``index.near_points``) keeps the *active* ones, those
within ``REFIT_REACH`` (2) reaches of a point, where the reach is the merge reach plus kappa sigma
plus ``margin``. So a wall seen again after a loop meets its old segments in the same fit, and
merging examines every pair of the active set, as batch does, so they join instead of doubling.
Segments outside stay exactly as they are. Memory is the map plus the buffer of the points of
the last ``buffer_scans`` updates: no point is kept longer.

Free-space clearing (``clear_max_length``): a segment in the map keeps itself alive through its
virtual points, so a person who stood still for a few scans, or a door since opened, would stay in
the map for good. After each update, the new scan's beams are traced through the short segments (up
to ``clear_max_length``, 0.9 m: a person, a chair, a door leaf) near them; a segment that beams
pass through over much of its length, with returns beyond it, is dropped
(``cleanup.seen_through``). Long walls are never cleared: a wall the scanner seems to see through
is more likely a registration error or glass. The limit is a length in metres, not in units of r,
since what it is for has a size of its own: at 16 r it was 0.45 m on fr079 but 1.5 m on the campus
log (r = 9.4 cm), where it cleared hedges and the sides of parked cars. Refitting only near the new
points makes this necessary: with a wider refit, clutter wore away slowly under the fit of its
neighbours, by accident rather than by evidence.

The noise scale sigma is ``SMEMSFConfig.sigma`` when given (then fixed). Otherwise it starts from
the local thickness of the first scans and then follows the scan-to-map spread: after every update
the robust residual scale (1.4826 x median distance) of the new points the map explains feeds a
running median over the last ``sigma_window`` updates, never below the first estimate (a single
scan's thickness is the range noise; registration error can only add to it). A map built from many
scans is as thick as their registration error; with sigma too small a wall seen again a few
centimetres off would be doubled. The running median has that spread as its fixed point: when sigma
is too small the truncated residuals look uniform and their scale is about 2 sigma, so sigma grows;
when it is large enough the scale is the spread itself. Each update runs ``iterations`` SMEMSF
iterations.

The LSS half-size r is ``r_over_sigma`` x sigma as in batch, but the square side 2r is never below
the spacing of one scan's points (the upper quartile of each scan's nearest-neighbour distances,
running median over ``sigma_window`` scans). Batch sees every scan at once; the mapper sees a
window of a few, and with a sparse scanner (1 degree between beams: 5-9 cm between points on a wall
3-5 m away) and low noise, squares of 2r = 5 sigma hold no point on most of a real wall, so the
density tests of trimming, seeding and LSS chop it into fragments.

Far returns: readings at or beyond ``max_mapping_range`` (100 m) are dropped before anything
else (``update_scan``, and ``update`` with an origin), so a scan with range_max = inf and far
junk maps as if those beams were invalid. Before this, 30 % of beams at 1e4 m made r follow their
87 m spacing from 3 cm to 44 m: updates took seconds and GBs and the map got walls 175 m long.
Every allocation of an update is bounded by the points kept (each scan thinned to
``max_scan_points``), the map near them and fixed block sizes (``index.DILATE_BUDGET``,
``cleanup.PAIR_BUDGET``), not by how far the points lie.

Free-space evidence (``free_space_window`` > 0; on by default with the poses given, off with
scan matching, ``IncrementalConfig.resolved``; 0 turns it off): the beams of every scan are
counted per LSS square (2r) of the segments near them, hits (the beam ends on the square) and
passes (it goes through beyond the noise margin of ``cleanup.beam_evidence``), as decaying,
capped counts that live beside the segments (one run of rows per segment in one pool array,
``_store``, so that a group of segments' counts is gathered and written back at once) and follow
them through refits, splits and merges (``split.carry_evidence``). Squares whose passes outweigh
their hits are cut out (``split.free_squares``, ``split.cut_squares``), whatever the segment's
length: a doorway splits a wall, a door that opened, a box carried away, a person's track go.
When on it replaces ``clear_max_length``. The state is bounded by the map: one pair of counts per
square of a live segment (and, with ``free_space_memory``, the cells the beams went through,
``memory.BeamMemory``).

A short chord across a corner, once in the map, is kept alive by its own virtual points; it is
dropped when the new points near it all lie on the two longer walls whose corner it cuts
(``cleanup.corner_chords``).
"""

from collections import deque
from dataclasses import dataclass, field, replace
import time
from typing import Optional

import numpy as np

from .cleanup import as_origins, beam_evidence, corner_chords, origin_runs, seen_through
from .geometry import (as_points, config_of, in_box, is_number, is_real, lengths,
                       sample_segments)
from .index import near_points, PointIndex, SegmentGrid
from .memory import BeamMemory, clearly_free
from .noise import estimate_noise, median, scan_spacing
from .polylines import map_geometry, MapGeometry
from .smemsf import (beams_of, BIG, check_in_ranges, range_noise_of, smemsf_iteration,
                     SMEMSFConfig)
from .split import (accumulate_evidence, carry_evidence, cut_squares, free_squares,
                    square_centres, square_layout)
from ..scan import scan_to_points


REFIT_REACH = 2.0
"""Segments within this many merge reaches of a point of the buffer are refit in an update."""

SPACING_RANGE_SHARE = 0.02
"""A scan's spacing (so 2r) is at most this share of ``max_mapping_range``: 2 m at 100 m, the
spacing of beams 1.15 degrees apart at that range. The shared logs' running spacing stays below
0.7 m (campus)."""

COORD_LIMIT = 1e7
"""Points must lie within this many metres of the fixed frame's origin (cell keys hold 2**30
cells a side, 1 cm cells included)."""

LOAD_LENGTH_LIMIT = 1e5
"""A map given to ``load`` holds at most this many metres of segments (100 km; the Freiburg
campus map has about 6000 segments). Matching samples the segments near a scan every few
centimetres, so one segment of 2e7 m (coordinates within the limits) asked for 23 GB."""

LOAD_CELL_SEGMENTS, LOAD_CELL_LENGTH = 200, 50.0
"""A map given to ``load`` has at most this many segments, and this many metres of them, in any
1 m square (``crowding``). The maps of the shared logs, replayed and batch, have at most 12
segments and 6.4 m in one (fr079). Every segment near a scan takes part in its E-step with its
support, so the work grows with the square of how many pile up in one place: a saved map with
20000 segments in 0.2 m x 0.2 m asked scipy for more memory than the machine has
(std::bad_alloc), 3000 for 4.6 GB and 33 s in one update, 200 for 0.1 GB."""


def crowding(segments: np.ndarray, cell: float = 1.0, step: float = 0.05) -> tuple:
    """
    Return the most crowded ``cell`` square of a map: (segments, metres, lower-left corner).

    The square whose count of segments reaching into it, or length of segments lying in it,
    comes nearest to (or furthest beyond) ``LOAD_CELL_SEGMENTS`` or ``LOAD_CELL_LENGTH``; its
    count and length. Lengths from samples ``step`` apart along each segment (each sample
    stands for its segment's length over its sample count). (0, 0.0, (0, 0)) for no
    segments. Vectorised; a straight segment's samples in one square are consecutive.
    """
    if len(segments) == 0:
        return 0, 0.0, (0.0, 0.0)
    samples, owner = sample_segments(segments, step)
    keys = np.clip(np.floor(samples / cell), -2.0 ** 30, 2.0 ** 30).astype(np.int64) + 2 ** 30
    code = keys[:, 0] * 2 ** 31 + keys[:, 1]
    cells, inverse = np.unique(code, return_inverse=True)
    enters = np.ones(len(code), dtype=bool)
    enters[1:] = (code[1:] != code[:-1]) | (owner[1:] != owner[:-1])
    count = np.bincount(inverse, weights=enters, minlength=len(cells))
    per = np.bincount(owner, minlength=len(segments))
    metres = np.bincount(inverse, weights=lengths(segments)[owner] / per[owner],
                         minlength=len(cells))
    top = int(np.argmax(np.maximum(count / LOAD_CELL_SEGMENTS, metres / LOAD_CELL_LENGTH)))
    corner = (cells[top] // 2 ** 31 - 2 ** 30, cells[top] % 2 ** 31 - 2 ** 30)
    return int(count[top]), float(metres[top]), tuple(float(c * cell) for c in corner)


RANGES = {
    'buffer_scans': (1, 1000), 'iterations': (1, 100), 'margin': (0.0, 100.0),
    'virtual_cap': (1e-9, BIG), 'cell': (0.01, 1000.0), 'noise_updates': (1, 10000),
    'sigma_window': (1, 100000), 'clear_max_length': (0.0, 100.0),
    'free_space_window': (-1, 100000), 'free_space_ghosts': (0, 10 ** 7),
    'free_space_hit_margin': (0.0, 1.0), 'free_space_memory': (0.0, 10.0),
    'min_mapping_range': (0.0, BIG), 'max_mapping_range': (1e-9, BIG),
    'max_scan_points': (16, 10 ** 7),
}
"""Closed hull (lo, hi) of each number ``IncrementalConfig`` accepts (as ``smemsf.RANGES``)."""
INTEGERS = ('buffer_scans', 'iterations', 'noise_updates', 'sigma_window', 'free_space_window',
            'free_space_ghosts', 'max_scan_points')


@dataclass
class IncrementalConfig:
    """Tunables of the incremental mapper (lengths in metres)."""

    buffer_scans: int = 3
    """Updates whose points take part in each update (k): the last k ``update`` calls' scans
    (k scans with the node's ``update_every_n_scans`` 1, N x k with N)."""
    iterations: int = 1
    """SMEMSF iterations per update."""
    margin: float = 0.0
    """Extra distance (m) around the new points within which segments are refit (added to the
    merge reach, which is always included)."""
    virtual_cap: float = 10.0
    """Largest weight of one virtual point (points per 2r of wall)."""
    cell: float = 2.0
    """Cell size (m) of the grid hash over the map."""
    noise_updates: int = 5
    """Updates whose thickness estimates are pooled (median) for the first sigma."""
    sigma_window: int = 50
    """Updates whose residual scales are pooled (running median) for sigma."""
    clear_max_length: float = 0.9
    """Segments up to this long (m) that the new scan's beams pass through are dropped
    (free-space clearing: people, moved chairs, opened door leaves); 0 turns clearing off. Needs
    the laser position of each scan (update_scan, replay and the node give it). Not used when
    ``free_space_window`` > 0 (the evidence per square replaces it)."""
    free_space_window: int = -1
    """Free-space evidence per LSS square (0 turns it off and ``clear_max_length`` clears
    instead; -1, the default, is ``AUTO_WINDOW`` with the poses given and 0 with scan matching,
    ``resolved``): every scan's beams are counted per 2r square of the map's segments near
    them, as hits (the beam ends on the square) and passes (it goes through, beyond the noise
    margin), decaying over about this many looks at the square and capped; squares whose
    passes outweigh their hits are removed, whatever the segment's length (doorways, opened
    doors, moved boxes, people's tracks). When on, it replaces ``clear_max_length``. Needs the
    laser position of each scan."""
    free_space_ghosts: int = 20000
    """With ``free_space_window`` > 0: the most cut squares remembered (default 20000; 0: none).
    A square cut out as free with at least twice as many passes as hits leaves a *ghost* (its
    centre, direction and counts; a marginal cut leaves none: remembering every cut held real
    structure out of the map, CSAIL 3.93 against 3.32 cm). A refit segment's new square takes
    the counts of the nearest old square or ghost (``split.carry_evidence``), so pieces that a
    refit or merge joins again across a cut gap do not bridge it with their neighbours' hits;
    the oldest ghosts go first beyond this many (memory: 48 bytes a ghost). With ghosts, a
    single square left between two cuts or beside one goes too once a beam passed through it
    (as a piece of its own its crossing window would shrink to its middle half, so a 5 cm
    sliver of a box or a person's track stayed)."""
    free_space_hit_margin: float = 0.03
    """With ``free_space_window`` > 0: 0 counts as a square's hits the beams that cross it at
    >= 20 deg and return within kappa sigma of its line; > 0 (default 0.03) counts every return
    within kappa sigma + this x its range of the line, abreast of the square, at any angle
    (``cleanup.beam_evidence``): the same margin as a pass's at 0.03. Crossing hits are so
    few that cut squares held real structure (fr079, window 10 and 20000 ghosts: 2.78 % /
    4.53 cm / 90.7 % without, 2.52 % / 3.98 cm / 92.9 % with 0.03)."""
    free_space_memory: float = 0.1
    """With ``free_space_window`` > 0: the cell size (m) of the free-space memory (default 0.1;
    0: none; at least ``MIN_MEMORY_CELL``). Every scan's beams are also counted per cell of a
    grid over the area seen (``memory.BeamMemory``: the same decaying, capped hits and passes as
    a square), and a square the map gains with no evidence to carry over starts from its cell's
    counts instead of none: a segment drawn where the laser had seen through is cut by the next
    beams."""
    min_mapping_range: float = 0.0
    """Readings closer than this (m) to the laser are not mapped, whatever the scan's range_min
    says (0: the scan's range_min alone): parts of the robot the laser sees (posts, a bumper, a
    cable) read the same range wherever the robot goes, and each is mapped as a wall along its
    whole path (sim:office with four posts of 6 deg at 0.25 m: 764 segments against 26). The
    session warns of such readings (``scan.SelfHits``, cause ``self_hits``)."""
    max_mapping_range: float = 100.0
    """Readings at or beyond this range (m) from the laser are not mapped, whatever the scan's
    range_max says: far returns set neither r, sigma nor the work of an update. The shared logs
    have no valid reading beyond 82 m."""
    max_scan_points: int = 8192
    """Most points one scan adds (or one update, for bare points without origin); a denser scan
    is thinned evenly in beam order. Bounds an update's work and memory."""
    smemsf: SMEMSFConfig = field(default_factory=SMEMSFConfig)
    """The fit parameters (sigma, r_over_sigma, merge and split thresholds ...)."""

    def __post_init__(self):
        """Reject values that cannot work, naming the field."""
        self.smemsf = config_of(self.smemsf, SMEMSFConfig, 'smemsf')
        check_in_ranges(self, RANGES, INTEGERS)
        if self.min_mapping_range >= self.max_mapping_range:
            raise ValueError(f'min_mapping_range must be below max_mapping_range '
                             f'({self.max_mapping_range:g} m), got {self.min_mapping_range!r}')
        if 0 < self.free_space_memory < MIN_MEMORY_CELL:
            raise ValueError(f'free_space_memory must be 0 (off) or a cell size >= '
                             f'{MIN_MEMORY_CELL:g} m, got {self.free_space_memory!r}')

    def resolved(self, scan_matching: bool = False) -> 'IncrementalConfig':
        """
        Return this configuration with ``free_space_window`` -1 (auto) made a number.

        ``AUTO_WINDOW`` when the poses are given (TF, odometry, a log's corrected poses), 0 when
        they come from matching the scans to the map itself: the evidence takes the poses for
        right, and where a matched pose is off it cuts the walls the beams then see through,
        which are what later matches anchor on (drifted Intel, seeds 5-14: ATE 0.152 m mean
        with it, 0.117 without; CSAIL seed 0 0.252 against 0.238 m; benchmarks/README.md).
        """
        if self.free_space_window != -1:
            return self
        return replace(self, free_space_window=0 if scan_matching else AUTO_WINDOW)


AUTO_WINDOW = 10
"""``free_space_window`` of the default (-1) when the poses are given."""


MIN_MEMORY_CELL = 0.02
"""
The smallest cell (m) of the free-space memory. Each beam is counted in every cell it crosses,
so the work and memory of a scan grow as 1 / cell: on the first 90 Intel scans 0.1 m took 1.7
s and 93 MB, 0.02 m 2.2 s and 138 MB, 0.001 m 650 MB, and 1e-6 m did not end in 120 s.
"""


@dataclass
class UpdateInfo:
    """What one update did."""

    points: int
    """Points the update took (after the range limit and thinning)."""
    active: int
    """Map segments refit."""
    segments: int
    """Segments in the map after the update."""
    seconds: float
    skipped: Optional[str] = None
    """Why the map did not change ('no valid points', 'estimating noise'), else None."""
    beyond_range: int = 0
    """Points dropped as farther than ``max_mapping_range`` from their laser, or closer than
    ``min_mapping_range``."""
    thinned: int = 0
    """Points dropped by thinning to ``max_scan_points``."""


class IncrementalMapper:
    """
    Online SMEMSF: feed scans (or point sets) one by one, read the map at any time.

    A robot drives through a 4 m x 3 m room with a 360-beam laser (1 cm range noise):

    >>> import numpy as np
    >>> angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    >>> def room_scan(x, y, w=4.0, h=3.0):       # ranges (m) from (x, y) to the room's walls
    ...     c, s = np.cos(angles), np.sin(angles)
    ...     with np.errstate(divide='ignore'):
    ...         return np.minimum(np.where(c > 0, w - x, -x) / c, np.where(s > 0, h - y, -y) / s)
    >>> rng = np.random.default_rng(0)
    >>> mapper = IncrementalMapper()
    >>> skipped = []
    >>> for x in np.linspace(1.0, 3.0, 8):
    ...     ranges = room_scan(x, 1.5) + rng.normal(0.0, 0.01, angles.size)
    ...     info = mapper.update_scan(ranges, angles, (x, 1.5, 0.0), range_max=10.0)
    ...     skipped.append(info.skipped)
    >>> skipped.count('estimating noise'), skipped[-1]    # sigma from the first 5 updates
    (4, None)
    >>> geo = mapper.polylines()
    >>> len(geo.segments), len(geo.support), geo.closed
    (4, 4, [True])
    >>> (geo.polylines[0].round(1) + 0.0).tolist()        # metres
    [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]
    """

    def __init__(self, config: IncrementalConfig = None):
        # free_space_window -1 (auto): the evidence on; a session that matches the scans
        # resolves it first (MappingSession, ``IncrementalConfig.resolved``).
        self.config = config_of(config, IncrementalConfig).resolved()
        self._seg = np.zeros((64, 2, 2))
        self._sup = np.zeros(64)
        self._alive = np.zeros(64, dtype=bool)
        # Bounding box of each slot's segment: [[min x, min y], [max x, max y]].
        self._box = np.zeros((64, 2, 2))
        self._grid = SegmentGrid(self.config.cell)
        self._buffer = deque(maxlen=int(self.config.buffer_scans))
        self._cells = deque(maxlen=int(self.config.buffer_scans))   # grid cells of each scan
        self._extra = deque(maxlen=int(self.config.buffer_scans))   # range noise of each point
        self._beams = deque(maxlen=int(self.config.buffer_scans))   # with range_noise: beams
        self._noise = []
        self._scales = deque(maxlen=int(self.config.sigma_window))
        self._spacings = deque(maxlen=int(self.config.sigma_window))
        self.sigma = self.config.smemsf.sigma
        self._sigma0 = self.sigma
        self._fit_config = None
        self.updates = 0
        # Free-space evidence: per slot of self._seg, none (start -1) or the [hits, passes] of
        # each of the segment's LSS squares in order from its first end: rows
        # _ev_at .. _ev_at + _ev_n - 1 of _pool (rows past _pool_used are free; dead rows are
        # dropped when the pool is full, ``_store``).
        self._ev_at = np.full(len(self._alive), -1, dtype=np.intp)
        self._ev_n = np.zeros(len(self._alive), dtype=np.intp)
        self._pool = np.zeros((0, 2))
        self._pool_used = 0
        # Cut squares remembered (free_space_ghosts): centre, direction, [hits, passes].
        self._ghosts = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)))
        # What the beams saw of every place (free_space_memory); ``reset`` forgets it with the map.
        self._memory = (BeamMemory(self.config.free_space_memory, self.config.free_space_window)
                        if self.config.free_space_memory > 0 and self.config.free_space_window > 0
                        else None)

    # -- the map -------------------------------------------------------------------------------
    @property
    def segments(self) -> np.ndarray:
        """Return the map's segments, (K, 2, 2) metres (a copy)."""
        return self._seg[self._alive].copy()

    @property
    def support(self) -> np.ndarray:
        """Return the accumulated, capped point weight behind each segment, shape (K,)."""
        return self._sup[self._alive].copy()

    def polylines(self) -> MapGeometry:
        """
        Return the map as published: ``MapGeometry(segments, support, polylines, closed)``.

        Short stubs inside a wall's noise band (``merge.noise_stubs``) are left out, as in a
        batch fit, from ``segments`` and ``support`` alike (``support[i]`` belongs to
        ``segments[i]``); the rest keep the order of ``self.segments``, with joined ends moved
        to their shared vertex. The stubs stay in the mapper's own map (``self.segments``),
        where later scans may still grow them.
        """
        cfg = self.config.smemsf
        r = self.r
        return map_geometry(self.segments, self.support, self.sigma, r, cfg.kappa,
                            cfg.join_over_r * r)

    def load(self, segments, support=None, sigma: float = None, r: float = None) -> None:
        """
        Replace the map by given segments (K, 2, 2) metres, e.g. a saved map to extend.

        ``support`` (K,) defaults to the cap (a loaded map is trusted like a long-seen one); NaN
        entries (a map file without support) take the cap too. ``sigma`` (m), when given, is
        the map's noise scale: mapping starts at once with it (no noise estimate from the first
        scans) and it is the floor sigma may grow from (unless the configuration fixes sigma).
        ``r`` (m), the map's LSS half-size (MAP.json's ``stats.r``), when larger than
        ``r_over_sigma`` x sigma, is taken as the scan spacing the map was made with, until new
        scans' spacings outvote it. Raises ValueError (the map unchanged) on bad segments,
        support, sigma or r, or more than LOAD_LENGTH_LIMIT metres of segments, or more
        than LOAD_CELL_SEGMENTS segments or LOAD_CELL_LENGTH metres of them in one 1 m square.
        """
        from .geometry import as_segments
        segs = as_segments(segments)
        total = float(lengths(segs).sum()) if len(segs) else 0.0
        if not total <= LOAD_LENGTH_LIMIT:
            raise ValueError(f'the map holds {total:.3g} m of segments, more than '
                             f'{LOAD_LENGTH_LIMIT:.0e} m: not a map of a building or campus '
                             '(absurd coordinates?)')
        count, metres, where = crowding(segs)
        if count > LOAD_CELL_SEGMENTS or metres > LOAD_CELL_LENGTH:
            raise ValueError(f'the map piles {count} segments ({metres:.3g} m) into the 1 m '
                             f'square at ({where[0]:g}, {where[1]:g}), more than '
                             f'{LOAD_CELL_SEGMENTS} segments or {LOAD_CELL_LENGTH:g} m: not a '
                             'map of walls')
        for name, v in (('sigma', sigma), ('r', r)):
            if v is not None and not (is_number(v) and v > 0):
                raise ValueError(f'{name} must be a finite number > 0 (m), got {v!r}')
        sup = None if support is None else np.asarray(support, dtype=np.float64)
        if sup is not None and (sup.shape != (len(segs),) or np.isinf(sup).any()
                                or np.any(sup < 0)):
            raise ValueError(f'support must be {len(segs)} finite values >= 0')
        if sigma is not None and self.config.smemsf.sigma is None:
            self.sigma = self._sigma0 = max(float(sigma), self.config.smemsf.sigma_min)
            if r is not None and r > self.config.smemsf.r_over_sigma * self.sigma:
                self._spacings.append(2.0 * float(r))
        r = self.r
        cap = self.config.virtual_cap * np.maximum(lengths(segs) / (2.0 * r), 1.0)
        sup = cap if sup is None else np.where(np.isnan(sup), cap, sup)
        self._replace(np.flatnonzero(self._alive), segs, sup)

    def reset(self) -> None:
        """
        Forget the map and the scan buffer; keep what describes the sensor.

        Kept: sigma and its floor (the first estimate), the residual scales sigma follows, the
        noise estimates pooled so far, and the scan-spacing estimate (so r). They describe the
        laser and the registration, not the map: once sigma was estimated, the next update after
        a reset maps at once, at the same sigma and r, instead of estimating the noise again.
        ``updates`` restarts at 0.
        """
        sensor = (self.sigma, self._sigma0, self._noise, self._scales, self._spacings)
        self.__init__(self.config)
        self.sigma, self._sigma0, self._noise, self._scales, self._spacings = sensor

    def nbytes(self) -> int:
        """Bytes held by the map arrays and the scan buffer."""
        return (self._seg.nbytes + self._sup.nbytes + self._alive.nbytes + self._box.nbytes
                + sum(p.nbytes for p in self._buffer) + sum(c.nbytes for c in self._cells)
                + sum(e.nbytes for e in self._extra) + sum(b.nbytes for b in self._beams)
                + self._ev_at.nbytes + self._ev_n.nbytes + self._pool.nbytes
                + sum(g.nbytes for g in self._ghosts)
                + (self._memory.nbytes if self._memory is not None else 0))

    # -- updates -------------------------------------------------------------------------------
    def update_scan(self, ranges, angles, pose, range_min: float = 0.0,
                    range_max: float = np.inf) -> UpdateInfo:
        """
        Add one laser scan: ranges (m) at angles (rad) from a laser at pose (x, y, yaw).

        NaN, inf and out-of-range readings are dropped (REP 117), and so are readings closer
        than ``min_mapping_range`` or at or beyond ``max_mapping_range`` (the range limits are
        max(range_min, min_mapping_range) and min(range_max, max_mapping_range)).
        Raises ValueError on mismatched lengths, a bad pose or range limits no LaserScan has
        (as the session's ``bad scan: range_limits``), leaving the map unchanged.
        """
        if not (is_number(range_min) and range_min >= 0 and is_real(range_max)
                and range_max > range_min):         # (inf passes, NaN does not)
            raise ValueError(f'range_min and range_max must be 0 <= range_min < range_max, got '
                             f'{range_min!r} and {range_max!r}')
        low = max(float(range_min), self.config.min_mapping_range)
        top = min(float(range_max), self.config.max_mapping_range)
        return self.update(scan_to_points(ranges, angles, pose, low, top),
                           ordered=True, origin=np.asarray(pose, dtype=np.float64)[:2])

    def update(self, points, ordered: bool = False, origin=None) -> UpdateInfo:
        """
        Add the points of one scan (N, 2, fixed frame, metres) and refit the map near them.

        ``ordered``: the points are in beam order (as ``scan_to_points`` returns them, or such
        runs concatenated), so a point's nearest neighbour in its scan is the one before or after
        it; the point spacing is then read off in order instead of from a k-d tree.

        ``origin``: where the laser was, fixed frame, metres: (2,) for one scan, or (N, 2), one
        row per point, for the points of several scans. With it, the beams clear the short
        segments they pass through (``IncrementalConfig.clear_max_length``); without it (bare
        points) nothing is cleared.

        Bounds, whatever the points hold: points at or beyond ``max_mapping_range`` from their
        origin are dropped before anything else (with origin); each scan (each run of one
        origin, or the whole call for bare points) is thinned evenly to ``max_scan_points``; a
        scan's spacing, hence r, is robust to a minority of far points (``noise.scan_spacing``)
        and at most ``SPACING_RANGE_SHARE`` x ``max_mapping_range``. The work and memory of an
        update then grow with the points kept (at most ``buffer_scans`` x ``max_scan_points``
        per scan grouped) and the map near them, not with how far the points lie.

        An empty point set changes nothing. Raises ValueError on NaN / inf / wrong shapes, or
        points farther than ``COORD_LIMIT`` from the frame's origin, leaving the map unchanged.
        """
        t0 = time.perf_counter()
        pts = as_points(points) if np.size(points) else np.zeros((0, 2))    # ([] too)
        origins = as_origins(origin, len(pts))
        pts, origins, beyond = self._in_range(pts, origins)
        if len(pts) and np.abs(pts).max() > COORD_LIMIT:
            raise ValueError(f'points lie up to {np.abs(pts).max():.3g} m from the frame origin; '
                             f'the mapper holds coordinates within {COORD_LIMIT:.0e} m')
        pts, origins, thinned = self._thin(pts, origins)
        views = origin_runs(origins)
        if len(pts) == 0:
            return UpdateInfo(0, 0, int(self._alive.sum()), 0.0, skipped='no valid points',
                              beyond_range=beyond)
        self._buffer.append(pts)
        self._cells.append(self._grid.cells(pts))
        self._extra.append(self._range_noise(pts, origins))
        self._beams.append(self._beam_directions(pts, origins))
        self._note_spacing(pts, ordered)
        window = np.concatenate(self._buffer)
        if not self._sigma_ready(window):
            return UpdateInfo(len(pts), 0, int(self._alive.sum()), time.perf_counter() - t0,
                              'estimating noise', beyond, thinned)
        sigma = self.sigma
        r = self.r
        cfg = self._config_for(r, sigma)
        reach = cfg.merge_reach * r + cfg.kappa * sigma + self.config.margin
        active = self._grid.near(window, REFIT_REACH * reach,
                                 np.unique(np.concatenate(self._cells)))
        active = active[self._alive[active]]
        active = active[near_points(window, self._seg[active], REFIT_REACH * reach)]
        old = self._seg[active]
        virt, vw = self._virtual_points(old, self._sup[active], r)
        extra = np.concatenate(self._extra)
        index = PointIndex(np.concatenate([window, virt]),
                           np.concatenate([np.ones(len(window)), vw]), virtual=len(virt),
                           sample_spacing=8.0,
                           extra=np.concatenate([extra, np.zeros(len(virt))]) if extra.any()
                           else None,
                           beams=np.concatenate([*self._beams, np.zeros((len(virt), 2))])
                           if self.config.smemsf.range_noise else None)
        segs = old
        for _ in range(int(self.config.iterations)):
            segs, sup, info = smemsf_iteration(index, segs, sigma, cfg, incremental=True)
        # A short chord across a corner (e.g. a T-junction seen from few angles) is kept alive by
        # its own virtual points; the new points decide whether the walls explain it.
        keep = ~corner_chords(index, segs, cfg.kappa * sigma, 2.0 * sigma, 8.0 * r,
                              np.deg2rad(20.0))
        segs, sup = segs[keep], sup[keep]
        if self.config.free_space_window > 0:
            # Free-space evidence per square: the beams of the new scan(s) against the refit
            # segments and the others they reach; squares seen through are cut out.
            self._free_space(active, segs, sup, views, pts, r, cfg.kappa * sigma)
        # Free-space clearing: a short segment the new scan sees through is gone.
        elif self.config.clear_max_length > 0:
            short = lengths(segs) <= self.config.clear_max_length
            for lo, hi, o in views:
                if short.any():
                    gone = short & seen_through(segs, o, pts[lo:hi], cfg.kappa * sigma)
                    segs, sup, short = segs[~gone], sup[~gone], short[~gone]
        if cfg.sigma is None and np.isfinite(info['residual_scale']):
            self._scales.append(info['residual_scale'])
            self.sigma = max(median(self._scales), self._sigma0)
        if self.config.free_space_window <= 0:
            cap = self.config.virtual_cap * np.maximum(lengths(segs) / (2.0 * r), 1.0)
            self._replace(active, segs, np.minimum(sup, cap))
        self.updates += 1
        return UpdateInfo(len(pts), int(active.size), int(self._alive.sum()),
                          time.perf_counter() - t0, None, beyond, thinned)

    @property
    def r(self) -> float:
        """
        Return the LSS half-size in metres.

        That is ``r_over_sigma`` x sigma, but the square side 2r is never below the point
        spacing of a scan: the running median, over the last ``sigma_window`` scans, of the
        upper quartile of each scan's nearest-neighbour distances (``noise.scan_spacing``: of
        its dense part when far points make a tail, at most 24 x the lower quartile and
        ``SPACING_RANGE_SHARE`` x ``max_mapping_range``).
        """
        cfg = self.config.smemsf
        r = cfg.r_over_sigma * (self.sigma or cfg.sigma_min)
        if self._spacings:
            r = max(r, 0.5 * median(self._spacings))
        return r

    # -- internals -----------------------------------------------------------------------------
    def _in_range(self, pts: np.ndarray, origins) -> tuple:
        """
        Drop points outside [min_mapping_range, max_mapping_range) from their origin.

        Returns (pts, origins, n dropped).
        """
        if origins is None or len(pts) == 0:
            return pts, origins, 0
        rel = pts - origins
        d = np.hypot(rel[:, 0], rel[:, 1])
        keep = (d < self.config.max_mapping_range) & (d >= self.config.min_mapping_range)
        if keep.all():
            return pts, origins, 0
        return pts[keep], origins[keep], int(keep.size - np.count_nonzero(keep))

    def _range_noise(self, pts: np.ndarray, origins) -> np.ndarray:
        """Return each point's noise beyond sigma (m): ``range_noise`` x its range (0 bare)."""
        share = self.config.smemsf.range_noise
        if origins is None or not share:
            return np.zeros(len(pts))
        return range_noise_of(pts, origins, share)

    def _beam_directions(self, pts: np.ndarray, origins) -> np.ndarray:
        """
        Return each point's beam direction (``PointIndex.beams``; 0 bare), with range noise only.

        Trimming each end by its points' errors along the wall (``emsf.END_SIGMAS``) is part of
        the range-noise model (``SMEMSFConfig.range_noise`` > 0): without it, no beams (an empty
        array per scan), so the maps stay exactly those of the plain sigma model.
        """
        if not self.config.smemsf.range_noise:
            return np.zeros((0, 2))
        if origins is None:
            return np.zeros((len(pts), 2))
        return beams_of(pts, origins)

    def _thin(self, pts: np.ndarray, origins) -> tuple:
        """Thin each run of one origin to ``max_scan_points`` (every k-th point, in order)."""
        most = int(self.config.max_scan_points)
        runs = origin_runs(origins) if origins is not None else [(0, len(pts), None)]
        if all(b - a <= most for a, b, _ in runs):
            return pts, origins, 0
        keep = np.concatenate([np.arange(a, b, max(1, -(-(b - a) // most))) for a, b, _ in runs])
        return (pts[keep], None if origins is None else origins[keep],
                int(len(pts) - keep.size))

    def _note_spacing(self, pts: np.ndarray, ordered: bool = False) -> None:
        """Pool one scan's point spacing (``noise.scan_spacing``)."""
        spacing = scan_spacing(pts, ordered,
                               SPACING_RANGE_SHARE * self.config.max_mapping_range)
        if np.isfinite(spacing):
            self._spacings.append(spacing)

    def _config_for(self, r: float, sigma: float) -> SMEMSFConfig:
        cfg = self.config.smemsf
        ratio = r / sigma
        if ratio == cfg.r_over_sigma:
            return cfg
        if self._fit_config is None or self._fit_config.r_over_sigma != ratio:
            self._fit_config = replace(cfg, r_over_sigma=ratio)
        return self._fit_config

    def _sigma_ready(self, window: np.ndarray) -> bool:
        if self.sigma is not None:
            return True
        cfg = self.config.smemsf
        est = estimate_noise(window, radius=cfg.noise_radius, rng=len(self._noise))
        if np.isfinite(est):
            self._noise.append(est)
        if len(self._noise) >= self.config.noise_updates:
            self.sigma = self._sigma0 = max(float(np.median(self._noise)), cfg.sigma_min)
            return True
        return False

    def _virtual_points(self, segs: np.ndarray, sup: np.ndarray, r: float) -> tuple:
        if len(segs) == 0:
            return np.zeros((0, 2)), np.zeros(0)
        pts, owner = sample_segments(segs, 2.0 * r)
        per = np.bincount(owner, minlength=len(segs))
        w = np.minimum(sup / per, self.config.virtual_cap)
        return pts, w[owner]

    def _free_space(self, active: np.ndarray, segs: np.ndarray, sup: np.ndarray, views: list,
                    pts: np.ndarray, r: float, tol: float) -> None:
        """
        Count the new beams per square, cut free squares, and put the result in the map.

        The group is the refit segments (replacing ``active``) plus, with beams, every other
        segment whose bounding box meets that of the scan (its points and laser positions).
        The refit segments' squares take over the evidence of the old squares
        (``split.carry_evidence``); the others keep theirs (resampled when r changed their
        layout). All add each scan's hits and passes (``cleanup.beam_evidence``,
        ``split.accumulate_evidence``) and lose the squares seen through
        (``split.free_squares``, ``split.cut_squares``). Other segments that lost no square keep
        their slot; the refit ones and the others that lost squares are replaced by pieces.
        """
        others = np.zeros(0, dtype=np.intp)
        if views:
            corners = np.concatenate([pts, np.array([o for _, _, o in views])])
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            box = self._alive & in_box(self._box, lo, hi)     # each slot's box, kept
            box[active] = False
            others = np.flatnonzero(box)
        n_new = len(segs)
        group = np.concatenate([segs, self._seg[others]])
        gsup = np.concatenate([sup, self._sup[others]])
        n_sub, _ = square_layout(group, r)
        k_new = int(n_sub[:n_new].sum())
        counts = np.zeros((int(n_sub.sum()), 2))
        at, num, pool = self._ev_at, self._ev_n, self._pool
        # The refit segments take over the old squares' evidence (moved, split, merged).
        old = active[at[active] >= 0]
        gc, gu, gn = self._ghosts
        near_g = np.zeros(0, dtype=np.intp)
        if len(gc) and n_new:
            lo, hi = segs.min(axis=(0, 1)) - 2 * r, segs.max(axis=(0, 1)) + 2 * r
            near_g = np.flatnonzero((gc[:, 0] >= lo[0]) & (gc[:, 1] >= lo[1])
                                    & (gc[:, 0] <= hi[0]) & (gc[:, 1] <= hi[1]))
        fresh = np.ones(k_new, dtype=bool)       # squares with nothing to carry over
        if old.size or near_g.size:
            n_old = num[old]
            centre, direction = square_centres(self._seg[old], n_old)
            carried = np.concatenate([pool[_runs(at[old], n_old)], gn[near_g]])
            counts[:k_new], src = carry_evidence(
                np.concatenate([centre, gc[near_g]]), np.concatenate([direction, gu[near_g]]),
                carried, segs, n_sub[:n_new], r, return_source=True)
            fresh = src < 0
            used = src[src >= len(centre)] - len(centre)
            if used.size:                   # a ghost taken up is a square again (or a new ghost)
                keep_g = np.ones(len(gc), dtype=bool)
                keep_g[near_g[used]] = False
                self._ghosts = gc, gu, gn = gc[keep_g], gu[keep_g], gn[keep_g]
        # The others keep theirs, resampled along the segment when r changed its layout.
        has = at[others] >= 0
        same = has & (num[others] == n_sub[n_new:])
        if same.any():
            kept = others[same]
            counts[k_new:][np.repeat(same, n_sub[n_new:])] = pool[_runs(at[kept], num[kept])]
        redo = has & ~same
        if redo.any():
            j = others[redo]
            n_old = num[j]
            seg_j = self._seg[j]
            centre, direction = square_centres(seg_j, n_old)
            counts[k_new:][np.repeat(redo, n_sub[n_new:])] = carry_evidence(
                centre, direction, pool[_runs(at[j], n_old)], seg_j, n_sub[n_new:][redo], r)
        if self._memory is not None and fresh.any():
            # A new square starts from what the beams saw of its place before it stood there.
            centre, direction = square_centres(segs, n_sub[:n_new])
            prior = self._memory.lookup(centre[fresh], direction[fresh])
            clear = clearly_free(prior)
            sel = np.flatnonzero(fresh)[clear]
            counts[sel] = prior[clear]
        for a, b, o in views:
            hits, passes = beam_evidence(group, n_sub, o, pts[a:b], tol,
                                         hit_range_tol=self.config.free_space_hit_margin or None)
            counts = accumulate_evidence(counts, hits, passes, self.config.free_space_window)
            if self._memory is not None:        # read above, before any of these beams
                self._memory.add(o, pts[a:b], tol)
        free = free_squares(counts)
        if self.config.free_space_ghosts > 0 and free.any():
            # A single square left between cuts or at the end of one, itself passed through,
            # goes too: as a piece its crossing window would shrink to its middle half.
            seg_of = np.repeat(np.arange(len(group)), n_sub)
            prev = np.concatenate([[True], free[:-1] | (seg_of[1:] != seg_of[:-1])])
            nxt = np.concatenate([free[1:] | (seg_of[1:] != seg_of[:-1]), [True]])
            cut_seg = np.bincount(seg_of, weights=free, minlength=len(group)) > 0
            free = free | (~free & prev & nxt & cut_seg[seg_of] & (counts[:, 1] > 0))
        pieces, parent, first, last = cut_squares(group, n_sub, ~free)
        if self.config.free_space_ghosts > 0 and free.any():
            most = int(self.config.free_space_ghosts)
            sure = free & (counts[:, 1] >= 2.0 * counts[:, 0])      # clearly seen through
            # The centres of the squares of the segments holding a sure one (the same values
            # as of all of them).
            held = np.bincount(seg_of, weights=sure, minlength=len(group)) > 0
            centre, direction = square_centres(group[held], n_sub[held])
            sure = sure[held[seg_of]]
            self._ghosts = tuple(np.concatenate([g, new[sure]])[-most:] for g, new in
                                 zip(self._ghosts, (centre, direction, counts[held[seg_of]])))
        size = last - first + 1
        whole = (parent >= n_new) & (size == n_sub[parent])
        kept = others[parent[whole] - n_new]
        self._ev_at[kept] = self._store(counts[_runs(first[whole], size[whole])], size[whole])
        self._ev_n[kept] = size[whole]
        new = np.flatnonzero(~whole)
        lost = np.ones(len(others), dtype=bool)
        lost[parent[whole] - n_new] = False
        lost = np.flatnonzero(lost)
        length = lengths(pieces[new])
        psup = gsup[parent[new]] * length / np.maximum(lengths(group)[parent[new]], 1e-12)
        cap = self.config.virtual_cap * np.maximum(length / (2.0 * r), 1.0)
        self._replace(np.concatenate([active, others[lost]]), pieces[new],
                      np.minimum(psup, cap), (counts[_runs(first[new], size[new])], size[new]))

    def _replace(self, old_ids: np.ndarray, segs: np.ndarray, sup: np.ndarray,
                 evidence: tuple = None) -> None:
        """
        Put ``segs`` in the map in place of ``old_ids``, with their square evidence.

        ``evidence`` is None (none) or ``(rows, sizes)``: the [hits, passes] of the squares of
        all of ``segs`` in order, (sizes.sum(), 2), and how many each has.
        """
        self._ev_at[old_ids] = -1
        self._grid.remove(old_ids)
        self._alive[old_ids] = False
        free = np.flatnonzero(~self._alive)
        if free.size < len(segs):
            grow = max(len(self._alive), len(segs) - free.size)
            self._seg = np.concatenate([self._seg, np.zeros((grow, 2, 2))])
            self._sup = np.concatenate([self._sup, np.zeros(grow)])
            self._alive = np.concatenate([self._alive, np.zeros(grow, dtype=bool)])
            self._box = np.concatenate([self._box, np.zeros((grow, 2, 2))])
            self._ev_at = np.concatenate([self._ev_at, np.full(grow, -1, dtype=np.intp)])
            self._ev_n = np.concatenate([self._ev_n, np.zeros(grow, dtype=np.intp)])
            free = np.flatnonzero(~self._alive)
        ids = free[:len(segs)]
        self._seg[ids] = segs
        self._box[ids, 0] = np.minimum(segs[:, 0], segs[:, 1])
        self._box[ids, 1] = np.maximum(segs[:, 0], segs[:, 1])
        self._sup[ids] = sup
        self._alive[ids] = True
        self._grid.add(ids, segs)
        if evidence is not None:
            self._ev_at[ids] = self._store(*evidence)
            self._ev_n[ids] = evidence[1]

    def _store(self, rows: np.ndarray, sizes: np.ndarray) -> np.ndarray:
        """
        Append evidence rows (runs of ``sizes``) to the pool; return each run's first row.

        A full pool is first compacted to the runs of the slots that hold evidence
        (``_ev_at`` >= 0) and sized to twice them plus ``rows``: amortised O(rows), memory
        O(live squares).
        """
        need = len(rows)
        if self._pool_used + need > len(self._pool):
            live = np.flatnonzero(self._ev_at >= 0)
            n = self._ev_n[live]
            held = self._pool[_runs(self._ev_at[live], n)]
            self._pool = np.zeros((max(2 * (len(held) + need), 1024), 2))
            self._pool[:len(held)] = held
            self._ev_at[live] = np.cumsum(n) - n
            self._pool_used = len(held)
        start = self._pool_used
        self._pool[start:start + need] = rows
        self._pool_used += need
        return start + np.cumsum(sizes) - sizes


def _runs(starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Return the indices ``starts[i] .. starts[i] + sizes[i] - 1`` of every run, in order."""
    return np.repeat(starts - (np.cumsum(sizes) - sizes), sizes) + np.arange(int(np.sum(sizes)))
