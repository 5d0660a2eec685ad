"""
The planner map: an occupancy grid in the map frame (ROS-free numpy).

Three cell states, valued as nav_msgs/OccupancyGrid does: ``UNKNOWN`` -1, ``FREE`` 0,
``OCCUPIED`` 100.

- **Free** cells come from the traced beams: each beam is sampled from the laser origin to its
  end point every half cell (vectorised over all beams of an update, no per-beam loop); every
  cell a sample falls in is free, except the cell of the end point itself. A cell stays free
  once seen free (a single flag per cell, no pass / hit counts): dynamic obstacles do not enter
  the grid at all, because occupied cells come from the polylines only.
- **Occupied** cells come from the current polylines: each segment is sampled every half cell
  and its cells are occupied, over free.
- **Unknown** everywhere else.

Beams without a return (at range_max, or beyond ``max_mapping_range``) are dropped as invalid
readings before the mapper sees them and are not traced either: the grid's free space only
comes from beams that hit something.

Memory: ``FreeSpaceGrid`` keeps one byte per cell over the bounding box of the beams traced so
far, which grows in chunks of ``CHUNK`` cells (aligned to the lattice of the resolution, so two
runs agree cell for cell), never beyond ``max_cells`` cells (default 2**26: 64 MiB, a 409 m
square at 5 cm). Beam samples that would need a larger grid are left out (counted in
``clipped``). So memory follows the area the laser has seen, not the number of beams.
"""

from dataclasses import dataclass
import math

import numpy as np

from .geometry import as_segments

UNKNOWN = -1
FREE = 0
OCCUPIED = 100
CHUNK = 64
"""The free-space grid grows by whole chunks of this many cells along each axis."""
DEFAULT_MAX_CELLS = 2 ** 26
MARK_BLOCK = 1 << 21
"""Cells crossed that ``mark_segments`` works on at once (about 100 MB of work arrays)."""
STEP = 0.5
"""Beams are sampled every STEP cells."""
BATCH = 2 ** 16
"""Samples traced at once (bounds the work arrays: 6 x 8 bytes x BATCH = 3 MiB); a beam is
sampled over at most BATCH * STEP cells (1.6 km at 5 cm, beyond any grid ``max_cells``
allows)."""


@dataclass
class GridMap:
    """
    A trinary occupancy grid, laid out as nav_msgs/OccupancyGrid.

    ``data[row, col]`` is the cell centred at x = origin[0] + (col + 0.5) * res,
    y = origin[1] + (row + 0.5) * res (row 0 at the lowest y).

    >>> g = GridMap(np.full((2, 3), UNKNOWN, dtype=np.int8), 0.05, (1.0, 2.0))
    >>> g.width, g.height
    (3, 2)
    """

    data: np.ndarray
    """(height, width) int8: -1 unknown, 0 free, 100 occupied."""
    resolution: float
    """Metres per cell."""
    origin: tuple
    """(x, y) metres of the lower-left corner of cell (0, 0), in the map frame."""

    @property
    def width(self) -> int:
        """Return the number of columns (cells along x)."""
        return int(self.data.shape[1])

    @property
    def height(self) -> int:
        """Return the number of rows (cells along y)."""
        return int(self.data.shape[0])

    def cell_of(self, xy) -> np.ndarray:
        """Return the (col, row) integer cells of (N, 2) points (may lie outside the grid)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.floor((xy - np.asarray(self.origin)) / self.resolution).astype(np.int64)

    def centers(self, mask: np.ndarray) -> np.ndarray:
        """Return the (N, 2) centres, metres, of the cells where ``mask`` (height, width) holds."""
        rows, cols = np.nonzero(mask)
        return (np.asarray(self.origin) + (np.stack([cols, rows], axis=1) + 0.5)
                * self.resolution)


def check_resolution(resolution) -> float:
    """Return ``resolution`` as a float, or raise ValueError unless it is in [0.001, 100] m."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, float, np.floating)):
        raise ValueError(f'grid resolution must be a number of metres, got {resolution!r}')
    r = float(resolution)
    if not (math.isfinite(r) and 1e-3 <= r <= 100.0):
        raise ValueError(f'grid resolution must be in [0.001, 100] m, got {resolution!r}')
    return r


