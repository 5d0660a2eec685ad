"""A lidar whose range noise grows with the range: ``smemsf.range_noise``, mapped and fitted."""

from conftest import REPO
import numpy as np
from polyline_mapper.config import load_mapper_config
from polyline_mapper.core import fit, SMEMSFConfig
from polyline_mapper.core.geometry import sample_segments
from polyline_mapper.core.incremental import IncrementalConfig
from polyline_mapper.core.index import nearest_distance, PointIndex
from polyline_mapper.recordings import drive_messages
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions
from polyline_mapper.sim import corridor_loop, LaserSpec, simulate_drive
import pytest

RPLIDAR = LaserSpec(beams=720, fov=2 * np.pi, range_min=0.15, range_max=12.0, noise=0.015,
                    noise_share=0.01, dropout=0.01)
"""An RPLidar-class laser: 12 m, 0.5 deg, 1.5 cm plus 1 % of the range (a new-user audit's)."""


@pytest.fixture(scope='module')
def loop():
    """Round a 10 m corridor loop, 2 m wide, at 7.5 Hz and 0.75 m/s (the laser sees 12 m)."""
    return simulate_drive(corridor_loop(width=2.0, side=10.0), RPLIDAR, step=0.1, rate=7.5,
                          rng=1, turn=1.0 / 7.5, scan_time=1.0 / 7.5)


def _mapped(drive, config: IncrementalConfig) -> np.ndarray:
    """Map the drive with its true poses (TF), as replay does; return the segments."""
    records = []
    for _, _, record in drive_messages(drive, mount=(0.0, 0.0, 0.0)):
        records.extend(record if isinstance(record, list) else [record])
    session = replay_records(records, config, options=SessionOptions(pose_source='tf'))
    return np.asarray(session.map_value().segments, dtype=np.float64)


def _scores(segments: np.ndarray, drive) -> tuple:
    """Return (walls' covered share, segments' share on a wall, segments under 0.5 m)."""
    walls = np.asarray(drive.world.walls, dtype=np.float64)
    pts, owner = sample_segments(walls, 0.05)
    d = nearest_distance(pts, segments)[0]
    covered = np.array([np.mean(d[owner == i] < 0.1) for i in range(len(walls))])
    spts, sowner = sample_segments(segments, 0.05)
    on = drive.world.distance(spts) < 0.1
    precise = np.array([np.mean(on[sowner == i]) for i in range(len(segments))])
    short = int(np.count_nonzero(np.hypot(*(segments[:, 1] - segments[:, 0]).T) < 0.5))
    return covered, precise, short


def test_far_noisy_returns_support_their_wall_instead_of_stubs_across_it(loop):
    # One noise scale (estimated from the many near points, about 1.6 cm): the far returns
    # lie beyond its cut-off and line up into stubs across the walls.
    covered, precise, short = _scores(_mapped(loop, IncrementalConfig()), loop)
    assert short >= 20 and np.mean(precise >= 0.9) < 0.6
    # Each point with its own noise scale (the preset config/rplidar.yaml): every wall whole,
    # every segment on a wall.
    preset = load_mapper_config(str(REPO / 'config' / 'rplidar.yaml'))
    assert preset.smemsf.range_noise == 0.01 and preset.smemsf.sigma is None
    segments = _mapped(loop, preset)
    covered, precise, short = _scores(segments, loop)
    assert covered.min() >= 0.9, covered
    assert precise.min() >= 0.9 and short == 0, (precise, short)
    assert len(segments) <= 2 * len(loop.world.walls)


def test_wall_ends_stay_at_the_corners_where_range_noise_moves_far_points_along_walls(loop):
    # A range error moves a point along its beam: at grazing incidence along the wall, and at a
    # corner the perpendicular wall's head-on points lie past the end. Trimmed to the extreme
    # projection of its points, each end overshot (end error median 11-14 cm on drives 1-5);
    # each point now bounds the end only up to 2 noise scales x |cos| inwards (1-4 cm).
    import sys
    sys.path.insert(0, str(REPO / 'benchmarks'))
    from baselines.walls import wall_scores
    preset = load_mapper_config(str(REPO / 'config' / 'rplidar.yaml'))
    errors = []
    for drive in (loop, *(simulate_drive(loop.world, RPLIDAR, step=0.1, rate=7.5, rng=seed,
                                         turn=1.0 / 7.5, scan_time=1.0 / 7.5)
                          for seed in (2, 3))):
        scores = wall_scores(_mapped(drive, preset).reshape(-1, 2, 2), drive.world.walls,
                             drive.world.distance, points=drive.points())
        assert scores['f1'] >= 0.95, scores
        errors.append(scores['end_error_median'])
    assert np.median(errors) < 0.05, errors


