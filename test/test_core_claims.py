"""
Documented behaviours of the numeric core, one small case each.

A mutation audit (2026-12-02: 103 hand-made mutants of polyline_mapper/core, 35 survived the
fast test files) found these claims of docstrings untested: breaking each left every test
green. Each case below fails with its mutant (named in the comment) and runs in well under a
second.
"""

import numpy as np
from polyline_mapper.core.cleanup import corner_chords, seen_through
from polyline_mapper.core.emsf import emsf_step
from polyline_mapper.core.geometry import lengths, wrap_angle
from polyline_mapper.core.grid import rasterise, UNKNOWN
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.core.index import PointIndex
from polyline_mapper.core.loops import chain, corrections
from polyline_mapper.core.memory import clearly_free
from polyline_mapper.core.merge import merge_segments, noise_stubs
from polyline_mapper.core.metrics import map_metrics, trajectory_error, twin_fraction
from polyline_mapper.core.noise import scan_spacing
from polyline_mapper.core.polylines import assemble_polylines
from polyline_mapper.core.register import match_scan, search_after_gap
from polyline_mapper.core.smemsf import fit, free_space_cut, SMEMSFConfig
from polyline_mapper.core.split import cut_squares, free_squares, split_segments, square_layout
import pytest


def corner(rng, n=300, noise=0.002):
    """Two walls meeting at (4, 0), ``n`` points each."""
    t = rng.uniform(0.0, 1.0, n)
    return np.concatenate([np.c_[4 * t, rng.normal(0.0, noise, n)],
                           np.c_[4 + rng.normal(0.0, noise, n), 3 * t]])


# -- merging -------------------------------------------------------------------------------

def test_a_gap_longer_than_r_without_points_is_not_merged_across():
    # merge.py: a gap longer than r must be backed by data (mutant: 4 r)
    r, sigma = 0.025, 0.01
    gap = 3.5 * r
    x = np.concatenate([np.arange(0.0, 1.0001, 0.002), np.arange(1 + gap, 2.0001, 0.002)])
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1 + gap, 0.0], [2.0, 0.0]]])
    out, _, merges = merge_segments(PointIndex(np.c_[x, np.zeros_like(x)]), segs,
                                    np.array([500.0, 500.0]), sigma, r)
    assert merges == 0 and len(out) == 2


def test_a_noise_stub_must_be_4_times_shorter_than_the_wall_it_crosses():
    # merge.noise_stubs: a 4 cm piece across a 10 cm one is no stub of it (mutant: 1x)
    segs = np.array([[[0.0, 0.0], [0.10, 0.0]], [[0.05, -0.02], [0.05, 0.02]]])
    assert noise_stubs(segs, 0.04, 0.10, 3.0).tolist() == [False, False]


# -- LSS and the free-space squares -------------------------------------------------------

def test_a_square_is_expected_to_hold_what_its_8_flanking_squares_do():
    # split.py: the expected support of a square is the larger mean of the 8 squares before
    # and after it. An empty square between 5 sparse ones (3 points) and 10 dense ones (100)
    # on each side expects (3 x 100 + 5 x 3) / 8 = 39 points: a gap (mutant: 3 flanks, 3).
    xs = []
    for i, n in [(i, 100) for i in range(10)] + [(i, 3) for i in range(10, 15)] \
            + [(i, 3) for i in range(16, 21)] + [(i, 100) for i in range(21, 31)]:
        xs.append(0.1 * i + (np.arange(n) + 0.5) * 0.1 / n)
    x = np.concatenate(xs)
    out, _ = split_segments(PointIndex(np.c_[x, np.zeros_like(x)]),
                            np.array([[[0.0, 0.0], [3.1, 0.0]]]), r=0.05)
    np.testing.assert_allclose(out[:, :, 0], [[0.0, 1.0], [2.1, 3.1]], atol=1e-9)


def test_a_square_is_free_when_passes_exceed_hits_not_equal_them():
    # split.free_squares: passes >= min_passes and > hits (mutant: >= hits)
    assert free_squares(np.array([[3.0, 3.0], [2.0, 3.0], [4.0, 4.0]])).tolist() == \
        [False, True, False]


