"""Merging: the paper's merged segment, the grouping cost and the data-backed gap test."""

from conftest import noisy_line
import numpy as np
from polyline_mapper.core.geometry import PointIndex
from polyline_mapper.core.merge import grouping_cost, merge_segments, merged_segment


def test_merged_segment_is_length_weighted():
    s1 = np.array([[[0.0, 0.0], [3.0, 0.0]]])       # long, at y = 0
    s2 = np.array([[[4.0, 0.1], [5.0, 0.1]]])       # short, at y = 0.1
    ms = merged_segment(s1, s2)
    seg = ms['segment'][0]
    # Horizontal; d1 * l1 = d2 * l2 puts the line at y = 0.1 * 1 / 4 = 0.025.
    np.testing.assert_allclose(seg[:, 1], 0.025, atol=1e-12)
    np.testing.assert_allclose(np.sort(seg[:, 0]), [0.0, 5.0], atol=1e-12)
    assert abs(ms['gap'][0] - 1.0) < 1e-12
    # Orientation of the inputs does not matter.
    ms2 = merged_segment(s1, s2[:, ::-1])
    np.testing.assert_allclose(np.sort(ms2['segment'][0][:, 0]), [0.0, 5.0], atol=1e-12)


def test_direction_follows_the_longer_segment():
    s1 = np.array([[[0.0, 0.0], [4.0, 0.0]]])
    s2 = np.array([[[0.0, 0.0], [1.0, 1.0]]]) / np.sqrt(2) * 1.0
    ms = merged_segment(s1, s2)
    d = ms['segment'][0, 1] - ms['segment'][0, 0]
    ang = np.degrees(np.arctan2(d[1], d[0]))
    assert 0 < ang < 22.5          # closer to the 4 m segment than to the 1 m one at 45 deg


def test_cost_orders_pairs_sensibly():
    sigma = 0.02
    pieces = merged_segment(np.array([[[0, 0], [2, 0]]], float),
                            np.array([[[2.1, 0.005], [4, 0.0]]], float))
    corner = merged_segment(np.array([[[0, 0], [2, 0]]], float),
                            np.array([[[2, 0], [2, 2]]], float))
    twin = merged_segment(np.array([[[0, 0], [2, 0]]], float),
                          np.array([[[0, 0.2], [2, 0.2]]], float))
    c = [grouping_cost(m, sigma, np.deg2rad(10))[0] for m in (pieces, corner, twin)]
    assert c[0] < 0.5            # two pieces of one wall: merge
    assert c[1] > 1.0            # a corner: never
    assert c[2] > 1.0            # two walls 10 sigma apart: no


def test_pieces_of_one_wall_merge_but_a_door_stays_open():
    rng = np.random.default_rng(0)
    wall = np.concatenate([noisy_line([0, 0], [3, 0], 3000, 0.01, rng),
                           noisy_line([4, 0], [7, 0], 3000, 0.01, rng)])
    idx = PointIndex(wall)
    segs = np.array([[[0, 0], [1.5, 0]], [[1.52, 0], [3, 0]],      # one wall in two pieces
                     [[4, 0], [7, 0]]], dtype=float)               # across a 1 m door
    out, sup, merges = merge_segments(idx, segs, np.array([1500.0, 1500, 3000]), sigma=0.01,
                                      r=0.02, reach=1.2)
    assert merges == 1 and len(out) == 2
    xs = np.sort(np.sort(out[:, :, 0], axis=1), axis=0)
    np.testing.assert_allclose(xs, [[0, 3], [4, 7]], atol=0.03)


def test_parallel_walls_a_wall_thickness_apart_do_not_merge():
    rng = np.random.default_rng(1)
    pts = np.concatenate([noisy_line([0, 0], [3, 0], 2000, 0.01, rng),
                          noisy_line([0, 0.15], [3, 0.15], 2000, 0.01, rng)])
    segs = np.array([[[0, 0], [3, 0]], [[0, 0.15], [3, 0.15]]], dtype=float)
    out, _, merges = merge_segments(PointIndex(pts), segs, np.array([2000.0, 2000]), sigma=0.01,
                                    r=0.02, reach=0.5)
    assert merges == 0 and len(out) == 2
