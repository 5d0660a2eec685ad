"""Free-space evidence per LSS square: beam counts, the removal rule, the carry through refits."""

import numpy as np
from polyline_mapper.core import fit
from polyline_mapper.core.cleanup import beam_evidence
from polyline_mapper.core.incremental import IncrementalConfig, IncrementalMapper
from polyline_mapper.core.split import (accumulate_evidence, carry_evidence, cut_squares,
                                        EVIDENCE_CAP, free_squares, square_centres,
                                        square_layout)
import pytest


def test_beams_are_counted_per_square():
    # A 1 m wall on y = 0 in 4 squares of 0.25 m, the laser 1 m below its middle.
    wall = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    n_sub, sub_len = square_layout(wall, 0.125)
    assert n_sub.tolist() == [4] and sub_len == pytest.approx([0.25])
    origin = np.array([0.5, -1.0])
    points = np.array([
        [0.30, 0.001], [0.35, -0.002],      # end on square 1: hits
        [1.20, 1.00], [1.60, 2.00],         # go through square 3 far beyond: passes
        [0.60, 0.05],                       # through square 2 but within the noise margin
        [0.10, -0.50],                      # ends before the wall: says nothing
        [-3.00, 0.10],                      # crosses the line outside the wall
    ])
    hits, passes = beam_evidence(wall, n_sub, origin, points, tol=0.03)
    assert hits.tolist() == [0, 2, 0, 0]
    assert passes.tolist() == [0, 0, 0, 2]
    # the margin grows with range: a return 0.1 m beyond the wall at 1 m passes, but the same
    # 0.1 m at 10 m does not (0.03 + 0.03 x range)
    near = beam_evidence(wall, n_sub, origin, np.array([[0.55, 0.1]]), tol=0.03)[1]
    assert near.sum() == 1
    far_origin = np.array([0.5, -10.0])
    far = beam_evidence(wall, n_sub, far_origin, np.array([[0.55, 0.1]]), tol=0.03)[1]
    assert far.sum() == 0
    # grazing beams (< 20 degrees to the wall) are not counted
    graze = beam_evidence(wall, n_sub, np.array([-3.0, -0.5]), np.array([[3.0, 0.55]]),
                          tol=0.03)
    assert graze[0].sum() == 0 and graze[1].sum() == 0


def test_with_a_hit_margin_returns_the_margin_cannot_tell_from_the_wall_are_hits():
    # A 1 m wall on y = 0 in 4 squares, the laser 2 m below its middle; tol 3 cm, hit margin
    # 3 cm + 0.03 x range (about 9 cm here).
    wall = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    n_sub, _ = square_layout(wall, 0.125)
    origin = np.array([0.5, -2.0])
    points = np.array([
        [0.10, 0.08],           # 8 cm beyond square 0: inside the margin
        [0.40, -0.07],          # 7 cm before square 1
        [0.62, 0.02],           # on square 2
        [1.02, 0.01],           # past the wall's end: abreast of nothing
        [0.80, 0.20],           # 20 cm beyond square 3: a pass, no hit
    ])
    crossing = beam_evidence(wall, n_sub, origin, points, tol=0.03)
    assert crossing[0].tolist() == [0, 0, 1, 0] and crossing[1].tolist() == [0, 0, 0, 1]
    hits, passes = beam_evidence(wall, n_sub, origin, points, tol=0.03, hit_range_tol=0.03)
    assert hits.tolist() == [1, 1, 1, 0] and passes.tolist() == [0, 0, 0, 1]
    # a beam along the wall (6 degrees) ending on it is a hit with the margin, never a pass
    graze = (np.array([-2.0, -0.25]), np.array([[0.7, 0.02]]))
    assert beam_evidence(wall, n_sub, *graze, tol=0.03)[0].sum() == 0
    assert beam_evidence(wall, n_sub, *graze, tol=0.03, hit_range_tol=0.03)[0].tolist() == \
        [0, 0, 1, 0]
    # hits count over the stretch passes count on: not within tol of an end
    edge = beam_evidence(wall, n_sub, origin, np.array([[0.01, 0.0], [0.99, 0.0]]), tol=0.03,
                         hit_range_tol=0.03)
    assert edge[0].sum() == 0
    with pytest.raises(ValueError, match='free_space_hit_margin'):
        IncrementalConfig(free_space_hit_margin=-0.01)


def test_a_wall_hit_many_times_needs_many_passes():
    counts = np.zeros((2, 2))
    for _ in range(30):                     # a wall seen well: 8 hits a scan on both squares
        counts = accumulate_evidence(counts, np.array([8, 8]), np.array([0, 0]), window=10)
    assert counts[:, 0].tolist() == [EVIDENCE_CAP, EVIDENCE_CAP]     # bounded
    # one scan seeing through square 0 does not free it ...
    one = accumulate_evidence(counts, np.array([0, 5]), np.array([8, 0]), window=10)
    assert not free_squares(one).any()
    # ... a few scans that keep seeing through it (the door opened) do; square 1 stays
    scans = 0
    while not free_squares(counts)[0] and scans <= 10:     # bounded: without decay it hung
        counts = accumulate_evidence(counts, np.array([0, 5]), np.array([8, 0]), window=10)
        scans += 1
    assert 3 <= scans <= 10 and free_squares(counts)[0] and not free_squares(counts)[1]
    # an unobserved square keeps its evidence: a wall out of view is not forgotten
    same = accumulate_evidence(counts, np.array([0, 0]), np.array([0, 0]), window=10)
    assert np.array_equal(same, counts)
    # a few passes alone are not enough
    assert not free_squares(np.array([[0.0, 2.0]])).any()
    assert free_squares(np.array([[0.0, 3.0]])).all()


