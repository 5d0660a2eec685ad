"""The simulated laser is physical, and scan -> points follows REP 117."""

import numpy as np
from polyline_mapper.scan import beam_angles, scan_to_points
from polyline_mapper.sim import Arc, LaserSpec, World
from polyline_mapper.sim.laser import simulate_scan
import pytest


def test_ray_cast_exact_against_geometry():
    world = World(walls=np.array([[[2.0, -5.0], [2.0, 5.0]]]), arcs=[Arc((0.0, 0.0), 1.0,
                                                                         np.pi / 2, np.pi)])
    d = np.array([[1.0, 0.0], [np.cos(0.5), np.sin(0.5)], [-1.0, 0.0], [0.0, -1.0],
                  [np.cos(2.0), np.sin(2.0)]])
    dist, hit = world.cast([0.0, 0.0], d)
    np.testing.assert_allclose(dist[:2], [2.0, 2.0 / np.cos(0.5)])
    assert hit.tolist()[:2] == [0, 0]
    assert dist[2] == 1.0 and hit[2] == 1            # arc end at angle pi
    assert np.isinf(dist[3]) and hit[3] == -1         # outside the arc's angles: no hit
    assert abs(dist[4] - 1.0) < 1e-12 and hit[4] == 1


def test_noise_dropouts_and_no_returns_follow_rep117():
    world = World(walls=np.array([[[3.0, -50.0], [3.0, 50.0]]]))
    spec = LaserSpec(beams=2001, fov=np.deg2rad(180), range_max=10.0, noise=0.02, dropout=0.1)
    ranges, _ = simulate_scan(world, np.zeros(3), spec, np.random.default_rng(0))
    ang = spec.angles()
    true = 3.0 / np.cos(ang)
    far = true >= 10.0
    assert np.all(np.isinf(ranges[far & ~np.isnan(ranges)]))
    ok = np.isfinite(ranges)
    assert 0.085 < np.isnan(ranges).mean() < 0.115
    resid = ranges[ok] - true[ok]
    assert abs(resid.std() - 0.02) < 0.002 and abs(resid.mean()) < 0.002


def test_scan_to_points_filters_and_transforms():
    ranges = np.array([1.0, np.nan, np.inf, -np.inf, 0.01, 30.0, 2.0])
    angles = beam_angles(-np.pi / 2, np.pi / 6, len(ranges))
    pts = scan_to_points(ranges, angles, (1.0, 2.0, np.pi / 2), range_min=0.1, range_max=30.0)
    # Kept: beam 0 (1 m at -90 deg) and beam 6 (2 m at +90 deg), rotated by +90 deg.
    np.testing.assert_allclose(pts, [[2.0, 2.0], [-1.0, 2.0]], atol=1e-12)


def test_a_reading_of_zero_is_no_return_even_with_range_min_zero():
    # Drivers that advertise range_min 0 send 0 for "no echo": each was mapped as a point at
    # the laser (an audit: 155 points along the path of a 50-scan drive, 4 occupied cells).
    ranges = np.array([0.0, 1.0, 0.0, 2.0, -0.0])
    angles = beam_angles(0.0, np.pi / 2, len(ranges))
    pts = scan_to_points(ranges, angles, (0.0, 0.0, 0.0), range_min=0.0, range_max=30.0)
    np.testing.assert_allclose(pts, [[0.0, 1.0], [0.0, -2.0]], atol=1e-12)


@pytest.mark.parametrize('ranges, angles, pose, why', [
    (np.ones(5), np.zeros(4), (0, 0, 0), 'differ in length'),
    (np.ones(3), np.zeros(3), (0, 0), 'pose'),
    (np.ones(3), np.zeros(3), (0, np.nan, 0), 'pose'),
])
def test_scan_to_points_rejects_mismatches(ranges, angles, pose, why):
    with pytest.raises(ValueError, match=why):
        scan_to_points(ranges, angles, pose)


def test_zero_angle_increment_rejected():
    with pytest.raises(ValueError, match='angle_increment'):
        beam_angles(0.0, 0.0, 10)
