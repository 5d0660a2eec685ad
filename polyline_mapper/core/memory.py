"""
Free-space memory: what the beams saw of every place, before a segment stood there.

The free-space evidence of the incremental mapper (``incremental.free_space_window``) lives on
the squares of the segments, so it only counts beams while a segment stands in their way. A
segment drawn later where the laser had seen through (the last scans of a visit see a table's
legs from a new angle, a person stands by a wall, the merge joins two pieces of clutter) starts
with no evidence, and once the robot has moved on nothing sees through it again. On the fr079
log nearly every segment the map -> beams metric contradicts at the end had most of its passing
beams *before* it was made (``benchmarks/README.md``).

``BeamMemory`` keeps, per cell of a grid over the area the beams have covered, the same decaying
and capped counts as a square (``split.accumulate_evidence``): a beam *ends* in the cell of its
return and *passes* the cells it crosses before that, up to the same noise margin as a square's
pass (``tol`` + ``range_tol`` x range short of its return); passes are kept per beam direction
(``BINS`` bins over a half turn). A square that the map gains with nothing to carry over
(``split.carry_evidence`` found no old square) starts from the counts of the cell its centre lies
in when that cell is clearly free (``lookup``, ``clearly_free``), so a wall drawn through space
seen free is cut by the next beams, and a new object in that space (a box put down) needs as
many hits as the cell holds passes (a few looks) before it stays.

Memory: 9 float16 (18 bytes) per cell, in chunks of ``CHUNK`` x ``CHUNK`` cells allocated only
where beams went, never more than ``max_cells`` cells (samples beyond are left out and counted in
``clipped``): at 0.1 m about 1 MB for fr079, 13 MB for the MIT corridor log, 91 MB for the
Freiburg campus (long outdoor beams).
"""

import numpy as np

from .split import EVIDENCE_CAP

BINS = 8
"""Passes are kept per beam direction (modulo a half turn), in this many bins."""
EXCLUDE = np.deg2rad(45.0)
"""A square takes the passes of the bins whose centre direction is at least this far from its own:
a beam along a wall, grazing it, is no evidence against it, and a cell's passes are counted up to
the pass margin short of the return, which a beam at a shallow angle to a wall crosses within a
cell's width of it (MIT corridor: 30 deg cut more of its walls, mean 1.151x the default map's
against 1.141x; benchmarks/README.md, "The beams' memory")."""
CLEAR = 2.0
"""A new square starts from its cell's counts only when the passes are at least this many times
the hits (a place clearly seen through, as a ghost's square); elsewhere it starts at nothing, as
without memory. (3 x left a 10 cm piece of the corridor walker's track in the dynamic office,
seed 3.)"""
SAMPLES = 1 << 18
"""Most beam samples traced at once (``add``): a few MB of work arrays."""
CHUNK = 16
"""Cells are stored in square chunks of this many cells a side, only where beams went."""
AROUND = np.array([(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)], dtype=np.int64)
"""The 3 x 3 cell offsets a square's hits are read from; the centre (0, 0) is the middle row."""
DENSE = 1 << 21
"""A scan whose beams fit in a box of at most this many cells x channels is counted in that box
(``bincount``) and stored once per cell; larger ones (long outdoor beams) sort their samples."""
CHUNK_TABLE = 1 << 20
"""Most chunks in the box a call of ``_rows`` spans for its lookup table (8 MB); wider boxes
are searched in the sorted chunk keys instead."""
DEFAULT_MAX_CELLS = 2 ** 24
"""Most cells stored (16.8 M: 300 MiB at 18 bytes a cell, a 410 m square at 0.1 m). Beams beyond
are left out, counted in ``clipped``."""


def clearly_free(counts: np.ndarray) -> np.ndarray:
    """Rows of [hits, passes] (M, 2) a new square starts from: passes >= ``CLEAR`` x hits."""
    return counts[:, 1] >= CLEAR * counts[:, 0]


