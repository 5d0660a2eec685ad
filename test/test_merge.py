"""Merging: the paper's merged segment, the grouping cost and the data-backed gap test."""

from conftest import noisy_line
import numpy as np
from polyline_mapper.core.index import PointIndex
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


def test_noise_stub_inside_a_wall_band_is_marked_an_object_outside_is_not():
    from polyline_mapper.core.merge import noise_stubs
    sigma, r, kappa = 0.04, 0.10, 3.0
    wall = [[0.0, 2.0], [20.0, 2.0]]
    segs = np.array([
        wall,
        [[15.03, 1.93], [15.05, 1.87]],     # 6 cm, across the wall, 7-13 cm off it: a stub
        [[8.00, 1.50], [8.05, 1.40]],       # as short and steep, but 50 cm off: an object
        [[3.00, 1.95], [3.15, 1.94]],       # short but along the wall: a piece, not a stub
        [[25.0, 1.95], [25.05, 1.85]],      # steep and close to the line, past the wall's end
    ])
    assert noise_stubs(segs, sigma, r, kappa).tolist() == [False, True, False, False, False]


def _corridor_drive(noise, seed):
    from polyline_mapper.sim import corridor_loop, LaserSpec, simulate_drive
    world = corridor_loop()
    spec = LaserSpec(beams=271, range_max=12.0, noise=noise, dropout=0.01)
    return world, spec, simulate_drive(world, spec, step=0.5, rng=seed)


def _strays(world, segs):
    """Segments with more than 20 % of their length over 10 cm from every true wall."""
    from polyline_mapper.core.geometry import sample_segments
    samples, owner = sample_segments(segs, 0.02)
    off = np.bincount(owner, world.distance(samples) > 0.10, len(segs))
    return segs[off / np.bincount(owner, None, len(segs)) > 0.2]


def test_range_noise_at_head_on_incidence_leaves_no_stub_in_the_map():
    # Corridors at 5 cm range noise, drive seed 1: a few points of the wall's noise tail lined up
    # into a 6 cm stub 7-13 cm off the wall (batch) and an 18 cm one (incremental).
    from polyline_mapper.core import fit
    from polyline_mapper.core.incremental import IncrementalMapper
    world, spec, drive = _corridor_drive(0.05, 1)
    res = fit(drive.points())
    assert len(_strays(world, res.segments)) == 0, _strays(world, res.segments)
    assert len(res.segments) == 9           # 8 walls, one corner cut by a short chord
    mapper = IncrementalMapper()
    for ranges, pose in zip(drive.ranges, drive.poses):
        mapper.update_scan(ranges, spec.angles(), pose, spec.range_min, spec.range_max)
    segs = mapper.polylines().segments
    assert len(_strays(world, segs)) == 0, _strays(world, segs)
