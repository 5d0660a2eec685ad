"""Incremental SMEMSF: G(t) + the last scans -> G(t+1), on simulated drives."""

from conftest import end_errors
import numpy as np
from polyline_mapper.core import fit, map_metrics
from polyline_mapper.core.cleanup import seen_through
from polyline_mapper.core.geometry import sample_segments
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.core.index import near_points, PointIndex, SegmentGrid
from polyline_mapper.core.metrics import twin_fraction
from polyline_mapper.core.noise import median, percentile, percentiles
from polyline_mapper.core.split import split_segments
from polyline_mapper.sim import corridor_loop, LaserSpec, office_floor, simulate_drive, World
from polyline_mapper.sim.laser import simulate_scan
from polyline_mapper.sim.world import path_poses
import pytest


def run_drive(drive, mapper=None):
    mapper = mapper or IncrementalMapper()
    angles = drive.spec.angles()
    infos = [mapper.update_scan(r, angles, p, drive.spec.range_min, drive.spec.range_max)
             for r, p in zip(drive.ranges, drive.poses)]
    return mapper, infos


@pytest.fixture(scope='module')
def office_incremental(office_drive):
    mapper, infos = run_drive(office_drive)
    return mapper, infos


def test_incremental_finds_every_wall_like_batch(office_incremental, office_drive, office_fit):
    mapper, _ = office_incremental
    pts, hits, batch = office_fit
    segs = mapper.polylines().segments      # the published map, ends joined like batch's
    for i, wall in enumerate(office_drive.world.walls):
        a, b = wall
        u = (b - a) / np.linalg.norm(b - a)
        t = (pts[hits == i] - a) @ u
        err = end_errors(segs, a + t.min() * u, a + t.max() * u).min()
        assert err <= 0.10, f'wall {i}: end-point error {err:.3f} m'
    samples, owner = sample_segments(segs, 0.02)
    assert office_drive.world.distance(samples).max() <= 0.10
    inc, bat = map_metrics(pts, segs), map_metrics(pts, batch.segments)
    assert inc['mean_distance'] <= 1.25 * bat['mean_distance']
    assert inc['segments'] <= 1.5 * bat['segments']
    assert inc['coverage_0_10m'] >= bat['coverage_0_10m'] - 0.03


def test_segment_grid_finds_exactly_the_segments_in_nearby_cells():
    """Random adds, re-adds and removals; every query equals a brute-force cell test."""
    rng = np.random.default_rng(7)
    grid, live, cell = SegmentGrid(2.0), {}, 2.0
    for _ in range(150):
        if live:
            gone = rng.choice(list(live), size=min(len(live), int(rng.integers(0, 20))),
                              replace=False)
            grid.remove(gone)
            for i in gone:
                live.pop(int(i))
        n = int(rng.integers(1, 30))
        ids = rng.choice(np.setdiff1d(np.arange(2000), list(live)), n, replace=False)
        a = rng.uniform(-50, 50, (n, 2))
        segs = np.stack([a, a + rng.normal(0, 3, (n, 2))], axis=1)
        grid.add(ids, segs)
        live.update({int(i): s for i, s in zip(ids, segs)})
        query = rng.uniform(-50, 50, (30, 2))
        ids_live = np.array(list(live))
        pts, owner = sample_segments(np.array([live[i] for i in ids_live]), 0.5 * cell)
        ci, qi = np.floor(pts / cell).astype(int), np.floor(query / cell).astype(int)
        hit = np.abs(ci[:, None, :] - qi[None]).max(axis=2).min(axis=1) <= 1
        expected = set(ids_live[np.unique(owner[hit])].tolist())
        assert set(grid.near(query, 1.0).tolist()) == expected


