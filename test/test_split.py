"""LSS: split where support drops, with a threshold that follows each segment's density."""

from conftest import noisy_line
import numpy as np
from polyline_mapper.core.index import PointIndex
from polyline_mapper.core.split import split_segments


def test_dense_wall_splits_at_a_door_but_not_elsewhere():
    rng = np.random.default_rng(0)
    pts = np.concatenate([noisy_line([0, 0], [3, 0], 3000, 0.01, rng),
                          noisy_line([4, 0], [7, 0], 3000, 0.01, rng)])
    seg = np.array([[[0, 0], [7, 0]]], dtype=float)
    out, parent = split_segments(PointIndex(pts), seg, r=0.04)
    assert len(out) == 2 and np.all(parent == 0)
    xs = np.sort(out[:, :, 0], axis=1)
    xs = xs[np.argsort(xs[:, 0])]
    np.testing.assert_allclose(xs, [[0, 3], [4, 7]], atol=0.1)


def test_sparse_far_wall_with_dropouts_stays_whole():
    # One scan of a 6 m wall 7 m away, 0.5 deg beams, 10 % dropouts: points 6-9 cm apart with
    # holes, about one point per 8 cm square. Empty squares occur by chance and must not cut it.
    from polyline_mapper.sim import LaserSpec, World
    from polyline_mapper.sim.laser import simulate_scan
    world = World(walls=np.array([[[-3.0, 7.0], [3.0, 7.0]]]))
    spec = LaserSpec(beams=361, fov=np.pi, noise=0.01, dropout=0.1)
    splits = 0
    for seed in range(20):
        ranges, _ = simulate_scan(world, np.array([0.0, 0.0, np.pi / 2]), spec,
                                  np.random.default_rng(seed))
        from polyline_mapper.scan import scan_to_points
        pts = scan_to_points(ranges, spec.angles(), [0, 0, np.pi / 2], 0.05, 12.0)
        seg = np.array([[[-3.0, 7.0], [3.0, 7.0]]])
        out, _ = split_segments(PointIndex(pts), seg, r=0.04)
        splits += len(out) != 1
    assert splits <= 1          # gap_p = 1e-3 per segment; allow one unlucky scan in 20


def test_segment_over_empty_space_disappears():
    pts = np.random.default_rng(2).uniform(0, 1, (50, 2))
    seg = np.array([[[10, 10], [12, 10]]], dtype=float)
    out, _ = split_segments(PointIndex(pts), seg, r=0.05)
    assert len(out) == 0