def test_the_batch_fit_of_the_beams_gives_far_points_their_noise_too(loop):
    # Each beam from its scan's pose, as `fit` of a recording gets them (one origin per scan:
    # MappingSession.origins); the batch fit takes a run of equal origins as one look, so the
    # moving sensor's own origin per beam (loop.origins()) made every beam a look: the same
    # segments here, 36 s instead of 1.7 s (2026-12-01, Intel Xeon VM).
    every = slice(None, None, 6)            # a sixth of the points (42k): the fit's time / 6
    pts, origins = loop.points()[every], loop.origins(per_beam=False)[every]
    _, _, short = _scores(fit(pts, origins=origins).segments, loop)
    assert short >= 10
    result = fit(pts, SMEMSFConfig(range_noise=0.01), origins=origins)
    covered, precise, short = _scores(result.segments, loop)
    assert covered.min() >= 0.9 and precise.min() >= 0.9 and short == 0, \
        (covered, precise, short)
    # bare points carry no range: the setting changes nothing there
    few = pts[::10]
    assert np.array_equal(fit(few, SMEMSFConfig(range_noise=0.01)).segments, fit(few).segments)


def test_a_point_of_its_own_noise_is_cut_off_at_kappa_times_it():
    from polyline_mapper.core.emsf import e_step
    wall = np.array([[[0.0, 0.0], [10.0, 0.0]]])
    pts = np.array([[1.0, 0.05], [9.0, 0.05], [9.0, 0.5]])
    near = PointIndex(pts)
    assert e_step(near, wall, 0.01, 3.0).support.tolist() == [-1, -1, -1]
    # 0.05 m off at 3 x hypot(0.01, 0.1) = 0.30 m: the far point's; 0.5 m is beyond it
    noisy = PointIndex(pts, extra=np.array([0.0, 0.1, 0.1]))
    assert e_step(noisy, wall, 0.01, 3.0).support.tolist() == [-1, 0, -1]
    with pytest.raises(ValueError, match='extra'):
        PointIndex(pts, extra=np.array([0.0, np.nan, 0.1]))
    with pytest.raises(ValueError, match='range_noise'):
        SMEMSFConfig(range_noise=-0.01)


def test_fit_uses_the_ranges_without_the_evidence_and_says_when_it_has_none(tmp_path, capsys):
    # fit passed the beams' origins only with the free-space evidence on: with
    # free_space_window=0 the setting was dropped, while MAP.json stored it as applied; a point
    # file (no ranges) dropped it without a word (a new-user audit).
    import json
    from polyline_mapper.cli import main

    def segments(name, *sets):
        out = tmp_path / name
        argv = ['fit', 'sim:hall', '-o', str(out), '-q', '--set', 'free_space_window=0']
        assert main(argv + [a for s in sets for a in ('--set', s)]) == 0
        data = json.loads(out.read_text())
        return data['segments'], data['config']['range_noise']
    plain, noise = segments('plain.json')
    ranged, stored = segments('ranged.json', 'range_noise=0.01')
    assert noise == 0.0 and stored == 0.01 and ranged != plain
    points = tmp_path / 'points.txt'
    np.savetxt(points, simulate_drive(corridor_loop(width=2.0, side=10.0), RPLIDAR, step=1.0,
                                      rng=2).points()[::4])
    out = tmp_path / 'points.json'
    assert main(['fit', str(points), '--set', 'range_noise=0.01', '-o', str(out), '-q']) == 0
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'range_noise=0.01 cannot be applied' in err
    assert json.loads(out.read_text())['config']['range_noise'] == 0.0


def test_replay_names_range_noise_when_the_map_leaves_points_off(tmp_path, capsys):
    # Ten times too high on a 1 cm lidar: the map coarsens (the audit: walls F1 1.00 -> 0.61)
    # and the only warning blamed the poses, which were exact.
    from polyline_mapper.cli import main
    assert main(['replay', 'sim:office', '--set', 'range_noise=0.1', '-o',
                 str(tmp_path / 'map.json'), '-q']) == 0
    err = capsys.readouterr().err
    assert 'the scans disagree' in err and 'range_noise (0.1:' in err, err
    assert main(['replay', 'sim:office', '-o', str(tmp_path / 'plain.json'), '-q']) == 0
    assert capsys.readouterr().err == ''