def test_revisiting_a_corridor_does_not_double_it():
    world = corridor_loop(width=2.0, side=16.0)
    spec = LaserSpec(beams=361, fov=np.deg2rad(270), range_max=8.0, noise=0.01)
    once = simulate_drive(world, spec, step=0.3, rng=3)
    twice = simulate_drive(world, spec, step=0.3, rng=4,
                           waypoints=world.path + world.path[1:])
    m1, _ = run_drive(once)
    m2, _ = run_drive(twice)
    assert twin_fraction(m2.segments) < 0.05
    assert len(m2.segments) <= 1.2 * len(m1.segments) + 2
    pts = twice.points()
    assert map_metrics(pts, m2.segments)['coverage_0_10m'] > 0.98


def test_only_segments_near_the_scan_are_refit():
    world = corridor_loop(width=2.0, side=30.0)
    spec = LaserSpec(beams=361, fov=np.deg2rad(270), range_max=4.0, noise=0.01)
    drive = simulate_drive(world, spec, step=0.3, rng=5)
    mapper, _ = run_drive(drive)
    before = mapper.segments
    assert len(before) >= 8
    # Scans in the corner at (1, 1)-(1, 5), 4 m range: the east side (x > 20) is out of reach.
    far = np.all(before.reshape(-1, 4)[:, [0, 2]] > 20, axis=1)
    last = simulate_drive(world, spec, step=0.3, rng=6, waypoints=[(1, 1), (1, 5)])
    _, infos = run_drive(last, mapper)
    assert far.any() and all(i.active <= len(before) - far.sum() for i in infos)
    after = mapper.segments
    kept = [s for s in before[far] if np.any(np.all(after == s, axis=(1, 2)))]
    assert len(kept) == int(far.sum())          # bit for bit unchanged


@pytest.mark.parametrize('ranges, angles, why', [
    (np.full(100, np.nan), np.linspace(-1, 1, 100), None),
    (np.zeros(0), np.zeros(0), None),
    (np.full(100, np.inf), np.linspace(-1, 1, 100), None),
    (np.ones(100), np.linspace(-1, 1, 90), 'differ in length'),
])
def test_bad_scans_leave_the_map_unchanged(office_incremental, ranges, angles, why):
    mapper, _ = office_incremental
    before, sup = mapper.segments, mapper.support
    if why is None:
        info = mapper.update_scan(ranges, angles, (5.0, 6.0, 0.0), 0.05, 12.0)
        assert info.skipped == 'no valid points'
    else:
        with pytest.raises(ValueError, match=why):
            mapper.update_scan(ranges, angles, (5.0, 6.0, 0.0), 0.05, 12.0)
    with pytest.raises(ValueError):
        mapper.update_scan(np.ones(10), np.zeros(10), (np.nan, 0.0, 0.0))
    np.testing.assert_array_equal(mapper.segments, before)
    np.testing.assert_array_equal(mapper.support, sup)