def _chunk_key(col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Return the sorted-store key of chunks (col, row): col in the high 32 bits, row below."""
    return (col << 32) + (row & 0xFFFFFFFF)


def _in_chunk(cells: np.ndarray) -> np.ndarray:
    """Return each (col, row) cell's row within its chunk's CHUNK x CHUNK block of the pool."""
    return (cells[:, 1] % CHUNK) * CHUNK + cells[:, 0] % CHUNK


class BeamMemory:
    """Decaying, capped counts of the beams that end in and pass through each grid cell."""

    def __init__(self, cell: float, window: float, cap: float = EVIDENCE_CAP,
                 max_cells: int = DEFAULT_MAX_CELLS):
        """Cells of ``cell`` metres; counts decay over ``window`` looks, capped at ``cap``."""
        if not (np.isfinite(cell) and cell > 0):
            raise ValueError(f'cell must be a finite number > 0, got {cell!r}')
        self.cell = float(cell)
        self.window = float(window)
        # Every float16 count decayed as ``count * (1 - 1 / window)`` (float16 arithmetic),
        # looked up by its bit pattern: the same values, without float16 multiplications.
        with np.errstate(invalid='ignore'):          # the NaN patterns stay NaN
            self._decayed = (np.arange(1 << 16, dtype=np.uint16).view(np.float16)
                             * (1.0 - 1.0 / self.window)).astype(np.float64)
        self.cap = float(cap)
        # ... and the float16 each becomes when a look adds nothing to it (``_store``), as a
        # bit pattern: the same arithmetic (+ 0.0, cap, cast) done once for all patterns.
        with np.errstate(invalid='ignore'):
            self._decayed16 = np.minimum(self._decayed + 0.0, self.cap).astype(
                np.float16).view(np.uint16)
        self.max_cells = int(max_cells)
        self._keys = np.zeros(0, dtype=np.int64)      # chunk keys, sorted
        self._slot = np.zeros(0, dtype=np.intp)       # the pool row of each sorted key
        self._pool = np.zeros((0, 1 + BINS), dtype=np.float16)   # CHUNK**2 rows a chunk
        self._used = 0                                # chunks in the pool
        self.clipped = 0
        """Beam samples left out because the memory held ``max_cells`` cells."""

    @property
    def nbytes(self) -> int:
        """Return the bytes the counts take (the pool, with room to grow)."""
        return int(self._pool.nbytes + self._keys.nbytes + self._slot.nbytes)

    @property
    def cells(self) -> int:
        """Return how many cells are stored."""
        return self._used * CHUNK * CHUNK

    def _rows(self, cells: np.ndarray, grow: bool) -> np.ndarray:
        """
        Return the pool row of every (col, row) cell, -1 where none is stored.

        With ``grow`` the chunks missing are added first (as far as ``max_cells`` allows), in
        the order of their keys. The chunks are looked up in a table over the box of chunks
        the cells span (``CHUNK_TABLE`` entries at most, else by binary search): a scan's beam
        samples cost one table read each.
        """
        if not len(cells):
            return np.full(0, -1, dtype=np.intp)
        chunk = cells // CHUNK
        col, row = chunk[:, 0], chunk[:, 1]         # (per column: faster than along axis 0)
        c0, r0, c1, r1 = col.min(), row.min(), col.max(), row.max()
        nc, nr = int(c1 - c0) + 1, int(r1 - r0) + 1
        if nc * nr > CHUNK_TABLE:
            return self._rows_searched(cells, chunk, grow)
        local = (col - c0) * nr + (row - r0)
        table = self._chunk_table(int(c0), int(r0), nc, nr)
        if grow:
            touched = np.bincount(local, minlength=nc * nr) > 0
            missing = np.flatnonzero(touched & (table < 0))
            room = self.max_cells // (CHUNK * CHUNK) - self._used
            if missing.size and room > 0:
                cols, rows = missing // nr + c0, missing % nr + r0
                key = _chunk_key(cols, rows)
                order = np.argsort(key, kind='stable')[:room]    # the smallest keys first
                self._add_chunks(key[order])
                table[missing[order]] = self._used - order.size + np.arange(order.size)
        slot = table.take(local)
        return np.where(slot >= 0, slot * (CHUNK * CHUNK) + _in_chunk(cells), -1)

    def _chunk_table(self, c0: int, r0: int, nc: int, nr: int) -> np.ndarray:
        """Return the slot of every chunk of the box (c0.., r0..; nc x nr), -1 where none."""
        table = np.full(nc * nr, -1, dtype=np.intp)
        a, b = np.searchsorted(self._keys, [c0 << 32, (c0 + nc) << 32])
        if a < b:
            keys = self._keys[a:b]
            cols = keys >> 32
            rows = keys & 0xFFFFFFFF
            rows = np.where(rows >= 1 << 31, rows - (1 << 32), rows)
            inside = np.flatnonzero((rows >= r0) & (rows < r0 + nr))
            table[(cols[inside] - c0) * nr + (rows[inside] - r0)] = self._slot[a:b][inside]
        return table

    def _add_chunks(self, new: np.ndarray) -> None:
        """Store the chunks of keys ``new`` (sorted, none stored yet) in the next pool slots."""
        need = (self._used + new.size) * CHUNK * CHUNK
        if need > len(self._pool):
            pool = np.zeros((max(need, 2 * len(self._pool)), 1 + BINS), np.float16)
            pool[:len(self._pool)] = self._pool
            self._pool = pool
        keys = np.concatenate([self._keys, new])
        slot = np.concatenate([self._slot, self._used + np.arange(new.size)])
        order = np.argsort(keys, kind='stable')
        self._keys, self._slot = keys[order], slot[order]
        self._used += new.size

    def _rows_searched(self, cells: np.ndarray, chunk: np.ndarray, grow: bool) -> np.ndarray:
        """``_rows`` by binary search in the sorted chunk keys (cells spanning a huge box)."""
        key = _chunk_key(chunk[:, 0], chunk[:, 1])
        if grow:
            # Samples along a beam share chunks: one key per run of equal keys is enough.
            firsts = key[np.flatnonzero(np.diff(key, prepend=key[:1] - 1))]
            new = np.setdiff1d(firsts, self._keys)
            room = self.max_cells // (CHUNK * CHUNK) - self._used
            new = new[:max(room, 0)]
            if new.size:
                self._add_chunks(new)
        out = np.full(len(key), -1, dtype=np.intp)
        if not self._keys.size:
            return out
        at = np.minimum(np.searchsorted(self._keys, key), self._keys.size - 1)
        ok = self._keys[at] == key
        out[ok] = self._slot[at[ok]] * (CHUNK * CHUNK) + _in_chunk(cells[ok])
        return out

    def lookup(self, xy: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """
        Return [hits, passes] for squares centred at ``xy`` (M, 2) along ``dirs`` (M, 2).

        Hits: the most of the 3 x 3 cells around the centre's (a wall's returns fall beside
        it too); passes: the centre cell's passes of beams at least ``EXCLUDE`` off the
        square's direction. 0 where nothing is stored.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.zeros((len(xy), 2))
        if not self._used or not len(xy):
            return out
        c = np.floor(xy / self.cell).astype(np.int64)
        rows = self._rows((c[:, None, :] + AROUND[None]).reshape(-1, 2), False).reshape(
            len(xy), len(AROUND))
        hits = np.where(rows >= 0, self._pool[np.maximum(rows, 0), 0], 0.0)
        out[:, 0] = hits.max(axis=1)
        row = rows[:, len(AROUND) // 2]                   # the centre's own cell
        ok = np.flatnonzero(row >= 0)
        counts = self._pool[row[ok]]
        ang = np.mod(np.arctan2(dirs[ok, 1], dirs[ok, 0]), np.pi)
        centres = (np.arange(BINS) + 0.5) * (np.pi / BINS)
        off = np.abs(ang[:, None] - centres[None, :])
        off = np.minimum(off, np.pi - off)
        out[ok, 1] = np.sum(counts[:, 1:] * (off >= EXCLUDE), axis=1)
        return out

    def add(self, origin: np.ndarray, points: np.ndarray, tol: float,
            range_tol: float = 0.03) -> None:
        """
        Add one scan's beams from ``origin`` (2,) to ``points`` (N, 2), metres.

        A beam passes every cell it crosses (sampled every cell length) up to ``tol`` +
        ``range_tol`` x range short of its return, and ends in the cell of its return. Cells a
        beam ended in or passed first forget 1 / ``window`` of their counts, then add the
        scan's (each capped at ``cap``); cells the scan did not see keep theirs.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        origin = np.asarray(origin, dtype=np.float64).reshape(2)
        if not len(points):
            return
        rel = points - origin
        rng = np.hypot(rel[:, 0], rel[:, 1])
        step = self.cell
        n = np.maximum(np.floor((rng - (tol + range_tol * rng)) / step), 0).astype(np.int64)
        bins = np.minimum((np.mod(np.arctan2(rel[:, 1], rel[:, 0]), np.pi)
                           / (np.pi / BINS)).astype(np.int64), BINS - 1)
        end_cells = np.floor(points / step).astype(np.int64)
        lo = np.minimum(end_cells.min(axis=0), np.floor(origin / step).astype(np.int64)) - 1
        hi = np.maximum(end_cells.max(axis=0), np.floor(origin / step).astype(np.int64)) + 1
        size = hi - lo + 1
        if int(size[0]) * int(size[1]) * (1 + BINS) <= DENSE:
            self._add_dense(origin, rel, rng, n, bins, end_cells, lo, size)
            return
        ends = self._rows(end_cells, True)
        self.clipped += int(np.count_nonzero(ends < 0))
        ends = ends[ends >= 0]
        parts = [(ends, np.zeros(len(ends), dtype=np.int64), np.ones(len(ends)))]  # row, chan, n
        # Beams in blocks of at most SAMPLES samples, each reduced to its cells' counts, so the
        # work arrays stay bounded however long the beams.
        for cells, beam in self._samples(origin, rel, rng, n):
            rows = self._rows(cells, True)
            self.clipped += int(np.count_nonzero(rows < 0))
            ok = rows >= 0
            key, count = np.unique(rows[ok] * BINS + bins[beam[ok]], return_counts=True)
            parts.append((key // BINS, 1 + key % BINS, count.astype(np.float64)))
        rows, chan, weight = (np.concatenate(p) for p in zip(*parts))
        seen, at = np.unique(rows, return_inverse=True)
        if not seen.size:
            return
        add = np.bincount(at * (1 + BINS) + chan, weights=weight,
                          minlength=seen.size * (1 + BINS)).reshape(-1, 1 + BINS)
        self._store(seen, add)

    def _samples(self, origin, rel, rng, n):
        """
        Yield the cells ((S, 2) int) and beam indices of the pass samples, in blocks.

        Beam i is sampled ``n[i]`` times, every cell length from its origin (at half-cells);
        a block holds about ``SAMPLES`` samples (whole beams).
        """
        for col, row, beam in self._sample_axes(origin, rel, rng, n):
            yield np.stack([col, row], axis=1), beam

    def _sample_axes(self, origin, rel, rng, n):
        """Yield ``_samples``' blocks with the cell columns and rows apart: (col, row, beam)."""
        step = self.cell
        cut = np.searchsorted(np.cumsum(n), np.arange(1, int(n.sum()) // SAMPLES + 1) * SAMPLES)
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(n)]):
            total = int(n[a:b].sum())
            if not total:
                continue
            beam = a + np.repeat(np.arange(b - a), n[a:b])
            k = np.arange(total) - np.repeat(np.cumsum(n[a:b]) - n[a:b], n[a:b])
            t = (k + 0.5) * step / np.maximum(rng.take(beam), 1e-12)
            # floor((origin + t x rel) / step) per axis: the same arithmetic as on (S, 2) rows
            yield (np.floor((origin[0] + t * rel[:, 0].take(beam)) / step).astype(np.int64),
                   np.floor((origin[1] + t * rel[:, 1].take(beam)) / step).astype(np.int64),
                   beam)

    def _add_dense(self, origin, rel, rng, n, bins, end_cells, lo, size):
        """``add`` for a scan whose cells fit a small box: counted there, then stored once."""
        chans = 1 + BINS
        # One count over the box of every end (channel 0) and pass (channel 1 + bin) sample;
        # the cells touched from the samples' cells, not from a pass over the whole box.
        local = [(end_cells[:, 0] - lo[0]) * size[1] + (end_cells[:, 1] - lo[1])]
        keys = [local[0] * chans]
        for col, row, beam in self._sample_axes(origin, rel, rng, n):
            local.append((col - lo[0]) * size[1] + (row - lo[1]))
            keys.append(local[-1] * chans + 1 + bins.take(beam))
        n_cells = int(size[0]) * int(size[1])
        box = np.bincount(np.concatenate(keys), minlength=n_cells * chans).reshape(-1, chans)
        hit = np.flatnonzero(np.bincount(np.concatenate(local), minlength=n_cells))
        if not hit.size:
            return
        cells = np.stack([hit // size[1] + lo[0], hit % size[1] + lo[1]], axis=1)
        rows = self._rows(cells, True)
        ok = rows >= 0
        self.clipped += int(box[hit[~ok]].sum())
        seen, add = rows[ok], box[hit[ok]].astype(np.float64)
        self._store(seen, add)

    def _store(self, rows: np.ndarray, add: np.ndarray) -> None:
        """Decay the counts of pool ``rows`` (distinct) by one look, add ``add``, cap, store."""
        old = self._pool[rows].view(np.uint16)
        new = self._decayed16.take(old)               # what adds nothing: looked up
        hot = np.flatnonzero(add.ravel())
        if hot.size:
            counts = self._decayed.take(old.ravel().take(hot)) + add.ravel().take(hot)
            new.ravel()[hot] = np.minimum(counts, self.cap).astype(np.float16).view(np.uint16)
        self._pool[rows] = new.view(np.float16)
