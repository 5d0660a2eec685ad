"""
Far returns, huge scans and wide queries: an incremental update stays bounded in time and memory.

A scan with range_max = inf and junk far returns used to make r follow their spacing (3 cm ->
44 m): updates took seconds and GBs, the map got walls 175 m long.
"""

import time
import tracemalloc

import numpy as np
from polyline_mapper.core import cleanup, index
from polyline_mapper.core.cleanup import corner_chords, seen_through
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.core.index import PointIndex, SegmentGrid
from polyline_mapper.core.noise import scan_spacing
from polyline_mapper.core.smemsf import fit
from polyline_mapper.scan import scan_to_points
from polyline_mapper.sim import LaserSpec, office_floor, simulate_drive
import pytest


@pytest.fixture(scope='module')
def drive():
    """60 scans of the office floor, full circle, 360 beams, 12 m (all other beams invalid)."""
    spec = LaserSpec(beams=360, fov=2 * np.pi, range_max=12.0, noise=0.01, dropout=0.01)
    d = simulate_drive(office_floor(), spec, step=0.25, rng=2)
    ranges = [np.where(r < spec.range_max, r, np.nan) for r in d.ranges[:60]]
    return spec.angles(), ranges, d.poses[:60]


def _hostile(ranges, case, rng):
    """Return the scans with far returns (range_max inf) and the same with those beams NaN."""
    far, nan = [], []
    for i, r in enumerate(ranges):
        if case == '30% at 1e4 m':
            bad = rng.random(r.size) < 0.3
            value = 1e4
        else:                                   # two scans in three: every beam at 1e6 m
            bad = np.full(r.size, i % 3 != 0)
            value = 1e6
        far.append(np.where(bad, value, r))
        nan.append(np.where(bad, np.nan, r))
    return far, nan


def _run(mapper, angles, scans, poses, grouped):
    """Feed the scans (one update_scan each, or update() of pairs with per-point origins)."""
    if not grouped:
        for r, p in zip(scans, poses):
            yield mapper.update_scan(r, angles, p, 0.0, np.inf)
        return
    for i in range(0, len(scans) - 1, 2):
        pts = [scan_to_points(scans[j], angles, poses[j], 0.0, np.inf) for j in (i, i + 1)]
        origin = np.repeat(poses[i:i + 2, :2], [len(q) for q in pts], axis=0)
        yield mapper.update(np.concatenate(pts), ordered=True, origin=origin)


@pytest.mark.parametrize('grouped', [False, True])
@pytest.mark.parametrize('case', ['30% at 1e4 m', 'all at 1e6 m'])
def test_far_returns_map_as_if_they_were_invalid(drive, case, grouped):
    angles, ranges, poses = drive
    far, nan = _hostile(ranges, case, np.random.default_rng(4))
    ratios = []
    for _ in range(2):                          # timing on a shared machine: best of two runs
        m_far, m_nan = IncrementalMapper(), IncrementalMapper()
        t_far = t_nan = 0.0
        # interleaved update by update, so that machine load hits both runs alike
        for dt_far, dt_nan in zip(_timed(m_far, angles, far, poses, grouped),
                                  _timed(m_nan, angles, nan, poses, grouped)):
            t_far += dt_far
            t_nan += dt_nan
        np.testing.assert_array_equal(m_far.segments, m_nan.segments)
        np.testing.assert_array_equal(m_far.support, m_nan.support)
        assert (m_far.sigma, m_far.r) == (m_nan.sigma, m_nan.r)
        assert len(m_far.segments) > 8 and m_far.r < 0.1
        ratios.append(t_far / t_nan)
        if ratios[-1] <= 1.5:
            break
    assert min(ratios) <= 1.5, ratios
    # Memory: what one run of the far scans holds at its peak.
    tracemalloc.start()
    try:
        infos = list(_run(IncrementalMapper(), angles, far, poses, grouped))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2 ** 20, f'{peak / 2 ** 20:.1f} MiB'
    # update_scan drops them as out of range; update() counts those it drops
    n_far = sum(int(np.sum(r >= 100.0)) for r in far)
    assert sum(i.beyond_range for i in infos) == (n_far if grouped else 0)


def _timed(mapper, angles, scans, poses, grouped):
    it = _run(mapper, angles, scans, poses, grouped)
    while True:
        t0 = time.perf_counter()
        try:
            next(it)
        except StopIteration:
            return
        yield time.perf_counter() - t0