def test_memory_is_bounded_by_map_and_buffer():
    world = corridor_loop(width=2.0, side=16.0)
    spec = LaserSpec(beams=361, fov=np.deg2rad(270), range_max=8.0, noise=0.01)
    mapper = IncrementalMapper(IncrementalConfig(buffer_scans=3))
    drive = simulate_drive(world, spec, step=0.3, rng=7,
                           waypoints=world.path + world.path[1:] + world.path[1:])
    n = len(drive.poses)
    sizes = []
    angles = spec.angles()
    for i, (r, p) in enumerate(zip(drive.ranges, drive.poses)):
        mapper.update_scan(r, angles, p, spec.range_min, spec.range_max)
        if i in (n // 3, n - 1):
            sizes.append((mapper.nbytes(), len(mapper.segments)))
    assert len(mapper._buffer) == 3
    (b1, k1), (b3, k3) = sizes
    assert b3 <= 1.2 * b1 + 64 * abs(k3 - k1) * 40


def test_batch_and_incremental_agree_on_the_same_points(office_drive, office_incremental):
    pts = office_drive.points()
    batch = fit(pts)
    mapper, _ = office_incremental
    assert abs(len(mapper.segments) - len(batch.segments)) <= 0.5 * len(batch.segments)


def test_sparse_low_noise_scans_give_the_batch_map():
    """1 degree between beams, 0.5 cm noise: squares of 2r = 5 sigma would miss far wall points."""
    world = office_floor()
    drive = simulate_drive(world, LaserSpec(beams=271, range_max=12.0, noise=0.005,
                                            dropout=0.01), step=0.5, rng=0)
    mapper, _ = run_drive(drive)
    pts, hits = drive.points(with_hits=True)
    segs = mapper.polylines().segments
    for i, (a, b) in enumerate(world.walls):
        u = (b - a) / np.linalg.norm(b - a)
        t = (pts[hits == i] - a) @ u
        err = end_errors(segs, a + t.min() * u, a + t.max() * u).min()
        assert err <= 0.10, f'wall {i}: end-point error {err:.3f} m'
    inc, bat = map_metrics(pts, segs), map_metrics(pts, fit(pts).segments)
    assert inc['mean_distance'] <= 1.25 * bat['mean_distance']
    assert inc['segments'] <= 1.5 * bat['segments']
    assert inc['coverage_0_10m'] >= bat['coverage_0_10m'] - 0.01


def test_a_virtual_point_a_rounding_error_past_the_end_holds_the_end_square():
    """LSS on the old map: the span virtual points cover is never low, end squares included."""
    seg = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    virt = np.c_[np.linspace(0.0, 1.0, 21), np.zeros(21)]
    virt[0, 0] = -1e-12                      # a refit end, a rounding error off the old sample
    index = PointIndex(virt, np.full(21, 30.0), virtual=21)
    pieces, _ = split_segments(index, seg, 0.02)
    np.testing.assert_allclose(pieces, seg)


def test_near_points_keeps_every_segment_within_the_distance():
    """Against brute force: none within the distance is missed, none beyond 4.3x is kept."""
    rng = np.random.default_rng(11)
    pts = rng.uniform(0, 20, (300, 2))
    a = rng.uniform(-5, 25, (400, 2))
    segs = np.stack([a, a + rng.normal(0, 2, (400, 2))], axis=1)
    dist = 0.4
    samples, owner = sample_segments(segs, 0.005)
    d = np.full(len(segs), np.inf)
    np.minimum.at(d, owner, PointIndex(pts).tree.query(samples)[0])
    keep = near_points(pts, segs, dist)
    assert keep[d <= dist].all() and not keep[d > 4.3 * dist].any()
    assert 0 < (d <= dist).sum() < len(segs)


def _room_scan(extra=(), pose=(2.0, 2.0, 0.0), seed=0):
    """Simulate a 360-beam scan in an 8 m x 6 m room (optionally with extra walls): its points."""
    room = np.array([[[0, 0], [8, 0]], [[8, 0], [8, 6]], [[8, 6], [0, 6]], [[0, 6], [0, 0]]],
                    dtype=float)
    walls = np.concatenate([room, np.array(extra, dtype=float).reshape(-1, 2, 2)])
    spec = LaserSpec(beams=360, fov=2 * np.pi, range_max=12.0, noise=0.01, dropout=0.0)
    ranges, _ = simulate_scan(World(walls=walls), np.asarray(pose), spec,
                              np.random.default_rng(seed))
    from polyline_mapper.scan import scan_to_points
    return scan_to_points(ranges, spec.angles(), pose, spec.range_min, spec.range_max)


def test_seen_through_flags_only_what_the_beams_pass():
    pts = _room_scan(extra=[[[5.0, 1.0], [5.0, 2.0]]])     # a box edge in the room
    o = np.array([2.0, 2.0])
    segs = np.array([
        [[3.0, 1.0], [3.0, 3.0]],      # 0: nothing there now, beams pass to the east wall
        [[8.0, 1.0], [8.0, 5.0]],      # 1: the east wall, hit
        [[6.0, 1.2], [6.0, 1.8]],      # 2: behind the box edge: occluded, no evidence
        [[1.0, 5.0], [7.9, 5.0]],      # 3: seen past along most of it (to the north wall)
        [[8.2, 1.0], [8.2, 5.0]],      # 4: beyond the east wall: never reached
        [[2.5, 2.2], [2.5, 2.25]],     # 5: 5 cm stub: too few beams
    ])
    tol = 0.03
    flags = seen_through(segs, o, pts, tol)
    assert flags.tolist() == [True, False, False, True, False, False]
    # Seen past along its whole length: flagged; seen past over its lowest 0.8 m only (the
    # rest outside a narrower field of view): kept, one end is no evidence against a wall.
    long_ = np.array([[[4.0, 0.5], [4.0, 5.5]]])
    fov = pts[np.arctan2(pts[:, 1] - 2, pts[:, 0] - 2) < np.deg2rad(-20.0)]
    assert seen_through(long_, o, pts, tol)[0]
    assert (seen_through(long_, o, fov, tol, share=0.1)[0]
            and not seen_through(long_, o, fov, tol)[0])


def _drive_scans(world, poses, spec, rng):
    return [simulate_scan(world, p, spec, rng)[0] for p in poses]


@pytest.mark.parametrize('clear_max_length, grouped', [(0.9, False), (0.0, False), (0.9, True)])
def test_a_person_who_walks_away_is_cleared(clear_max_length, grouped):
    """
    A person (0.4 m of legs) stands in the corridor for the first pass, then leaves.

    ``grouped``: after the person left, scans arrive two per update with one laser position
    per point (as the node sends them with update_every_n_scans = 2).
    """
    office = office_floor()
    person = np.array([[[6.0, 5.6], [6.4, 5.6]]])
    with_person = World(walls=np.concatenate([office.walls, person]), arcs=office.arcs)
    spec = LaserSpec(beams=360, fov=2 * np.pi, range_max=12.0, noise=0.01)
    poses = path_poses(office.path, 0.25)
    k = int(np.argmax(poses[:, 0] > 9.0))      # the robot has passed the person
    rng = np.random.default_rng(9)
    ranges = (_drive_scans(with_person, poses[:k], spec, rng)
              + _drive_scans(office, poses[k:], spec, rng))
    mapper = IncrementalMapper(IncrementalConfig(clear_max_length=clear_max_length,
                                                 free_space_window=0))
    for r, p in zip(ranges[:k], poses[:k]):
        mapper.update_scan(r, spec.angles(), p, spec.range_min, spec.range_max)
    samples = sample_segments(mapper.segments, 0.02)[0]
    on_person = np.hypot(samples[:, 0] - 6.2, samples[:, 1] - 5.6) < 0.3
    assert on_person.any()                       # mapped while it stood there
    if grouped:
        from polyline_mapper.scan import scan_to_points
        for i in range(k, len(poses) - 1, 2):
            pts = [scan_to_points(ranges[j], spec.angles(), poses[j], spec.range_min,
                                  spec.range_max) for j in (i, i + 1)]
            origin = np.repeat(poses[i:i + 2, :2], [len(q) for q in pts], axis=0)
            mapper.update(np.concatenate(pts), ordered=True, origin=origin)
    else:
        for r, p in zip(ranges[k:], poses[k:]):
            mapper.update_scan(r, spec.angles(), p, spec.range_min, spec.range_max)
    samples = sample_segments(mapper.segments, 0.02)[0]
    on_person = np.hypot(samples[:, 0] - 6.2, samples[:, 1] - 5.6) < 0.3
    assert on_person.any() == (clear_max_length == 0)
    # The walls are all still there.
    pts = np.concatenate([simulate_drive(office, spec, step=0.25, rng=1).points()])
    assert map_metrics(pts, mapper.segments)['coverage_0_10m'] > 0.99


def test_bad_origin_is_rejected_and_leaves_the_map_unchanged(office_incremental):
    mapper, _ = office_incremental
    before = mapper.segments
    pts = np.array([[5.0, 5.0], [5.1, 5.0], [5.2, 5.0]])
    for origin in ([1.0], [np.nan, 0.0], np.zeros((2, 2))):
        with pytest.raises(ValueError, match='origin'):
            mapper.update(pts, origin=origin)
    np.testing.assert_array_equal(mapper.segments, before)


def test_running_statistics_equal_numpy():
    # The partial-sort median and percentile must give numpy's values exactly (sigma and r
    # follow them, and a last-bit difference would change maps).
    rng = np.random.default_rng(5)
    for n in list(range(1, 60)) + [359, 360, 720]:
        x = rng.exponential(0.03, n)
        assert median(list(x)) == float(np.median(x))
        if n >= 2:
            for q in (25.0, 50.0, 75.0, 90.0):
                assert percentile(x, q) == float(np.percentile(x, q))
            assert percentiles(x, (25.0, 75.0)) == np.percentile(x, [25.0, 75.0]).tolist()


@pytest.mark.parametrize('world, noise, stubs', [
    (office_floor, 0.01, [24]),           # the demo's drive (seed 1): a stub last, 25 -> 24
    (corridor_loop, 0.05, [3, 6, 11]),    # 5 cm noise: stubs inside the list, 27 -> 24
])
def test_published_support_belongs_to_the_segment_beside_it(world, noise, stubs):
    """``polylines()`` drops noise stubs from segments and support alike, in the same order."""
    from polyline_mapper.core.geometry import end_distance
    from polyline_mapper.core.merge import noise_stubs
    mapper, _ = run_drive(simulate_drive(world(), LaserSpec(beams=541, noise=noise), rng=1))
    inner, sup = mapper.segments, mapper.support
    stub = noise_stubs(inner, mapper.sigma, mapper.r, mapper.config.smemsf.kappa)
    assert np.flatnonzero(stub).tolist() == stubs          # the case this test is about
    geo = mapper.polylines()
    assert len(geo.segments) == len(geo.support) == len(inner) - len(stubs)
    # Each published segment is its inner segment with ends joined (moved a few cm at most).
    src = [int(np.argmin(end_distance(inner, s[None]))) for s in geo.segments]
    assert src == np.flatnonzero(~stub).tolist()
    assert end_distance(inner[src], geo.segments).max() < 0.1
    np.testing.assert_array_equal(geo.support, sup[src])
    assert sum(len(p) - 1 + c for p, c in zip(geo.polylines, geo.closed)) == len(geo.segments)


def test_reset_forgets_the_map_but_keeps_sigma_and_spacing():
    drive = simulate_drive(corridor_loop(width=2.0, side=16.0),
                           LaserSpec(beams=361, fov=np.deg2rad(270), range_max=8.0, noise=0.01),
                           step=0.3, rng=3)
    mapper, infos = run_drive(drive, IncrementalMapper(IncrementalConfig(noise_updates=5)))
    assert [i.skipped for i in infos[:5]] == ['estimating noise'] * 4 + [None]
    sigma, r = mapper.sigma, mapper.r
    assert sigma is not None and len(mapper.segments) > 0
    mapper.reset()
    assert len(mapper.segments) == 0 and len(mapper.polylines().segments) == 0
    assert mapper.nbytes() == IncrementalMapper().nbytes() and mapper.updates == 0
    assert (mapper.sigma, mapper.r) == (sigma, r)
    info = mapper.update_scan(drive.ranges[0], drive.spec.angles(), drive.poses[0],
                              drive.spec.range_min, drive.spec.range_max)
    assert info.skipped is None and info.segments > 0 and mapper.updates == 1
    # A reset before sigma is known keeps the estimates pooled so far.
    fresh = IncrementalMapper(IncrementalConfig(noise_updates=3))
    for i in range(2):
        fresh.update_scan(drive.ranges[i], drive.spec.angles(), drive.poses[i])
    fresh.reset()
    assert fresh.sigma is None
    assert fresh.update_scan(drive.ranges[2], drive.spec.angles(), drive.poses[2]).skipped is None
