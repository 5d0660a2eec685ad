"""A simulated office floor with known walls: every wall found, nothing invented."""

from conftest import end_errors
import numpy as np
from polyline_mapper.core import fit, map_metrics, SMEMSFConfig
from polyline_mapper.core.geometry import sample_segments
from polyline_mapper.sim import hall_with_arc, LaserSpec, simulate_drive
import pytest


def observed_extent(points, hits, wall_index, wall):
    """End points of the part of a wall the laser actually saw (from the simulator's hit ids)."""
    a, b = wall
    u = (b - a) / np.linalg.norm(b - a)
    t = (points[hits == wall_index] - a) @ u
    return a + t.min() * u, a + t.max() * u


def test_every_wall_found_with_end_points_within_10cm(office_fit, office_drive):
    pts, hits, res = office_fit
    walls = office_drive.world.walls
    segs = res.segments
    for i, wall in enumerate(walls):
        assert np.linalg.norm(wall[1] - wall[0]) > 1.0
        p, q = observed_extent(pts, hits, i, wall)
        err = end_errors(segs, p, q)
        assert err.min() <= 0.10, f'wall {i} {wall.tolist()}: end-point error {err.min():.3f} m'


def test_no_segment_where_no_wall_is(office_fit, office_drive):
    _, _, res = office_fit
    samples, owner = sample_segments(res.segments, 0.02)
    d = office_drive.world.distance(samples)
    worst = np.zeros(len(res.segments))
    np.maximum.at(worst, owner, d)
    assert worst.max() <= 0.10, f'segment {int(worst.argmax())} strays {worst.max():.3f} m'


def test_office_map_quality_and_doors_open(office_fit):
    pts, _, res = office_fit
    m = map_metrics(pts, res.segments)
    assert m['mean_distance'] < 0.012 and m['coverage_0_10m'] > 0.995
    assert res.converged and res.iterations <= 30
    # The 1 m doors in the corridor walls (y = 5 and y = 7) stay open.
    for y, xs in ((5.0, (3.0, 9.5, 16.0)), (7.0, (5.0, 14.5))):
        probe = np.array([[x, y] for x in xs])
        samples, _ = sample_segments(res.segments, 0.02)
        near = np.min(np.linalg.norm(samples[None] - probe[:, None], axis=2), axis=1)
        assert np.all(near > 0.3), f'a door at y={y} is bridged'


@pytest.fixture(scope='module')
def noise_series():
    counts = {}
    for noise in (0.005, 0.02, 0.05):
        drive = simulate_drive(hall_with_arc(), LaserSpec(noise=noise, dropout=0.02), step=0.4,
                               rng=21)
        pts = drive.points()
        res = fit(pts, SMEMSFConfig())
        counts[noise] = (len(res.segments), res.sigma, map_metrics(pts, res.segments))
    return counts


def test_more_noise_gives_fewer_segments(noise_series):
    n = [noise_series[k][0] for k in (0.005, 0.02, 0.05)]
    assert n[0] > n[1] > n[2], f'segment counts for noise 0.5, 2, 5 cm: {n}'


def test_noise_scale_follows_the_sensor(noise_series):
    # The fit's final sigma estimates the range noise (normal to walls it is a little smaller:
    # beams hit walls obliquely), never the floor when the data are noisier.
    for noise, (_, sigma, m) in noise_series.items():
        assert 0.6 * noise <= sigma <= 1.3 * max(noise, 0.005), (noise, sigma)
        assert m['coverage_0_10m'] > 0.95
