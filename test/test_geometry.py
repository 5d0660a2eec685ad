"""Segment geometry and the spatial index, against brute force."""

import numpy as np
from polyline_mapper.core.geometry import as_points, lengths, project, sample_segments
from polyline_mapper.core.index import (in_sorted, nearest_distance, piece_pairs, PIECE_SCAN,
                                        PointIndex)
import pytest


def brute_distance(points, segments):
    k, n = len(segments), len(points)
    d, _, _ = project(np.repeat(points, k, axis=0), np.tile(segments, (n, 1, 1)))
    return d.reshape(n, k)


def test_project_distance_to_segment_not_line():
    seg = np.array([[[0.0, 0.0], [1.0, 0.0]]] * 4)
    pts = np.array([[0.5, 2.0], [3.0, 0.0], [-1.0, -1.0], [0.25, -0.5]])
    d, along, normal = project(pts, seg)
    np.testing.assert_allclose(d, [2.0, 2.0, np.sqrt(2.0), 0.5])
    np.testing.assert_allclose(along, [0.5, 3.0, -1.0, 0.25])
    np.testing.assert_allclose(normal, [2.0, 0.0, -1.0, -0.5])


@pytest.mark.parametrize('spacing', [3.0, 8.0])
@pytest.mark.parametrize('radius', [0.02, 0.3, 1.5, 6.0])
def test_pairs_equal_brute_force(radius, spacing):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, (3000, 2))
    segs = rng.uniform(-5, 5, (40, 2, 2))
    segs[0, 1] = segs[0, 0]                          # a zero-length segment too
    p = PointIndex(pts, sample_spacing=spacing).pairs(segs, radius)
    d = brute_distance(pts, segs)
    want = set(zip(*np.nonzero(d <= radius)))
    got = list(zip(p.pt.tolist(), p.seg.tolist()))
    assert len(got) == len(set(got)), 'pairs must be unique'
    assert set(got) == want
    np.testing.assert_allclose(p.dist, d[p.pt, p.seg], atol=1e-12)


@pytest.mark.parametrize('extend', [0.0, 0.3])
def test_piece_pairs_equal_brute_force(extend):
    # Pieces of segments (several per parent, one reaching past its parent's ends by `extend`),
    # their pairs derived from the parents' pairs, against brute force on the pieces.
    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 10, (4000, 2))
    segs = rng.uniform(0, 10, (30, 2, 2))
    length = lengths(segs)
    u = (segs[:, 1] - segs[:, 0]) / length[:, None]
    parent = rng.integers(0, 30, 60)
    t0 = rng.uniform(0, 0.6, 60) * length[parent] - extend
    t1 = t0 + extend + rng.uniform(0.05, 0.4, 60) * length[parent] + extend
    pieces = segs[parent, :1] + np.stack([t0, t1], axis=1)[:, :, None] * u[parent, None]
    radius = 0.2
    p = piece_pairs(PointIndex(pts).pairs(segs, radius + extend), parent, t0, t1 - t0, radius)
    d = brute_distance(pts, pieces)
    assert set(zip(p.pt.tolist(), p.seg.tolist())) == set(zip(*np.nonzero(d <= radius)))
    np.testing.assert_allclose(p.dist, d[p.pt, p.seg], atol=1e-12)
    _, along, normal = project(pts[p.pt], pieces[p.seg])
    np.testing.assert_allclose(p.along, along, atol=1e-12)
    np.testing.assert_allclose(p.normal, normal, atol=1e-12)


def test_nearest_distance_exact_including_far_points():
    rng = np.random.default_rng(4)
    pts = rng.uniform(-20, 20, (2000, 2))
    segs = rng.uniform(-2, 2, (15, 2, 2))
    d, j = nearest_distance(pts, segs, radius=0.5)
    bd = brute_distance(pts, segs)
    np.testing.assert_allclose(d, bd.min(axis=1), atol=1e-12)
    np.testing.assert_allclose(bd[np.arange(len(pts)), j], d, atol=1e-12)