def test_far_bare_points_cannot_blow_up_r_or_memory(drive):
    """Without an origin nothing can be range-limited: the spacing statistic must hold."""
    angles, ranges, poses = drive
    far, _ = _hostile(ranges, '30% at 1e4 m', np.random.default_rng(4))
    mapper = IncrementalMapper()
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        for r, p in zip(far[:30], poses):
            mapper.update(scan_to_points(r, angles, p, 0.0, np.inf), ordered=True)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 32 * 2 ** 20, f'{peak / 2 ** 20:.1f} MiB'
    assert time.perf_counter() - t0 < 10.0
    # r follows the dense part's spacing (was 44 m)
    assert mapper.r < 0.1
    walls = mapper.segments
    assert np.abs(walls).max() < 30.0            # no wall out among the far points


def test_a_100k_beam_scan_is_thinned_evenly_to_max_scan_points(drive):
    from polyline_mapper.sim.laser import simulate_scan
    _, _, poses = drive
    spec = LaserSpec(beams=100_000, fov=2 * np.pi, range_max=50.0, noise=0.01)
    rng = np.random.default_rng(1)
    scans = [simulate_scan(office_floor(), p, spec, rng)[0] for p in poses[:8]]
    big, small = IncrementalMapper(), IncrementalMapper()
    most = big.config.max_scan_points
    tracemalloc.start()
    try:
        for r, p in zip(scans, poses):
            info = big.update_scan(r, spec.angles(), p, 0.0, spec.range_max)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2 ** 20, f'{peak / 2 ** 20:.1f} MiB'
    n = len(scan_to_points(scans[-1], spec.angles(), poses[7], 0.0, spec.range_max))
    assert n > 50_000 and info.points == len(range(0, n, -(-n // most))) <= most
    assert info.thinned == n - info.points
    for r, p in zip(scans, poses):              # the same as every k-th point given directly
        pts = scan_to_points(r, spec.angles(), p, 0.0, spec.range_max)
        small.update(pts[::-(-len(pts) // most)], ordered=True, origin=p[:2])
    np.testing.assert_array_equal(big.segments, small.segments)


def test_max_mapping_range_applies_to_update_scan_and_update_with_origin():
    angles = np.linspace(-np.pi, np.pi, 8, endpoint=False)
    mapper = IncrementalMapper(IncrementalConfig(max_mapping_range=5.0))
    info = mapper.update_scan(np.array([1, 4.99, 5.0, 7, np.inf, 3, 6, 2.0]), angles,
                              (1.0, 2.0, 0.3), 0.0, 10.0)
    assert info.points == 4 and info.skipped == 'estimating noise'
    pts = np.array([[0.0, 0.0], [3.0, 4.0], [2.9, 4.0], [10.0, 0.0]])
    info = mapper.update(pts, origin=np.zeros(2))
    assert (info.points, info.beyond_range) == (2, 2)
    assert mapper.update(pts).points == 4       # bare points: no origin, no range to limit


@pytest.mark.parametrize('values, match', [
    ({'max_mapping_range': 0.0}, 'max_mapping_range'),
    ({'max_mapping_range': float('inf')}, 'max_mapping_range'),
    ({'max_mapping_range': float('nan')}, 'max_mapping_range'),
    ({'max_scan_points': 8}, 'max_scan_points'),
    ({'max_scan_points': 100.5}, 'max_scan_points'),
    ({'cell': 1e-4}, 'cell'),
])
def test_bad_bounds_are_refused_naming_the_field(values, match):
    with pytest.raises(ValueError, match=match):
        IncrementalConfig(**values)


def test_points_beyond_the_coordinate_limit_are_refused_leaving_the_map_unchanged(drive):
    angles, ranges, poses = drive
    mapper = IncrementalMapper()
    for r, p in zip(ranges[:8], poses):
        mapper.update_scan(r, angles, p)
    before = mapper.segments
    pts = scan_to_points(ranges[8], angles, poses[8])
    with pytest.raises(ValueError, match='frame origin'):
        mapper.update(pts + 1e12, ordered=True)
    with pytest.raises(ValueError, match='frame origin'):
        mapper.update_scan(ranges[8], angles, poses[8] + [3e7, 0.0, 0.0])
    np.testing.assert_array_equal(mapper.segments, before)


def test_scan_spacing_is_the_upper_quartile_unless_a_far_minority_would_set_it(drive):
    angles, ranges, poses = drive
    rng = np.random.default_rng(0)
    for r, p in zip(ranges[::10], poses[::10]):
        pts = scan_to_points(r, angles, p)
        gap = np.hypot(*np.diff(pts, axis=0).T)
        nearest = np.minimum(np.append(gap, np.inf), np.insert(gap, 0, np.inf))
        assert scan_spacing(pts, ordered=True) == np.percentile(nearest, 75)
        far = rng.random(r.size) < 0.3
        junk = scan_to_points(np.where(far, 1e4, r), angles, p)
        s = scan_spacing(junk, ordered=True)
        assert s <= 1.5 * np.percentile(nearest, 75)     # the dense part's, not 87 m
        assert scan_spacing(junk) <= 2 * np.percentile(nearest, 75)    # k-d tree path alike
        assert scan_spacing(junk, ordered=True, limit=0.05) == min(s, 0.05)


def test_a_wide_grid_query_equals_the_dilated_one_without_its_memory(monkeypatch):
    rng = np.random.default_rng(3)
    grid = SegmentGrid(2.0)
    a = rng.uniform(-200, 200, (500, 2))
    grid.add(np.arange(500), np.stack([a, a + rng.normal(0, 3, (500, 2))], axis=1))
    grid.remove(np.arange(0, 500, 7))
    query = rng.uniform(-20, 20, (50, 2))
    for dist in (1.0, 9.0, 40.0):
        want = grid.near(query, dist)
        monkeypatch.setattr(index, 'DILATE_BUDGET', 0)
        np.testing.assert_array_equal(grid.near(query, dist), want)
        monkeypatch.undo()
    tracemalloc.start()
    try:
        ids = grid.near(query, 1e5)             # dilation: (1e5 rings)^2 x 50 cells
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(ids) == 500 - len(range(0, 500, 7)) and peak < 8 * 2 ** 20


def test_clearing_and_corner_chords_work_in_blocks_of_bounded_memory(monkeypatch):
    rng = np.random.default_rng(8)
    origin = np.array([5.0, 5.0])
    ang = np.linspace(-np.pi, np.pi, 2000, endpoint=False)
    pts = origin + rng.uniform(1, 6, 2000)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    a = rng.uniform(0, 10, (300, 2))
    segs = np.stack([a, a + rng.normal(0, 0.4, (300, 2))], axis=1)
    idx = PointIndex(pts)
    want = (seen_through(segs, origin, pts, 0.05), corner_chords(idx, segs, 0.1, 0.05, 1.0, 0.3))
    assert want[0].any() and want[1].any()
    monkeypatch.setattr(cleanup, 'PAIR_BUDGET', 50)
    got = (seen_through(segs, origin, pts, 0.05), corner_chords(idx, segs, 0.1, 0.05, 1.0, 0.3))
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    monkeypatch.undo()
    # 8192 beams against 4000 short segments 1-2 m away: 3 million (segment, beam) pairs, 72 MB
    # at once before blocks.
    ang = np.linspace(-np.pi, np.pi, 8192, endpoint=False)
    pts = origin + 8.0 * np.c_[np.cos(ang), np.sin(ang)]
    t = rng.uniform(-3, 3, 4000)
    c = origin + rng.uniform(1, 2, 4000)[:, None] * np.c_[np.cos(t), np.sin(t)]
    d = 0.45 * np.c_[-np.sin(t), np.cos(t)]
    tracemalloc.start()
    try:
        flags = seen_through(np.stack([c - d, c + d], axis=1), origin, pts, 0.05)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert flags.all() and peak < 24 * 2 ** 20, f'{peak / 2 ** 20:.1f} MiB'


def test_fit_memory_follows_pairs_on_a_long_cut_line():
    # 5000 points 2 m apart along a 10 km line: LSS cuts it into about 5000 pieces. Every pair
    # used to be tested against every piece of its parent (25 M rows, 1.2 GB peak RSS); the
    # pieces a point can reach are now searched along the line.
    pts = np.c_[np.linspace(0.0, 10_000.0, 5000), np.zeros(5000)]
    tracemalloc.start()
    try:
        fit(pts)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100e6, f'fit peaked at {peak / 1e6:.0f} MB'
