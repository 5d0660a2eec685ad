"""The numpy baselines of benchmarks/compare.py and the wall precision / recall metric."""

import importlib
import sys

from conftest import end_errors, noisy_line, REPO
import numpy as np
import pytest

sys.path.insert(0, str(REPO / 'benchmarks'))
B = importlib.import_module('baselines')


def corner(rng, n=300, sigma=0.005):
    """Two 2 m walls meeting at the origin at a right angle."""
    return np.concatenate([noisy_line((0, 0), (2, 0), n, sigma, rng),
                           noisy_line((0, 0), (0, 2), n, sigma, rng)])


def test_fit_line_and_gaps():
    rng = np.random.default_rng(0)
    c, u = B.fit_line(noisy_line((0, 1), (4, 3), 200, 0.002, rng))
    assert abs(abs(u @ np.array([2, 1]) / np.sqrt(5)) - 1) < 1e-4
    runs = B.split_at_gaps(np.array([0.0, 0.1, 0.2, 1.0, 1.1, 5.0]), gap=0.3, min_points=2)
    assert [r.tolist() for r in runs] == [[0, 1, 2], [3, 4]]


def test_em_fixed_k_recovers_a_corner():
    pts = corner(np.random.default_rng(1))
    res = B.em_lines(pts, 2, sigma=0.02, restarts=3, rng=0)
    assert len(res.segments) == 2
    for a, b in (((0, 0), (2, 0)), ((0, 0), (0, 2))):
        assert end_errors(res.segments, a, b).min() < 0.02


def even_line(a, b, n, sigma, rng):
    """N points evenly along ab (like laser beams) with normal noise sigma (m)."""
    t = np.linspace(0, 1, n)[:, None]
    d = np.subtract(b, a)
    return np.add(a, t * d) + rng.normal(0, sigma, (n, 1)) * np.array([-d[1], d[0]]) / np.hypot(*d)


def test_em_bic_picks_three_walls():
    # evenly spaced points: plain EM only grows a segment across gaps narrower than kappa sigma
    rng = np.random.default_rng(2)
    pts = np.concatenate([even_line((0, 0), (3, 0), 300, 0.01, rng),
                          even_line((0, 1), (3, 1), 300, 0.01, rng),
                          even_line((4, 0), (4, 3), 300, 0.01, rng)])
    res = B.em_bic(pts, sigma=0.02, k_start=1, growth=1.0, patience=3, rng=0)
    assert len(res.segments) == 3
    ks = [p['k'] for p in res.path]
    assert ks[:3] == [1, 2, 3] and len(ks) >= 5
    bic = {p['k']: p['bic'] for p in res.path}
    assert bic[3] < bic[2] < bic[1] and bic[3] < bic[4]


def test_em_rejects_bad_input():
    with pytest.raises(ValueError, match='k'):
        B.em_lines(np.zeros((10, 2)), 0, 0.02)
    with pytest.raises(ValueError, match='sigma'):
        B.em_lines(np.random.default_rng(0).random((10, 2)), 2, 0.0)


def test_scan_breaks_at_range_jumps_and_invalid_readings():
    r = np.concatenate([np.full(20, 2.0), np.full(20, 4.0), [np.nan], np.full(10, 4.0)])
    a = np.linspace(-0.5, 0.5, r.size)
    chains = B.break_at_jumps(r, a, 0.0, 10.0, jump=0.2, min_points=4)
    assert [(c[0], c[-1]) for c in chains] == [(0, 19), (20, 39), (41, 50)]


def test_iterative_end_point_fit_finds_the_corner():
    xs = np.linspace(0, 1, 21)
    chain = np.concatenate([np.column_stack([xs, 0 * xs]), np.column_stack([0 * xs[1:] + 1,
                                                                            xs[1:]])])
    assert B.iterative_end_point_fit(chain, 0.01).tolist() == [0, 20, 40]
    assert B.approx_poly(chain, 0.01, use_cv2=False).tolist() == [0, 20, 40]


def test_approx_poly_matches_cv2():
    pytest.importorskip('cv2', reason='opencv-python-headless (benchmarks/requirements.txt)')
    rng = np.random.default_rng(3)
    chain = np.cumsum(rng.normal(0, 0.05, (200, 2)), axis=0)
    for eps in (0.1, 0.3):
        assert (B.approx_poly(chain, eps).tolist()
                == B.iterative_end_point_fit(chain, eps).tolist())
    # at small tolerances cv2's float32 distances break near-ties differently
    assert abs(len(B.approx_poly(chain, 0.02)) - len(B.iterative_end_point_fit(chain, 0.02))) < 8