def test_sample_segments_spacing_and_ends():
    segs = np.array([[[0, 0], [1, 0]], [[0, 1], [0, 1.05]]], dtype=float)
    s, owner = sample_segments(segs, 0.3)
    first = s[owner == 0]
    assert np.allclose(first[0], [0, 0]) and np.allclose(first[-1], [1, 0])
    assert np.diff(first[:, 0]).max() <= 0.3 + 1e-12
    assert (owner == 1).sum() == 2


@pytest.mark.parametrize('bad, why', [
    (np.zeros((3, 3)), 'shape'), (np.zeros(4), 'shape'), ([[0, np.nan]], 'NaN'),
    ([[np.inf, 0]], 'NaN or inf'), ('abc', 'numeric'),
])
def test_as_points_rejects_bad_input(bad, why):
    with pytest.raises(ValueError, match=why):
        as_points(bad)


def test_in_sorted_matches_isin():
    rng = np.random.default_rng(11)
    for n_table in (0, 1, 7, 500):
        table = np.unique(rng.integers(-50, 50, n_table))
        values = rng.integers(-60, 60, 300)
        np.testing.assert_array_equal(in_sorted(values, table), np.isin(values, table))


def test_nearest_distance_in_point_chunks_is_exact_and_bounds_memory(office_fit):
    # A cluttered map pairs each point with many segments within the radius: fr079's 1.7 M
    # points took 1.9 GB at once in the replay's final statistics. In chunks of points the
    # distances are the same and the memory is that of a chunk.
    import tracemalloc
    pts, _, result = office_fit
    pts = np.concatenate([pts] * 3)
    segs = np.concatenate([result.segments + off for off in np.linspace(-0.2, 0.2, 9)[:, None]])
    peaks, out = [], []
    for point_chunk in (len(pts), 4000):
        tracemalloc.start()
        out.append(nearest_distance(pts, segs, radius=0.5, point_chunk=point_chunk))
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    np.testing.assert_array_equal(out[0][0], out[1][0])
    assert len(pts) > 20 * 4000 and peaks[1] < peaks[0] / 4, peaks


@pytest.mark.parametrize('tiled', [False, True])
def test_piece_pairs_many_pieces_per_parent(tiled):
    # Parents cut into more pieces than PIECE_SCAN: their pairs are searched along the parent,
    # not tested against every piece. Overlapping pieces of random lengths (a long piece before
    # short ones), or disjoint tiles with gaps as LSS leaves them, in shuffled order; against
    # brute force on the pieces.
    rng = np.random.default_rng(7)
    pts = rng.uniform(0, 10, (3000, 2))
    segs = rng.uniform(0, 10, (4, 2, 2))
    length = lengths(segs)
    u = (segs[:, 1] - segs[:, 0]) / length[:, None]
    n = 5 * PIECE_SCAN
    parent = np.repeat(np.arange(4), n)
    if tiled:
        cut = np.sort(rng.uniform(0, 1, (4, 2 * n)), axis=1) * length[:, None]
        t0, t1 = cut[:, 0::2].ravel(), cut[:, 1::2].ravel()
    else:
        t0 = rng.uniform(-0.1, 0.9, 4 * n) * length[parent]
        t1 = t0 + rng.exponential(0.05, 4 * n) * length[parent]
        t1[::n] = t0[::n] + 0.8 * length[parent[::n]]
    shuffle = rng.permutation(4 * n)
    parent, t0, t1 = parent[shuffle], t0[shuffle], t1[shuffle]
    pieces = segs[parent, :1] + np.stack([t0, t1], axis=1)[:, :, None] * u[parent, None]
    radius = 0.2
    reach = radius + max(0.0, -t0.min(), (t1 - length[parent]).max())   # past parents' ends
    p = piece_pairs(PointIndex(pts).pairs(segs, reach), parent, t0, t1 - t0, radius)
    d = brute_distance(pts, pieces)
    got = list(zip(p.pt.tolist(), p.seg.tolist()))
    assert len(got) == len(set(got)), 'pairs must be unique'
    assert set(got) == set(zip(*np.nonzero(d <= radius)))
    np.testing.assert_allclose(p.dist, d[p.pt, p.seg], atol=1e-12)