def test_free_squares_are_cut_out():
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]], [[0.0, 1.0], [0.0, 2.0]]])
    n_sub = np.array([4, 2])
    keep = np.array([True, False, True, True, True, True])
    pieces, parent, first, last = cut_squares(segs, n_sub, keep)
    assert np.allclose(pieces, [[[0, 0], [0.25, 0]], [[0.5, 0], [1, 0]], [[0, 1], [0, 2]]])
    assert parent.tolist() == [0, 0, 1] and first.tolist() == [0, 2, 4]
    assert last.tolist() == [0, 3, 5]
    assert pieces[2] is not segs[1] and np.array_equal(pieces[2], segs[1])   # bit for bit
    none = cut_squares(segs, n_sub, np.zeros(6, dtype=bool))
    assert none[0].shape == (0, 2, 2) and none[1].size == 0


def test_evidence_follows_splits_merges_and_moves():
    old = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.05, 0.01], [2.0, 0.01]]])
    n_old, _ = square_layout(old, 0.125)
    centre, direction = square_centres(old, n_old)
    counts = np.stack([np.arange(n_old.sum()), 100 + np.arange(n_old.sum())], axis=1) * 1.0
    # merged into one segment, moved 1 cm: each new square takes its old square's counts
    merged = np.array([[[0.0, 0.005], [2.0, 0.005]]])
    n_new, _ = square_layout(merged, 0.125)
    got = carry_evidence(centre, direction, counts, merged, n_new, 0.125)
    assert got.shape == (8, 2) and np.array_equal(got[:4], counts[:4])
    # split: the piece gets the squares it keeps; a crossing wall takes nothing
    piece = np.array([[[0.5, 0.0], [1.0, 0.0]], [[0.6, -1.0], [0.6, 1.0]]])
    n_p = np.array([2, 8])
    got = carry_evidence(centre, direction, counts, piece, n_p, 0.125)
    assert np.array_equal(got[:2], counts[2:4]) and not got[2:].any()


def test_the_mapper_cuts_a_doorway_into_a_long_wall_seen_through():
    # A 6 m wall y = 2 is mapped; then the middle metre is gone (a door opened) and the laser
    # sees through it to a wall at y = 4. The wall splits at the doorway and its ends stay.
    rng = np.random.default_rng(4)
    angles = np.linspace(0.1, np.pi - 0.1, 361)

    def scan(x, door_open):
        c, s = np.cos(angles), np.sin(angles)
        r = 2.0 / s
        hx = x + r * c
        through = door_open & (hx > 2.5) & (hx < 3.5)
        r = np.where(through | (hx < 0) | (hx > 6), 4.0 / s, r)
        return np.minimum(r, 8.0) + rng.normal(0, 0.005, angles.size)

    for window, cut in ((10, True), (0, False)):
        mapper = IncrementalMapper(IncrementalConfig(free_space_window=window))
        for i in range(40):
            x = 1.0 + 4.0 * (i % 20) / 19
            mapper.update_scan(scan(x, i >= 20), angles, (x, 0.0, 0.0), range_max=10.0)
        segs = mapper.segments
        on_wall = segs[np.all(np.abs(segs[:, :, 1] - 2.0) < 0.05, axis=1)]
        xs = np.sort(on_wall[:, :, 0], axis=1)
        in_door = (xs[:, 1] > 2.7) & (xs[:, 0] < 3.3)
        assert in_door.any() != cut, xs.round(2).tolist()
        if cut:
            assert xs[:, 0].min() < 0.6 and xs[:, 1].max() > 5.4      # the wall is kept
            left = xs[xs[:, 1] <= 3.0]
            assert left.size and left[:, 1].max() > 2.3                 # up to the door jamb


def test_bad_origins_and_windows_are_rejected_by_name():
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(0, 4, 200), rng.normal(0, 0.01, 200)]
    for bad in (np.zeros((3, 2)), np.full((200, 2), np.nan), np.zeros((200, 3))):
        with pytest.raises(ValueError, match='origin'):
            fit(pts, origins=bad)
    for bad in (-2, 2.5):
        with pytest.raises(ValueError, match='free_space_window'):
            IncrementalConfig(free_space_window=bad)
    assert IncrementalConfig(free_space_window=-1).resolved().free_space_window == 10   # auto
    # bare points: the fit says that no beam was used
    res = fit(pts)
    assert res.beams == 0 and res.free_squares == 0