def test_scan_segments_and_merging_across_scans():
    from polyline_mapper.sim import LaserSpec, simulate_drive, World
    walls = np.array([[[0.0, 0.0], [6.0, 0.0]], [[6.0, 0.0], [6.0, 4.0]]])
    world = World(walls=walls, path=[(1.0, 2.0), (4.0, 2.0)])
    spec = LaserSpec(beams=361, noise=0.005, dropout=0.0)
    drive = simulate_drive(world, spec, step=0.5, rng=4)
    merger = B.SegmentMerger()
    for ranges, pose in zip(drive.ranges, drive.poses):
        s, st = B.scan_segments(ranges, spec.angles(), pose, spec.range_min, spec.range_max,
                                epsilon=0.05, use_cv2=False)
        assert len(s) >= 2 and st[:, 0].sum() > 100
        merger.add_many(s, st)
    segs = merger.segments(min_points=50)
    assert len(segs) == 2
    assert end_errors(segs, (0, 0), (6, 0)).min() < 0.6   # seen from x >= 1 only near (0, 0)
    assert np.abs(segs[..., 1][np.abs(segs[:, 0, 1] - segs[:, 1, 1]) < 0.1]).max() < 0.01


def test_merger_rules():
    def stats(seg):
        p = np.linspace(seg[0], seg[1], 50)
        return np.array([50, *p.sum(0), (p[:, 0] ** 2).sum(), (p[:, 0] * p[:, 1]).sum(),
                         (p[:, 1] ** 2).sum()])
    m = B.SegmentMerger(max_angle=5.0, max_offset=0.05, max_gap=0.1)
    for s in ([[0, 0], [2, 0]], [[1.5, 0.01], [3, 0.01]], [[3.05, 0], [4, 0]],
              [[0, 0.3], [2, 0.3]], [[5, 0], [6, 0]]):
        m.add(np.array(s, float), stats(np.array(s, float)))
    segs = m.segments()
    assert len(segs) == 3        # 0..4 joined; the parallel one 0.3 m away and the far one stay
    long_ = segs[np.argmax(np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1))]
    assert np.allclose(sorted(long_[:, 0]), [0, 4], atol=1e-3)


def test_rasterise():
    img, origin = B.rasterise(np.array([[0.0, 0.0], [0.26, 0.0], [0.26, 0.11]]), cell=0.05)
    assert img.dtype == np.uint8 and img.sum() == 3 * 255
    assert np.allclose(origin, [-0.05, -0.05])
    assert img[1, 1] == 255 and img[1, 6] == 255 and img[3, 6] == 255


def test_wall_scores_hand_made():
    walls = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]]], float)
    segs = np.array([[[0.2, 0.03], [3.8, 0.03]],     # 90 % of wall 0: found
                     [[4.0, 0.0], [4.0, 1.5]],       # 50 % of wall 1: correct but not found
                     [[10, 10], [11, 10]]], float)   # nowhere near a wall
    s = B.wall_scores(segs, walls)
    assert (s['found'], s['walls']) == (1, 2)
    assert s['recall'] == pytest.approx(0.5) and s['precision'] == pytest.approx(2 / 3)
    assert s['f1'] == pytest.approx(4 / 7)
    assert s['end_error_median'] == pytest.approx(np.hypot(0.2, 0.03), abs=1e-9)
    assert B.wall_scores(segs[:0], walls)['f1'] == 0.0
    # a segment 0.15 m off the wall finds nothing and is wrong
    off = B.wall_scores(np.array([[[0, 0.15], [4, 0.15]]], float), walls)
    assert off['found'] == 0 and off['precision'] == 0.0


def test_walls_are_cut_at_t_junctions():
    walls = np.array([[[0, 0], [10, 0]], [[4, 0], [4, 3]]], float)
    pieces, parent = B.split_at_junctions(walls)
    assert parent.tolist() == [0, 0, 1]
    assert np.allclose(pieces[:2], [[[0, 0], [4, 0]], [[4, 0], [10, 0]]])
    # one long segment along the whole outer wall finds both of its pieces
    s = B.wall_scores(np.array([[[0, 0], [10, 0]]], float), walls)
    assert s['found'] == 2 and s['end_error_median'] == pytest.approx(0.0)


def test_pieces_no_scan_saw_are_not_counted():
    # The outer wall is seen from x = 0 to 4 only (the stretch behind the cross wall is hidden);
    # the cross wall is seen whole. Given the points, the hidden piece is not a wall to find.
    walls = np.array([[[0, 0], [10, 0]], [[4, 0], [4, 3]]], float)
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 4, 400)
    y = rng.uniform(0, 3, 300)
    points = np.concatenate([np.c_[x, rng.normal(0, 0.01, x.size)],
                             np.c_[4 + rng.normal(0, 0.01, y.size), y]])
    segs = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]]], float)
    all_pieces = B.wall_scores(segs, walls)
    assert (all_pieces['found'], all_pieces['walls']) == (2, 3)
    seen = B.wall_scores(segs, walls, points=points)
    assert (seen['found'], seen['walls']) == (2, 2) and seen['f1'] == pytest.approx(1.0)


def test_cluttered_room_is_a_valid_world():
    world = B.cluttered_room()
    assert world.walls.shape[1:] == (2, 2) and len(world.walls) == 26 and len(world.arcs) == 10
    d = world.distance(np.array(world.path, float))
    assert d.min() > 0.5      # the drive keeps clear of every obstacle
