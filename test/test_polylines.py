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


def test_collinear_ends_meet_at_midpoint_and_far_ends_stay_apart():
    segs = np.array([[[0, 0], [1, 0]], [[1.04, 0], [2, 0]], [[5, 5], [6, 5]]], dtype=float)
    _, polys, closed = assemble_polylines(segs, join=0.1)
    assert sorted(len(p) for p in polys) == [2, 3]
    chain = [p for p in polys if len(p) == 3][0]
    np.testing.assert_allclose(chain[1], [1.02, 0.0])
    assert closed == [False, False]


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