def _sample_segments(a: np.ndarray, b: np.ndarray, step: float, skip_last: bool = False):
    """
    Sample the segments a[i] -> b[i] every ``step`` (vectorised; ragged per segment).

    Returns (points (M, 2), segment index (M,)). Samples lie at a + k * step * u for
    k = 0 .. ceil(L / step) - 1, plus b itself unless ``skip_last``.
    """
    d = b - a
    length = np.hypot(d[:, 0], d[:, 1])
    n = np.ceil(length / step).astype(np.int64)
    n = np.maximum(n, 1) + (0 if skip_last else 1)
    total = int(n.sum())
    idx = np.repeat(np.arange(len(a)), n)
    k = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
    with np.errstate(invalid='ignore', divide='ignore'):
        frac = np.where(length > 0, step / length, 0.0)
    t = np.minimum(k * frac[idx], 1.0)
    return a[idx] + d[idx] * t[:, None], idx


class FreeSpaceGrid:
    """
    Free space seen by the traced beams, in a grid that grows with the area seen.

    >>> g = FreeSpaceGrid(0.1)
    >>> g.add_beams(np.array([[0.0, 0.0]]), np.array([[1.05, 0.05]]))
    >>> m = g.occupancy(np.zeros((0, 2, 2)))
    >>> int((m.data == FREE).sum())            # cells 0 .. 9 along the beam, not the end cell
    10
    """

    def __init__(self, resolution: float = 0.05, max_cells: int = DEFAULT_MAX_CELLS):
        self.resolution = check_resolution(resolution)
        if isinstance(max_cells, bool) or int(max_cells) != max_cells or max_cells < CHUNK ** 2:
            raise ValueError(f'max_cells must be an integer >= {CHUNK ** 2}, got {max_cells!r}')
        self.max_cells = int(max_cells)
        self.clipped = 0
        """Beam samples left out because the grid would have grown beyond ``max_cells``."""
        self.reset()

    def reset(self) -> None:
        """Forget all free space."""
        self._free = np.zeros((0, 0), dtype=np.uint8)
        self._lo = np.zeros(2, dtype=np.int64)      # global (col, row) of _free[0, 0]
        self._work = None
        self.clipped = 0

    @property
    def nbytes(self) -> int:
        """Return the bytes the grid holds (one per cell)."""
        return int(self._free.nbytes)

    @property
    def shape(self) -> tuple:
        """Return (rows, cols) of the grid held."""
        return self._free.shape

    def _grow(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Make the grid cover global cells lo .. hi (inclusive, (col, row)), in whole chunks."""
        if self._free.size:
            cur_lo, cur_hi = self._lo, self._lo + np.array(self._free.shape[::-1]) - 1
            if (lo >= cur_lo).all() and (hi <= cur_hi).all():
                return
            lo, hi = np.minimum(lo, cur_lo), np.maximum(hi, cur_hi)
        new_lo = np.floor_divide(lo, CHUNK) * CHUNK
        new_hi = (np.floor_divide(hi, CHUNK) + 1) * CHUNK - 1
        size = new_hi - new_lo + 1
        if int(size[0]) * int(size[1]) > self.max_cells:
            return                                  # stay as is; add_beams clips
        grid = np.zeros((int(size[1]), int(size[0])), dtype=np.uint8)
        if self._free.size:
            off = self._lo - new_lo
            grid[off[1]:off[1] + self._free.shape[0],
                 off[0]:off[0] + self._free.shape[1]] = self._free
        self._free, self._lo = grid, new_lo

    def add_beams(self, origins, ends) -> None:
        """
        Trace beams: the cells from each origin to its end point are free, the end cell not.

        ``origins``: (2,) one origin for all, or (N, 2); ``ends``: (N, 2), metres, map frame.
        """
        ends = np.asarray(ends, dtype=np.float64).reshape(-1, 2)
        if not len(ends):
            return
        origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), ends.shape)
        ok = np.isfinite(ends).all(axis=1) & np.isfinite(origins).all(axis=1)
        if not ok.all():
            ends, origins = ends[ok], origins[ok]
            if not len(ends):
                return
        res = self.resolution
        o = origins / res                           # cell units: cell (i, j) = [i, i + 1)
        e = ends / res
        both = np.floor(np.concatenate([o, e])).astype(np.int64)
        self._grow(both.min(axis=0), both.max(axis=0))
        d = e - o
        length = np.hypot(d[:, 0], d[:, 1])
        # Where the beam enters its end cell (slab test against the end cell's box): every
        # sample before that lies outside the end cell, so no sample needs comparing with it.
        box = np.floor(e)
        with np.errstate(divide='ignore', invalid='ignore'):
            inv = 1.0 / d
            t1 = (box - o) * inv
            t2 = (box + 1.0 - o) * inv
        near = np.where(d == 0, -np.inf, np.minimum(t1, t2))
        enter = np.clip(np.nan_to_num(near.max(axis=1), nan=0.0, neginf=0.0), 0.0, 1.0)
        reach = enter * length                      # cells travelled before the end cell
        n = np.minimum(np.ceil(reach / STEP), BATCH).astype(np.int64)  # samples k*STEP < reach
        keep = n > 0
        if not keep.all():
            o, d, length, n = o[keep], d[keep], length[keep], n[keep]
        if not len(n):
            return
        with np.errstate(divide='ignore', invalid='ignore'):
            u = d / length[:, None] * STEP
        rel = o - self._lo                          # cells from the grid's corner, >= 0 ...
        covered = self._covers(both)
        ends_at = np.cumsum(n)
        # Batches of whole beams with at most BATCH samples each (one, for a longer beam).
        cuts = [0]
        while cuts[-1] < len(n):
            base = ends_at[cuts[-1] - 1] if cuts[-1] else 0
            cuts.append(max(int(np.searchsorted(ends_at, base + BATCH, side='right')),
                            cuts[-1] + 1))
        for a, b in zip(cuts[:-1], cuts[1:]):
            self._trace(rel[a:b], u[a:b], n[a:b], covered)

    def _scratch(self, size: int) -> tuple:
        """Reusable work arrays (no fresh pages per update: that cost more than the work)."""
        if self._work is None or len(self._work[0]) < size:
            m = max(size, 4096)
            self._work = (np.arange(m, dtype=np.float64), np.empty(m, dtype=np.int64),
                          np.empty(m), np.empty(m), np.empty(m), np.empty(m, dtype=np.int64))
        return tuple(w[:size] for w in self._work)

    def _trace(self, rel, u, n, covered: bool) -> None:
        """Mark the samples of beams starting at ``rel`` (cells from the grid corner) free."""
        total = int(n.sum())
        j, idx, x, y, tmp, cell = self._scratch(total)
        # Sample j (index in the batch) of beam b: rel_b + u_b * (j - first_b).
        first = np.cumsum(n) - n
        idx[:] = 0
        idx[first[1:]] = 1
        np.cumsum(idx, out=idx)                     # the beam of every sample
        start = rel - u * first[:, None].astype(np.float64)
        np.take(start[:, 0], idx, out=x)
        np.take(u[:, 0], idx, out=tmp)
        tmp *= j
        x += tmp
        np.take(start[:, 1], idx, out=y)
        np.take(u[:, 1], idx, out=tmp)
        tmp *= j
        y += tmp
        h, w = self._free.shape
        free = self._free.reshape(-1)
        if covered:                                 # ... so truncation is floor
            np.copyto(idx, y, casting='unsafe')
            idx *= w
            np.copyto(cell, x, casting='unsafe')
            idx += cell
            free[idx] = 1
            return
        cols, rows = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        self.clipped += int((~inside).sum())
        free[rows[inside] * w + cols[inside]] = 1

    def _covers(self, cells: np.ndarray) -> bool:
        lo = self._lo
        hi = lo + np.array(self._free.shape[::-1]) - 1
        return bool(self._free.size and (cells.min(axis=0) >= lo).all()
                    and (cells.max(axis=0) <= hi).all())

    def seed(self, grid: GridMap) -> None:
        """
        Mark the free cells of a saved planner map free: the free space a loaded map was made with.

        Each free cell's centre marks the cell it lies in (the same cell when the resolutions and
        lattices agree; a resampling otherwise). Counts what does not fit in ``clipped``.
        """
        rows, cols = np.nonzero(np.asarray(grid.data) == FREE)
        if not len(rows):
            return
        res = float(grid.resolution)
        centres = np.asarray(grid.origin, dtype=np.float64) + (
            np.stack([cols, rows], axis=1) + 0.5) * res
        cells = np.floor(centres / self.resolution).astype(np.int64)
        self._grow(cells.min(axis=0), cells.max(axis=0))
        rel = cells - self._lo
        h, w = self._free.shape
        inside = (rel[:, 0] >= 0) & (rel[:, 0] < w) & (rel[:, 1] >= 0) & (rel[:, 1] < h)
        self.clipped += int((~inside).sum())
        self._free[rel[inside, 1], rel[inside, 0]] = 1

    def occupancy(self, segments) -> GridMap:
        """
        Return the trinary grid (a GridMap) of the traced free space and ``segments``.

        Occupied: the cells ``segments`` ((K, 2, 2) metres) cross, over the free cells traced;
        unknown elsewhere. Covers the traced area and the segments (a wall beyond what the beams
        traced, as a loaded map's, is marked too), within ``max_cells``; the segments' box alone
        while nothing is traced.
        """
        segs = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
        res = self.resolution
        if not self._free.size:
            return rasterise(segs, res)
        h, w = self._free.shape
        lo, hi = self._lo, self._lo + np.array([w, h]) - 1
        if len(segs):
            ends = np.floor(segs.reshape(-1, 2) / res).astype(np.int64)
            wide_lo = np.minimum(lo, ends.min(axis=0))
            wide_hi = np.maximum(hi, ends.max(axis=0))
            size = wide_hi - wide_lo + 1
            if int(size[0]) * int(size[1]) <= self.max_cells:
                lo, hi = wide_lo, wide_hi
        size = hi - lo + 1
        data = np.full((int(size[1]), int(size[0])), UNKNOWN, dtype=np.int8)
        off = self._lo - lo
        data[off[1]:off[1] + h, off[0]:off[0] + w][self._free > 0] = FREE
        grid = GridMap(data, res, tuple(float(v) for v in lo * res))
        mark_segments(grid, segs)
        return grid


def crossed_cells(a, b) -> np.ndarray:
    """
    Return the (M, 2) integer (col, row) cells the segments a[i] -> b[i] cross (cell units).

    Exact and vectorised: besides the start cell, a segment enters a new cell at each column
    boundary (the new column, and the row of the crossing point) and at each row boundary; so
    those cells, generated per boundary without sorting, are all the cells it crosses. A cell
    only touched at a corner may be left out or counted. May hold duplicates.

    >>> crossed_cells(np.array([[0.5, 0.5]]), np.array([[2.5, 1.5]])).tolist()
    [[0, 0], [1, 0], [2, 1], [1, 1]]
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    ca, cb = np.floor(a).astype(np.int64), np.floor(b).astype(np.int64)
    out = [ca]
    for axis in (0, 1):
        other = 1 - axis
        n = np.abs(cb[:, axis] - ca[:, axis])
        total = int(n.sum())
        if not total:
            continue
        seg = np.repeat(np.arange(len(a)), n)
        k = np.arange(1, total + 1) - np.repeat(np.cumsum(n) - n, n)
        step = np.sign(cb[:, axis] - ca[:, axis])[seg]
        entered = ca[seg, axis] + k * step           # the new index along this axis
        boundary = np.where(step > 0, entered, entered + 1).astype(np.float64)
        t = (boundary - a[seg, axis]) / (b[seg, axis] - a[seg, axis])
        across = np.floor(a[seg, other] + t * (b[seg, other] - a[seg, other])).astype(np.int64)
        cells = np.empty((total, 2), dtype=np.int64)
        cells[:, axis], cells[:, other] = entered, across
        out.append(cells)
    return np.concatenate(out)


def mark_segments(grid: GridMap, segments) -> None:
    """Mark every cell ``segments`` ((K, 2, 2) metres) cross occupied (clipped to ``grid``)."""
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
    if not len(segs):
        return
    o = np.asarray(grid.origin)
    a, b = (segs[:, 0] - o) / grid.resolution, (segs[:, 1] - o) / grid.resolution
    # Clip to the grid's box (Liang-Barsky), so a far segment costs no more than the grid.
    d = b - a
    size = np.array([grid.width, grid.height], dtype=np.float64)
    with np.errstate(divide='ignore', invalid='ignore'):
        t1, t2 = -a / d, (size - a) / d
    lo = np.where(d == 0, np.where((a >= 0) & (a <= size), -np.inf, np.inf), np.minimum(t1, t2))
    hi = np.where(d == 0, np.where((a >= 0) & (a <= size), np.inf, -np.inf), np.maximum(t1, t2))
    t0, t1 = np.maximum(lo.max(axis=1), 0.0), np.minimum(hi.min(axis=1), 1.0)
    keep = t0 <= t1
    a, d, t0, t1 = a[keep], d[keep], t0[keep], t1[keep]
    start, end = a + t0[:, None] * d, a + t1[:, None] * d
    # In blocks of about MARK_BLOCK cells crossed (a segment longer than that in pieces), so
    # the work arrays stay bounded whatever the segments' length (a map of twenty 1000 km
    # segments took 6.4 GB before its export failed).
    work = _crossings(start, end)
    pieces = np.ceil(work / MARK_BLOCK).astype(np.int64)
    if (pieces > 1).any():
        seg = np.repeat(np.arange(len(start)), pieces)
        k = np.arange(len(seg)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        span = end - start
        t0, t1 = (k / pieces[seg])[:, None], ((k + 1) / pieces[seg])[:, None]
        start, end = start[seg] + t0 * span[seg], start[seg] + t1 * span[seg]
        work = _crossings(start, end)
    bounds = np.searchsorted(np.cumsum(work), np.arange(1, int(work.sum() // MARK_BLOCK) + 1)
                             * MARK_BLOCK)
    for i, j in zip(np.r_[0, bounds], np.r_[bounds, len(start)]):
        if i >= j:
            continue
        cells = crossed_cells(start[i:j], end[i:j])
        inside = ((cells[:, 0] >= 0) & (cells[:, 0] < grid.width) & (cells[:, 1] >= 0)
                  & (cells[:, 1] < grid.height))
        cells = cells[inside]
        grid.data[cells[:, 1], cells[:, 0]] = OCCUPIED


def _crossings(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return about how many cells each segment a[i] -> b[i] (cell units) crosses."""
    return np.abs(b - a).sum(axis=1) + 1.0


def rasterise(segments, resolution: float, max_cells: int = DEFAULT_MAX_CELLS) -> GridMap:
    """
    Return a grid of the segments alone: their cells occupied, the rest unknown.

    The grid covers the segments' bounding box plus one cell, aligned to the lattice of
    ``resolution``; an empty map gives a 1 x 1 unknown grid at the origin. Raises ValueError
    when it would need more than ``max_cells`` cells (pick a coarser resolution).
    """
    res = check_resolution(resolution)
    segs = as_segments(segments)
    if not len(segs):
        return GridMap(np.full((1, 1), UNKNOWN, dtype=np.int8), res, (0.0, 0.0))
    pts = segs.reshape(-1, 2)
    lo = np.floor(pts.min(axis=0) / res).astype(np.int64) - 1
    hi = np.floor(pts.max(axis=0) / res).astype(np.int64) + 1
    size = hi - lo + 1
    if int(size[0]) * int(size[1]) > max_cells:
        raise ValueError(f'a grid of {int(size[0])} x {int(size[1])} cells at {res:g} m is '
                         f'larger than {max_cells} cells: use a coarser resolution')
    work = float(_crossings(segs[:, 0] / res, segs[:, 1] / res).sum())
    if work > max_cells:
        raise ValueError(f'the segments cross about {work:.3g} cells at {res:g} m, more than '
                         f'{max_cells}: use a coarser resolution')
    grid = GridMap(np.full((int(size[1]), int(size[0])), UNKNOWN, dtype=np.int8), res,
                   tuple(float(v) for v in lo * res))
    mark_segments(grid, segs)
    return grid


def encode_cells(data: np.ndarray) -> list:
    """
    Run-length encode grid values (row-major): ``[value, count, value, count, ...]``.

    >>> encode_cells(np.array([[-1, -1, 0], [0, 100, 100]], dtype=np.int8))
    [-1, 2, 0, 2, 100, 2]
    """
    flat = np.asarray(data).ravel()
    if not len(flat):
        return []
    starts = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]])
    counts = np.diff(np.r_[starts, len(flat)])
    out = np.empty(2 * len(starts), dtype=np.int64)
    out[0::2], out[1::2] = flat[starts], counts
    return out.tolist()


def decode_cells(runs: list, width: int, height: int) -> np.ndarray:
    """
    Return the (height, width) int8 grid of ``encode_cells`` runs; ValueError if they are bad.

    Values must be -1, 0 or 100, counts positive integers, and their total width * height.
    """
    if not isinstance(runs, list) or len(runs) % 2 or not all(type(v) is int for v in runs):
        raise ValueError('"grid" cells must be a list of integers: value, count, ...')
    arr = np.array(runs, dtype=np.int64).reshape(-1, 2)
    if not np.isin(arr[:, 0], (UNKNOWN, FREE, OCCUPIED)).all():
        raise ValueError('"grid" cell values must be -1, 0 or 100')
    if (arr[:, 1] < 1).any():
        raise ValueError('"grid" run lengths must be positive')
    total = int(arr[:, 1].sum())
    if total != width * height:
        raise ValueError(f'"grid" runs hold {total} cells for {width} x {height}')
    return np.repeat(arr[:, 0], arr[:, 1]).astype(np.int8).reshape(height, width)