def test_a_segment_has_round_length_over_2r_squares_and_comes_back_whole():
    # split.square_layout: n_sub = max(1, round(L / 2r)) (mutant: ceil); cut_squares keeps a
    # segment whose squares all stay bit for bit (mutant: rebuilt from its squares)
    n_sub, _ = square_layout(np.array([[[0.0, 0.0], [0.13, 0.0]], [[0.0, 0.0], [0.17, 0.0]]]),
                             0.05)
    assert n_sub.tolist() == [1, 2]
    segs = np.random.default_rng(0).uniform(-7.0, 7.0, (50, 2, 2))
    n_sub, _ = square_layout(segs, 0.05)
    pieces, _, _, _ = cut_squares(segs, n_sub, np.ones(int(n_sub.sum()), bool))
    assert np.array_equal(pieces, segs)


def test_pieces_the_free_space_cut_leaves_need_min_support():
    # smemsf.free_space_cut: pieces keep their share of the support and need min_support. A
    # 1 m segment of support 6 seen through in its middle: the two pieces of 0.6 fall (mutant:
    # kept).
    seg = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    px = np.linspace(-0.3, 1.3, 161)
    pts = np.c_[px, np.ones_like(px)]
    origins = np.broadcast_to([0.5, -1.0], pts.shape).copy()
    out, sup, cut = free_space_cut(seg, np.array([6.0]), pts, origins, r=0.05, tol=0.03,
                                   min_support=4.0)
    assert cut == 8 and len(out) == 0 and len(sup) == 0


def test_a_new_square_starts_from_its_cell_only_where_passes_are_twice_the_hits():
    # memory.CLEAR: passes 1.5 x the hits seed nothing (mutant 1.0: they do); nothing stored
    # (0, 0) starts at nothing either way
    counts = np.array([[2.0, 3.0], [2.0, 4.0], [0.0, 0.5], [0.0, 0.0], [1.0, 0.0]])
    assert clearly_free(counts).tolist() == [False, True, True, True, False]


# -- EM and the fit ------------------------------------------------------------------------

def test_trimming_asks_min_density_of_every_segment():
    # emsf_step with min_density: 11 points over 2 m (0.55 per 2r) are no segment, 200 over
    # 1 m are (mutant: the density test dropped)
    sparse = np.c_[np.linspace(0.0, 2.0, 11), np.zeros(11)]
    dense = np.c_[np.linspace(0.0, 1.0, 200), np.ones(200)]
    segs = np.array([[[0.0, 0.0], [2.0, 0.0]], [[0.0, 1.0], [1.0, 1.0]]])
    out, sup, _ = emsf_step(PointIndex(np.concatenate([sparse, dense])), segs, sigma=0.01,
                            kappa=3.0, min_support=4.0, min_density=1.0, r=0.05)
    assert len(out) == 1 and sup.tolist() == [200.0]


@pytest.mark.parametrize('key', ['split_fraction', 'gap_p'])
def test_split_fraction_and_gap_p_stay_below_1(key):
    # (mutants: split_fraction 1 accepted; the gap_p < 1 check skipped)
    with pytest.raises(ValueError, match=f'{key} must be in'):
        SMEMSFConfig(**{key: 1.0})


def test_the_noise_floor_is_never_below_sigma_min():
    # a given sigma under sigma_min is raised to it (mutant: sigma taken as given)
    res = fit(corner(np.random.default_rng(0)), SMEMSFConfig(sigma=0.001, sigma_min=0.005))
    assert res.sigma == 0.005


def test_a_fit_with_beams_runs_three_evidence_rounds():
    # smemsf.EVIDENCE_ROUNDS (3, as the README and benchmarks/README.md say; mutant: 1)
    rng = np.random.default_rng(0)
    res = fit(corner(rng, 200, 0.01), origins=np.array([2.0, 1.5]))
    assert sum('free_squares' in h for h in res.history) == 3 and res.beams == 400


# -- cleanup -------------------------------------------------------------------------------

def test_a_short_segment_is_seen_through_only_by_min_beams_beams():
    # cleanup.seen_through: at least min_beams (3) beams must pass (mutant: 1)
    seg = np.array([[[0.0, 0.0], [0.5, 0.0]]])
    origin = np.array([0.25, -1.0])
    two = np.array([[-0.05, 1.0], [0.55, 1.0]])
    assert seen_through(seg, origin, two, 0.03).tolist() == [False]
    three = np.array([[-0.05, 1.0], [0.25, 1.0], [0.55, 1.0]])
    assert seen_through(seg, origin, three, 0.03).tolist() == [True]


