"""The planner map: free space from traced beams, occupied cells from segments (core.grid)."""

import numpy as np
from polyline_mapper.core.grid import (CHUNK, decode_cells, encode_cells, FREE, FreeSpaceGrid,
                                       OCCUPIED, rasterise, UNKNOWN)
from polyline_mapper.formats.records import Scan
from polyline_mapper.session import MappingSession, SessionOptions
import pytest


def _point_segment_distance(p, a, b):
    """Distance of points p (N, 2) to the segment a-b."""
    d = b - a
    t = np.clip(((p - a) @ d) / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def test_a_beam_frees_its_cells_but_not_its_end_cell():
    g = FreeSpaceGrid(0.1)
    g.add_beams(np.array([0.02, 0.03]), np.array([[1.02, 0.03]]))
    m = g.occupancy(np.zeros((0, 2, 2)))
    cols, rows = np.nonzero(m.data.T == FREE)
    cells = g_cells = np.stack([cols, rows], axis=1) + np.round(np.array(m.origin) / 0.1)
    assert sorted(map(tuple, g_cells.astype(int))) == [(i, 0) for i in range(10)]
    end = m.cell_of([[1.02, 0.03]])[0]
    assert m.data[end[1], end[0]] == UNKNOWN
    assert len(cells) == 10


def test_free_cells_lie_on_the_beams_and_cover_them():
    rng = np.random.default_rng(3)
    res = 0.05
    g = FreeSpaceGrid(res)
    origin = np.array([1.3, -0.7])
    ang = rng.uniform(-np.pi, np.pi, 40)
    ends = origin + rng.uniform(0.3, 4.0, (40, 1)) * np.stack([np.cos(ang), np.sin(ang)], 1)
    g.add_beams(origin, ends)
    m = g.occupancy(np.zeros((0, 2, 2)))
    centres = m.centers(m.data == FREE)
    dist = np.min([_point_segment_distance(centres, origin, e) for e in ends], axis=0)
    assert dist.max() <= res * np.sqrt(0.5) + 1e-9       # every free cell is crossed by a beam
    for e in ends:              # a cell a beam crosses over >= 0.6 cell (not its end cell) is free
        t = np.linspace(0, 1, 4000)[:, None]
        cells = m.cell_of(origin + t * (e - origin))
        end = m.cell_of(e[None])[0]
        spacing = np.linalg.norm(e - origin) / 3999 / res
        uniq, count = np.unique(cells, axis=0, return_counts=True)
        long_chord = (count * spacing >= 0.6) & (uniq != end).any(axis=1)
        assert long_chord.sum() >= np.linalg.norm(e - origin) / res / 2
        assert (m.data[uniq[long_chord, 1], uniq[long_chord, 0]] == FREE).all()
    lone = [e for i, e in enumerate(ends)
            if np.min([_point_segment_distance(e[None], origin, f)[0]
                       for k, f in enumerate(ends) if k != i]) > 2 * res]
    assert lone
    for e in lone:                                        # an end cell no other beam crosses
        c = m.cell_of(e[None])[0]
        assert m.data[c[1], c[0]] == UNKNOWN


def test_a_segment_marks_its_cells_occupied_over_free():
    res = 0.05
    g = FreeSpaceGrid(res)
    g.add_beams(np.array([0.0, 0.0]), np.array([[3.0, 2.5], [3.0, -0.5], [-1.0, 2.0]]))
    seg = np.array([[[0.2, 1.0], [2.3, 0.1]]])
    m = g.occupancy(seg)
    occ = m.centers(m.data == OCCUPIED)
    assert len(occ) >= 2.3 / res
    assert _point_segment_distance(occ, seg[0, 0], seg[0, 1]).max() <= res * np.sqrt(0.5) + 1e-9
    along = seg[0, 0] + np.linspace(0, 1, 5000)[:, None] * (seg[0, 1] - seg[0, 0])
    cells = m.cell_of(along)                    # every cell the segment crosses: no gap
    assert (m.data[cells[:, 1], cells[:, 0]] == OCCUPIED).all()
    assert (m.data == FREE).any() and (m.data == UNKNOWN).any()


def test_memory_grows_with_the_area_seen_not_with_the_beams():
    rng = np.random.default_rng(0)
    g = FreeSpaceGrid(0.05)
    ang = np.linspace(-np.pi / 2, np.pi / 2, 361)
    dirs = np.stack([np.cos(ang), np.sin(ang)], 1)
    home = np.array([4.8, 4.8])
    g.add_beams(home, home + 4.0 * dirs)
    first = g.nbytes
    assert first <= (2 * 4.0 / 0.05 + 2 * CHUNK) ** 2      # about the 4 m x 8 m area seen
    for _ in range(200):                                    # the same room, seen again
        g.add_beams(home + rng.normal(0, 0.03, 2), home + rng.uniform(0.5, 3.9, (361, 1)) * dirs)
    assert g.nbytes == first
    g.add_beams(np.array([30.0, 0.0]), np.array([[33.0, 1.0]]))   # new area: the grid grows
    assert g.nbytes > first
    rows, cols = g.shape
    assert rows % CHUNK == 0 and cols % CHUNK == 0
    assert cols * 0.05 <= 33.0 + 4.0 + 2 * CHUNK * 0.05


def test_the_grid_never_grows_beyond_max_cells():
    g = FreeSpaceGrid(0.05, max_cells=CHUNK ** 2 * 4)
    g.add_beams(np.zeros(2), np.array([[1.0, 1.0]]))
    g.add_beams(np.zeros(2), np.array([[500.0, 0.0]]))      # would need 10000 columns
    assert g.nbytes <= CHUNK ** 2 * 4
    assert g.clipped > 0
    m = g.occupancy(np.array([[[-1e6, 0.01], [1e6, 0.01]]]))   # a far segment: clipped too
    assert (m.data == FREE).sum() > 0
    assert (m.data[0] == OCCUPIED).all() and (m.data[1:] != OCCUPIED).all()


def test_bad_beams_and_values_are_refused_or_skipped():
    g = FreeSpaceGrid(0.1)
    g.add_beams(np.zeros(2), np.array([[np.nan, 1.0], [np.inf, 0.0]]))
    g.add_beams(np.zeros(2), np.zeros((0, 2)))
    assert g.nbytes == 0
    g.add_beams(np.zeros(2), np.array([[0.01, 0.01], [np.nan, 0.0]]))  # within the origin cell
    assert not (g.occupancy(np.zeros((0, 2, 2))).data == FREE).any()
    for bad in (0.0, -1.0, float('nan'), True, 'a', 1e3):
        with pytest.raises(ValueError, match='resolution'):
            FreeSpaceGrid(bad)


def test_rasterised_segments_and_run_length_cells_round_trip():
    seg = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [1.0, 1.0]]])
    m = rasterise(seg, 0.1)
    assert set(np.unique(m.data)) == {UNKNOWN, OCCUPIED}
    occ = m.centers(m.data == OCCUPIED)
    assert np.min([_point_segment_distance(occ, s[0], s[1]) for s in seg], axis=0).max() \
        <= 0.1 * np.sqrt(0.5) + 1e-9
    runs = encode_cells(m.data)
    assert np.array_equal(decode_cells(runs, m.width, m.height), m.data)
    assert rasterise(np.zeros((0, 2, 2)), 0.05).data.shape == (1, 1)
    with pytest.raises(ValueError, match='coarser'):
        rasterise(np.array([[[0.0, 0.0], [1e4, 1e4]]]), 0.05)
    for runs, what in (([0, 5], 'hold 5 cells'), ([7, 6], '-1, 0 or 100'),
                       ([0, 0, 0, 6], 'positive'), ([0, 6.0], 'integers'), ([0], 'integers')):
        with pytest.raises(ValueError, match=what):
            decode_cells(runs, 3, 2)


