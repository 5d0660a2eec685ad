"""Polyline assembly: chains, corners at line intersections, closed loops."""

import numpy as np

from polyline_mapper.core.polylines import assemble_polylines


def test_square_becomes_one_closed_polyline_with_exact_corners():
    # Four sides whose ends stop a little short of the corners, as fitted segments do.
    e = 0.02
    segs = np.array([[[e, 0], [2 - e, 0]], [[2, e], [2, 2 - e]],
                     [[2 - e, 2], [e, 2]], [[0, 2 - e], [0, e]]])
    out, polys, closed = assemble_polylines(segs, join=0.1)
    assert len(polys) == 1 and closed == [True]
    verts = {tuple(np.round(v, 9)) for v in polys[0]}
    assert verts == {(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)}
    assert len(out) == 4


def test_collinear_ends_meet_at_the_length_weighted_point_and_far_ends_stay_apart():
    segs = np.array([[[0, 0], [1, 0]], [[1.04, 0], [2, 0]], [[5, 5], [6, 5]]], dtype=float)
    _, polys, closed = assemble_polylines(segs, join=0.1)
    assert sorted(len(p) for p in polys) == [2, 3]
    chain = [p for p in polys if len(p) == 3][0]
    np.testing.assert_allclose(chain[1], [(1.0 * 1.0 + 0.96 * 1.04) / 1.96, 0.0])
    assert closed == [False, False]


def test_a_short_piece_joined_straight_does_not_tilt_a_long_wall():
    # An 8 m wall and a 0.28 m piece 2 deg off its line, 1 cm below its end (an arc's first
    # chord, say): the wall's end moves by the piece's share of the gap, 0.34 mm, not by half
    # of it (5 mm with the midpoint, a 0.036 deg tilt over the whole wall).
    wall = [[0.0, 0.0], [8.0, 0.0]]
    piece = [[8.02, -0.01], [8.30, -0.02]]
    out, polys, _ = assemble_polylines(np.array([wall, piece]), join=0.05)
    assert len(polys) == 1 and len(polys[0]) == 3
    np.testing.assert_allclose(out[0, 0], wall[0])
    share = np.hypot(0.28, 0.01) / (8.0 + np.hypot(0.28, 0.01))
    np.testing.assert_allclose(out[0, 1], np.array([8.0, 0.0]) + share * np.array([0.02, -0.01]))
    assert abs(out[0, 1, 1]) < 4e-4
    np.testing.assert_allclose(out[1, 0], out[0, 1])


def test_every_segment_in_exactly_one_polyline():
    rng = np.random.default_rng(0)
    segs = rng.uniform(0, 5, (60, 2, 2))
    _, polys, closed = assemble_polylines(segs, join=0.3)
    edges = sum(len(p) - 1 + int(c) for p, c in zip(polys, closed))
    assert edges == 60


def test_corner_join_does_not_cut_a_wall_back_past_its_points():
    # A wall to x = 4 and a crossing segment whose line meets it 0.2 m before its end (within
    # the corner reach): joining would cut off 0.2 m of wall, farther from the other line than
    # join / 2, so they stay apart. A corner that overshoots by less is still joined.
    join = 0.1
    wall = [[0.0, 0.0], [4.0, 0.0]]
    crossing = [[3.8, 0.05], [3.8, 1.0]]
    out, polylines, _ = assemble_polylines(np.array([wall, crossing]), join)
    np.testing.assert_allclose(out[0], wall)
    assert len(polylines) == 2
    overshooting = [[0.0, 0.0], [4.03, 0.0]]
    corner = [[4.0, 0.02], [4.0, 1.0]]
    out, polylines, _ = assemble_polylines(np.array([overshooting, corner]), join)
    np.testing.assert_allclose(out[0, 1], [4.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[1, 0], [4.0, 0.0], atol=1e-12)
    assert len(polylines) == 1


def test_segments_keep_their_input_order_and_each_end_moves_at_most_the_corner_reach():
    """The i-th output segment is the i-th input segment (what aligns support with it)."""
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 10, (300, 2))
    segs = np.stack([a, a + rng.normal(0, 0.5, (300, 2))], axis=1)
    join = 0.1
    chains = assemble_polylines(segs, join)
    assert chains.segments.shape == segs.shape
    moved = np.linalg.norm(chains.segments - segs, axis=2)
    # an end moves to a corner within join * max(corner_reach, 1 / sin(min_angle)), else stays
    assert moved.max() <= join / np.sin(np.deg2rad(5.0)) + 1e-9
    assert (moved == 0).any() and (moved > 0).any()
    own = np.linalg.norm(chains.segments[:, None] - segs[None], axis=3).sum(axis=2)
    assert (np.argmin(own, axis=1) == np.arange(len(segs))).mean() > 0.99
    assert chains == tuple(chains) and len(chains.polylines) == len(chains.closed)