def test_a_corner_chord_joins_two_different_walls_not_one_wall_to_itself():
    # cleanup.corner_chords spares short clutter pieces beside a single wall (mutant: both
    # ends on the same wall count)
    segs = np.array([[[0.0, 0.0], [4.0, 0.0]], [[0.0, 0.0], [0.0, 3.0]],
                     [[2.0, -0.02], [2.02, 0.02]]])
    x = np.linspace(0.0, 4.0, 400)
    chords = corner_chords(PointIndex(np.c_[x, np.zeros_like(x)]), segs, reach=0.03, near=0.02,
                           short=0.2, min_angle=np.deg2rad(20))
    assert chords.tolist() == [False, False, False]


# -- the grid, noise and metrics -----------------------------------------------------------

def test_the_grid_covers_the_bounding_box_plus_one_cell():
    # grid.rasterise (mutant: no padding)
    g = rasterise(np.array([[[0.0, 0.0], [1.0, 0.0]]]), 0.1)
    assert np.allclose(g.origin, (-0.1, -0.1)) and (g.width, g.height) == (13, 3)
    assert (g.data[0] == UNKNOWN).all() and (g.data[-1] == UNKNOWN).all()


def test_the_grid_refuses_a_resolution_under_1_mm_and_more_cells_than_max_cells():
    # grid.check_resolution: [0.001, 100] m (mutant: 1e-6); rasterise: more than max_cells
    # cells is a ValueError (mutant: no check): 100 copies of a 4.2 m diagonal at 5 cm
    with pytest.raises(ValueError, match=r'grid resolution must be in \[0.001, 100\] m'):
        rasterise(np.array([[[0.0, 0.0], [1.0, 0.0]]]), 1e-4)
    segs = np.repeat(np.array([[[0.0, 0.0], [3.0, 3.0]]]), 100, axis=0)
    with pytest.raises(ValueError, match='use a coarser resolution'):
        rasterise(segs, 0.05, max_cells=64 * 64)


def test_the_scan_spacing_is_at_most_24_times_the_lower_quartile():
    # noise.SPACING_SPREAD: 30 points 1 cm apart and 30 points 0.5 m apart (mutant: 1000)
    x = np.concatenate([np.arange(0.0, 0.30, 0.01), 10 + np.arange(30) * 0.5])
    assert scan_spacing(np.c_[x, np.zeros_like(x)], ordered=True) == pytest.approx(0.24)


def test_pieces_of_one_wall_end_to_end_are_no_twins():
    # metrics.twin_fraction counts overlapping parallels only (mutant: overlap not asked)
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.05, 0.0], [2.0, 0.0]]])
    assert twin_fraction(segs) == 0.0


def test_compression_is_points_over_twice_the_segments():
    x = np.linspace(0.0, 2.0, 100)
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [2.0, 0.0]]])
    assert map_metrics(np.c_[x, np.zeros(100)], segs)['compression'] == 25.0   # (mutant: 50)


def test_the_final_trajectory_error_is_the_last_pose_s():
    ref = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    est = ref + [[0.0, 0.0], [0.5, 0.0], [0.1, 0.0]]
    assert trajectory_error(est, ref)['final'] == pytest.approx(0.1)     # (mutant: the largest)


def test_two_segments_join_at_their_corner_within_the_corner_reach():
    # polylines.assemble_polylines: ends 0.1 m from their corner join at join 0.05 through
    # corner_reach 4 (mutant: 1, two polylines)
    segs = np.array([[[0.0, 0.0], [0.9, 0.0]], [[1.0, 0.1], [1.0, 1.0]]])
    ch = assemble_polylines(segs, join=0.05)
    assert len(ch.polylines) == 1
    np.testing.assert_allclose(ch.polylines[0], [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]],
                               atol=1e-9)


# -- the incremental mapper ----------------------------------------------------------------

def test_virtual_points_weigh_at_most_virtual_cap():
    _, w = IncrementalMapper()._virtual_points(np.array([[[0.0, 0.0], [1.0, 0.0]]]),
                                               np.array([1e6]), 0.05)
    assert w.max() == 10.0                                            # (mutant: 9e4)


def test_r_follows_at_most_2_percent_of_the_mapping_range():
    # incremental.SPACING_RANGE_SHARE: points 1 m apart within max_mapping_range 10 m set
    # the spacing to 0.2 m, so r to 0.1 m (mutant: 0.5 m)
    m = IncrementalMapper(IncrementalConfig(max_mapping_range=10.0))
    x = np.arange(0.0, 9.0, 1.0)
    m.update(np.c_[x, np.full_like(x, 0.5)], ordered=True)
    assert m.r == pytest.approx(0.1)


