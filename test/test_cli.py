"""The fit and demo commands end to end: schema, plot, config files, CARMEN logs."""

import gzip
import json

from conftest import noisy_line, REPO
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.formats.mapjson import read_map


def square_room_points(rng):
    corners = [(0, 0), (4, 0), (4, 3), (0, 3), (0, 0)]
    sides = zip(corners[:-1], corners[1:])
    return np.concatenate([noisy_line(a, b, 800, 0.01, rng) for a, b in sides])


def test_fit_writes_schema_and_png(tmp_path, capsys):
    pts = square_room_points(np.random.default_rng(0))
    src = tmp_path / 'room.csv'
    np.savetxt(src, pts, delimiter=',', header='x,y', comments='')
    out, png = tmp_path / 'm.json', tmp_path / 'm.png'
    assert main(['fit', str(src), '-o', str(out), '--plot', str(png)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f'wrote {out} and {png}: 4 segments in 1 polylines')
    data = read_map(str(out))
    assert data['frame_id'] == 'map'
    assert len(data['segments']) == 4 and all(len(s) == 4 for s in data['segments'])
    assert len(data['polylines']) == 1 and data['closed'] == [True]
    stats = data['stats']
    for key in ('points', 'segments', 'iterations', 'mean_distance', 'p95_distance',
                'coverage_0_10m', 'seconds'):
        assert key in stats
    assert stats['points'] == len(pts) and stats['mean_distance'] < 0.012
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 10_000
    corners = {tuple(np.round(v, 1)) for v in data['polylines'][0]}
    assert corners == {(0.0, 0.0), (4.0, 0.0), (4.0, 3.0), (0.0, 3.0)}


def test_fit_reads_npy_txt_and_the_shipped_ros_param_file(tmp_path):
    pts = square_room_points(np.random.default_rng(1))
    np.save(tmp_path / 'p.npy', pts)
    np.savetxt(tmp_path / 'p.txt', pts)
    cfg = REPO / 'config' / 'polyline_mapper.yaml'
    for name in ('p.npy', 'p.txt'):
        out = tmp_path / (name + '.json')
        assert main(['fit', str(tmp_path / name), '-o', str(out), '--config', str(cfg),
                     '-q']) == 0
        assert len(json.loads(out.read_text())['segments']) == 4
    out = tmp_path / 'sig.json'
    assert main(['fit', str(tmp_path / 'p.npy'), '-o', str(out), '--set', 'sigma=0.05',
                 '-q']) == 0
    assert json.loads(out.read_text())['config']['sigma'] == 0.05


def test_fit_carmen_log_registers_scans(tmp_path):
    # A robot in a 6 x 4 m room, FLASER with 181 beams (odd count: pi / 180 spacing).
    from polyline_mapper.sim import LaserSpec, simulate_drive, World
    walls = np.array([[[0, 0], [6, 0]], [[6, 0], [6, 4]], [[6, 4], [0, 4]], [[0, 4], [0, 0]]],
                     dtype=float)
    spec = LaserSpec(beams=181, fov=np.pi, range_max=50.0, noise=0.01, dropout=0.0)
    drive = simulate_drive(World(walls, path=[(1, 1), (5, 1), (5, 3), (1, 3)]), spec, step=0.5,
                           rng=2)
    lines = []
    for i, (pose, rng_) in enumerate(zip(drive.poses, drive.ranges)):
        r = np.where(np.isfinite(rng_), rng_, 81.91)
        vals = ' '.join(f'{v:.3f}' for v in r)
        p = ' '.join(f'{v:.5f}' for v in pose)
        lines.append(f'FLASER 181 {vals} {p} {p} {i * 0.1:.2f} host 0.0\n')
    lines.insert(3, 'FLASER 181 1 2 3 garbage\n')
    path = tmp_path / 'room.log.gz'
    with gzip.open(path, 'wt') as fh:
        fh.writelines(['# a comment\n', 'PARAM robot_front_laser_max 81.91 host 0\n'] + lines)
    out = tmp_path / 'room.json'
    # the free-space evidence is on by default: the log's beams go into the fit, the walls stay
    assert main(['fit', str(path), '-o', str(out), '-q']) == 0
    data = json.loads(out.read_text())
    stats = data['stats']
    assert len(data['segments']) == 4 and stats['mean_distance'] < 0.012
    assert '1 malformed' in stats['input_type']
    assert stats['free_space_window'] == 10 and stats['free_space_beams'] == stats['points']
    assert stats['contradicted_share'] == 0.0 and stats['free_space_hit_margin'] == 0.03
    # the mapper's keys (the ones replay takes) set it: no hit margin, or the bare points
    out = tmp_path / 'beams.json'
    assert main(['fit', str(path), '-o', str(out), '-q', '--set',
                 'free_space_hit_margin=0']) == 0
    stats = json.loads(out.read_text())['stats']
    assert stats['free_space_hit_margin'] == 0.0 and stats['free_space_window'] == 10
    assert stats['segments'] == 4
    assert main(['fit', str(path), '-o', str(out), '-q', '--set', 'free_space_window=0']) == 0
    stats = json.loads(out.read_text())['stats']
    assert stats['free_space_window'] == stats['free_space_beams'] == 0
    assert stats['segments'] == 4 and stats['beams'] == stats['points']


def test_offline_demo_fits_the_office(tmp_path, capsys):
    out, png = tmp_path / 'd.json', tmp_path / 'd.png'
    assert main(['demo', '--offline', '-o', str(out), '--plot', str(png)]) == 0
    said = capsys.readouterr()
    assert said.out.startswith(f'wrote {out} and {png}: ') and not said.err
    data = json.loads(out.read_text())
    assert 15 <= data['stats']['segments'] <= 45 and data['stats']['coverage_0_10m'] > 0.99
    assert png.exists()
    # the live demo's flags change nothing offline, and it says so (a new-user audit)
    assert main(['demo', '--offline', '-o', str(out), '--rate', '4', '--domain-id', '7',
                 '-q']) == 0
    assert capsys.readouterr().err == ('polyline-mapper: warning: --rate and --domain-id apply '
                                       'to the live demo only, not with --offline\n')


def test_fit_of_bare_points_with_free_space_evidence_warns_once(tmp_path, capsys):
    # A point file has no beams: asked for the evidence, fit warns in one line, fits the points
    # as without it and its stats say no beams were used.
    pts = square_room_points(np.random.default_rng(3))
    src = tmp_path / 'room.npy'
    np.save(src, pts)
    maps = []
    # fit --help suggests the shipped parameter file, whose free_space_window is -1, the
    # default ('by the pose source'): it warned that 10 could not be applied (new-user audit)
    shipped = ['--config', str(REPO / 'config' / 'polyline_mapper.yaml')]
    for extra in (['--set', 'free_space_window=10'], [], shipped):
        out = tmp_path / f'm{len(maps)}.json'
        assert main(['fit', str(src), '-o', str(out), '-q'] + extra) == 0
        err = capsys.readouterr().err.strip().splitlines()
        maps.append(read_map(str(out)))
        if extra and extra != shipped:
            assert len(err) == 1, err
            assert err[0].startswith('polyline-mapper: warning: ') and \
                'free_space_window=10 cannot be applied' in err[0] and 'no beams' in err[0]
        else:
            assert err == []
    stats = maps[0]['stats']
    assert stats['beams'] == 0 and stats['contradicted_share'] is None
    assert stats['free_space_window'] == stats['free_space_beams'] == stats['free_squares'] == 0
    assert np.array_equal(maps[0].value.segments, maps[1].value.segments)
    assert len(maps[0].value.segments) == 4