def _scan(stamp, pose, rng):
    ranges = rng.uniform(1.0, 3.0, 181).astype(np.float32)
    return Scan(stamp, 'laser', -np.pi / 2, np.pi / 180, 0.1, 30.0, ranges, pose=pose)


def test_the_session_traces_every_mapped_scan_and_reset_forgets():
    rng = np.random.default_rng(1)
    session = MappingSession(options=SessionOptions(grid_resolution=0.1))
    for i in range(8):
        session.add(_scan(float(i), (0.1 * i, 0.0, 0.0), rng))
        session.step()
    grid = session.occupancy()
    assert grid.resolution == 0.1
    free = grid.centers(grid.data == FREE)
    assert len(free) > 100
    assert free[:, 0].min() > -3.2 and free[:, 0].max() < 3.9 and np.abs(free[:, 1]).max() < 3.1
    session.reset()
    assert not (session.occupancy().data == FREE).any()
    assert MappingSession(options=SessionOptions(grid_resolution=None)).occupancy() is None
    with pytest.raises(ValueError, match='resolution'):
        SessionOptions(grid_resolution=-0.05)


def test_grouped_updates_trace_each_scan_from_its_own_origin():
    grids = []
    for n in (1, 3):
        rng = np.random.default_rng(2)
        session = MappingSession(options=SessionOptions(grid_resolution=0.1,
                                                        update_every_n_scans=n))
        for i in range(9):
            session.add(_scan(float(i), (0.5 * i, 0.2 * (i % 2), 0.1 * i), rng))
            session.step()
        session.flush()
        grids.append(session.occupancy(np.zeros((0, 2, 2))))
    assert grids[0].origin == grids[1].origin
    assert np.array_equal(grids[0].data, grids[1].data)
    assert (grids[0].data == FREE).sum() > 500