def test_the_support_stays_capped_without_free_space_evidence():
    # IncrementalMapper.support is the accumulated, capped weight: virtual_cap per 2r
    # (free_space_window 0; mutant: uncapped, 1.47 of the cap)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    c, s = np.cos(angles), np.sin(angles)
    rng = np.random.default_rng(0)
    m = IncrementalMapper(IncrementalConfig(free_space_window=0))
    for x in np.tile(np.linspace(1.0, 3.0, 8), 3):
        with np.errstate(divide='ignore'):
            ranges = np.minimum(np.where(c > 0, 4.0 - x, -x) / c, np.where(s > 0, 1.5, -1.5) / s)
        m.update_scan(ranges + rng.normal(0.0, 0.01, 360), angles, (x, 1.5, 0.0), range_max=10.0)
    cap = m.config.virtual_cap * np.maximum(lengths(m.segments) / (2 * m.r), 1.0)
    assert len(m.segments) >= 4 and (m.support / cap).max() <= 1.0


# -- registration and loops ----------------------------------------------------------------

def test_a_match_that_explains_fewer_points_than_the_prediction_is_not_taken():
    # register._refine: 100 points on a wall and 100 clutter points 0.3 m in front of it; one
    # Gauss-Newton step pulls toward the clutter, which explains fewer (mutant: taken, 5.7 cm)
    wall = np.array([[[-5.0, 0.0], [5.0, 0.0]]])
    x = np.linspace(-3.0, 3.0, 100)
    pts = np.concatenate([np.c_[x, np.full(100, -1.0)], np.c_[x, np.full(100, -0.7)]])
    m = match_scan(pts, np.array([0.0, 1.0, 0.0]), wall, sigma=0.01, iterations=1)
    assert m.ok
    np.testing.assert_allclose(m.pose, [0.0, 1.0, 0.0], atol=1e-3)


def test_the_prediction_gives_way_only_to_a_start_scoring_clearly_higher():
    # register.START_MARGIN: a start 5 cm off scores below the prediction (mutant: >= 0.9 x)
    walls = np.array([[[-5.0, 0.0], [5.0, 0.0]], [[5.0, 0.0], [5.0, 5.0]]])
    pts = np.concatenate([np.c_[np.linspace(-3.0, 3.0, 100), np.full(100, -1.0)],
                          np.c_[np.full(60, 5.0), np.linspace(0.2, 3.0, 60) - 1.0]])
    m = match_scan(pts, np.array([0.0, 1.0, 0.0]), walls, sigma=0.01, iterations=0,
                   starts=np.array([[0.0, 1.05, 0.0]]))
    np.testing.assert_allclose(m.pose, [0.0, 1.0, 0.0], atol=1e-3)


def rotated(xy, angle):
    """``xy`` (N, 2) turned by ``angle`` (rad) about the origin."""
    c, s = np.cos(angle), np.sin(angle)
    return xy @ np.array([[c, s], [-s, c]])


@pytest.mark.parametrize('n_turned, turned', [(42, False), (48, True)])
def test_the_heading_search_leaves_the_prediction_only_for_a_turn_scoring_1_1_times_more(
        n_turned, turned):
    # register.TURN_MARGIN: 40 points on a wall at the predicted heading; 42 (1.05 x) or 48
    # (1.2 x) on a second wall that the map holds 0.15 rad turned (mutant 1.0: 42 turn it)
    x = 5.0 + 3.0 * np.linspace(0.0, 1.0, 40)
    pts = np.concatenate([np.c_[5.0 + 3.0 * np.linspace(1.0, 0.0, n_turned),
                                np.full(n_turned, -1.0)], np.c_[x, np.full(40, 1.0)]])
    walls = np.stack([[[4.5, 1.0], [8.5, 1.0]],
                      rotated(np.array([[4.5, -1.0], [8.5, -1.0]]), 0.15)])
    m = match_scan(pts, np.zeros(3), walls, sigma=0.01)
    assert m.ok
    np.testing.assert_allclose(m.pose, [0.0, 0.0, 0.15 if turned else 0.0], atol=1e-3)


@pytest.mark.parametrize('counts, moved', [((21, 34, 45), False), ((21, 24, 55), True)])
def test_a_relocalized_pose_needs_1_5_times_the_share_on_the_map(counts, moved):
    # register.RELOCALIZE_GAIN: a long wall matches at either pose, a face at x = 3 at the
    # prediction, one at x = 6 (the map's x = 7) 1 m on. 55 % against 66 % (1.2 x) keeps the
    # prediction, 45 % against 76 % (1.7 x) moves (mutant 1.0: 1.2 x moves)
    n_w, n_a, n_b = counts
    pts = np.concatenate([np.c_[np.linspace(-4.0, 4.0, n_w), np.full(n_w, -2.0)],
                          np.c_[np.full(n_a, 3.0), np.linspace(0.0, 1.5, n_a)],
                          np.c_[np.full(n_b, 6.0), np.linspace(2.0, 3.5, n_b)]])
    walls = np.array([[[-20.0, -2.0], [20.0, -2.0]], [[3.0, -0.2], [3.0, 1.7]],
                      [[7.0, 1.8], [7.0, 3.7]]])
    m = match_scan(pts, np.zeros(3), walls, sigma=0.01, relocalize=1.5)
    assert m.ok and m.relocalized == moved
    np.testing.assert_allclose(m.pose, [1.0 if moved else 0.0, 0.0, 0.0], atol=1e-3)


def test_the_default_kernel_keeps_a_radiator_before_a_quarter_of_a_wall_from_pulling_the_match():
    # register.match_scan: Cauchy kernel 2 sigma by default. A quarter of one wall's points
    # lie 3.5 sigma in front of it; the match stays within half a sigma (mutants 4 and 6 sigma:
    # 0.61-0.70 and 0.73-0.81 sigma off along x over 20 seeds; the default 0.28-0.38 sigma)
    rng = np.random.default_rng(0)
    sigma, n = 0.02, 120
    x = np.full(n, 4.0)
    x[:n // 4] -= 3.5 * sigma
    pts = np.concatenate([np.c_[x, rng.uniform(-2.0, 2.0, n)],
                          np.c_[rng.uniform(-2.0, 4.0, n), np.full(n, 3.0)]])
    pts += rng.normal(0.0, 0.005, pts.shape)
    walls = np.array([[[4.0, -2.5], [4.0, 3.0]], [[-2.5, 3.0], [4.0, 3.0]]])
    m = match_scan(pts, np.array([0.03, -0.02, 0.0]), walls, sigma=sigma)
    assert m.ok
    assert np.hypot(*m.pose[:2]) < 0.5 * sigma and abs(m.pose[2]) < 0.002


def test_poses_searched_after_a_gap_are_distinct():
    # register.search_after_gap: at least 0.5 m or 0.3 rad apart (mutant: 0.05 m / 0.03 rad)
    room = np.array([[[0, 0], [4, 0]], [[4, 0], [4, 3]], [[4, 3], [0, 3]], [[0, 3], [0, 0]]],
                    float)
    a = np.linspace(-np.pi, np.pi, 120, endpoint=False)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide='ignore'):
        rr = np.minimum(np.abs(2.0 / c), np.abs(1.5 / s))
    poses = search_after_gap(np.c_[rr * c, rr * s], room, (2.0, 1.5, 0.0), radius=1.0)
    assert len(poses) >= 2
    for i, p in enumerate(poses):
        for q in poses[:i]:
            assert np.hypot(*(p[:2] - q[:2])) > 0.5 or abs(wrap_angle(p[2] - q[2])) > 0.3


def test_loop_chain_covariance_has_a_floor_and_corrections_unwrap_the_yaw():
    # loops.chain: at least the floor for a 1 mm step (mutant: 1e-4 m); loops.corrections
    # interpolates the unwrapped yaw: 3.1 and -3.1 rad meet at pi, not 0 (mutant: 0)
    e = chain(np.array([[0.0, 0.0, 0.0], [0.001, 0.0, 0.0]]))
    np.testing.assert_allclose(np.sqrt(np.diag(e[0].cov)), [0.01, 0.01, 0.02], atol=1e-4)
    before = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    after = np.array([[0.0, 0.0, 3.1], [1.0, 0.0, -3.1]])
    yaw = corrections(before, after, np.array([0.0, 1.0]), np.array([0.5]))[0, 2]
    assert abs(abs(wrap_angle(yaw)) - np.pi) < 1e-6
