"""The free-space metric: beams that pass through or end on map segments (kernel, stats, CLI)."""

import json
import re

from bag_helpers import drive_messages, room_drive, write_bag, write_carmen
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.core import freespace
from polyline_mapper.core.freespace import free_space_stats, judge, NO_BEAMS
from polyline_mapper.recordings import drive_beams, read_beams, read_points
from polyline_mapper.replay import run_replay
import pytest

WALL = np.array([[[-1.0, 2.0], [1.0, 2.0]]])      # 2 m along y = 2, the laser at the origin


def counts(segs, points, origins):
    v = judge(segs, np.asarray(points, float), np.asarray(origins, float))
    return v.passes.tolist(), v.ends.tolist()


def test_a_beam_through_the_middle_passes():
    assert counts(WALL, [[0.0, 3.0]], [0.0, 0.0]) == ([1], [0])


def test_a_beam_grazing_at_10_degrees_does_not_pass_and_one_at_25_does():
    for deg, passes in ((10.0, 0), (25.0, 1)):
        a = np.deg2rad(deg)
        origin = np.array([-3.0, 2.0 - 3.0 * np.tan(a)])     # crosses y = 2 at x = 0
        end = np.array([0.9, 2.0 + 0.9 * np.tan(a)])          # > 10 cm beyond the line
        assert counts(WALL, [end], origin) == ([passes], [0]), deg


def test_a_beam_ending_on_the_segment_ends_and_one_ending_short_counts_for_nothing():
    assert counts(WALL, [[0.3, 2.05]], [0.0, 0.0]) == ([0], [1])
    assert counts(WALL, [[0.3, 1.95]], [0.0, 0.0]) == ([0], [1])     # short but within 10 cm
    assert counts(WALL, [[0.3, 1.5]], [0.0, 0.0]) == ([0], [0])
    assert counts(WALL, [[1.05, 2.0]], [1.05, 0.0]) == ([0], [1])    # 5 cm past the end
    assert counts(WALL, [[0.3, 2.08]], [-5.0, 1.9]) == ([0], [1])    # grazing, still ends on it


def test_beams_ending_just_beyond_or_crossing_near_an_end_do_not_pass():
    assert counts(WALL, [[0.0, 2.09]], [0.0, 0.0]) == ([0], [1])     # 9 cm beyond: an end
    assert counts(WALL, [[0.0, 2.11]], [0.0, 0.0]) == ([1], [0])
    # crossing 5 cm and 15 cm from the right end
    assert counts(WALL, [[0.95 * 1.5, 3.0]], [0.0, 0.0]) == ([0], [0])
    assert counts(WALL, [[0.85 * 1.5, 3.0]], [0.0, 0.0]) == ([1], [0])
    # behind the laser: the beam points away from the wall
    assert counts(WALL, [[0.0, -3.0]], [0.0, 0.0]) == ([0], [0])


def test_contradicted_needs_five_passes_and_more_passes_than_ends():
    through = np.column_stack([np.linspace(-0.5, 0.5, 5), np.full(5, 3.0)])
    on = np.column_stack([np.linspace(-0.5, 0.5, 5), np.full(5, 2.02)])
    for n_pass, n_end, verdict in ((5, 4, True), (5, 5, False), (4, 0, False)):
        pts = np.concatenate([through[:n_pass], on[:n_end]])
        v = judge(WALL, pts, [0.0, 0.0])
        assert (v.passes[0], v.ends[0]) == (n_pass, n_end)
        assert v.contradicted.tolist() == [verdict]
        assert v.stats() == {'beams': n_pass + n_end, 'contradicted_share': float(verdict),
                             'contradicted_segments': int(verdict)}


def brute_force(segs, points, origins, tol=0.10, min_angle=np.deg2rad(20.0)):
    """Every (segment, beam) pair by the definitions, one at a time, another formulation."""
    passes, ends = np.zeros(len(segs), int), np.zeros(len(segs), int)
    for k, (a, b) in enumerate(segs):
        e = b - a
        length = np.hypot(*e)
        for p, o in zip(points, origins):
            d = p - o
            r = np.hypot(*d)
            if r == 0:
                continue
            u = np.clip(np.dot(p - a, e) / (length * length), 0, 1) if length > 0 else 0.0
            ends[k] += np.hypot(*(p - (a + u * e))) <= tol
            if length == 0:
                continue
            angle = np.arccos(min(1.0, abs(np.dot(d, e)) / (r * length)))
            if angle < min_angle:
                continue
            t, s = np.linalg.solve(np.column_stack([d, -e]), a - o)
            normal = np.array([-e[1], e[0]]) / length
            side_o, side_p = np.dot(o - a, normal), np.dot(p - a, normal)
            passes[k] += (t > 0 and tol < s * length < length - tol
                          and np.sign(side_p) != np.sign(side_o) and abs(side_p) > tol)
    return passes, ends


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_the_kernel_equals_brute_force_on_random_beams_and_segments(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    segs = rng.uniform(-5, 5, (40, 2, 2))
    segs[0, 1] = segs[0, 0]                                   # a zero-length segment
    points, origins = [], []
    for _ in range(5):
        o = rng.uniform(-5, 5, 2)
        ang = rng.uniform(-np.pi, np.pi, 150)
        r = rng.uniform(0.05, 9.0, 150)
        points.append(o + r[:, None] * np.column_stack([np.cos(ang), np.sin(ang)]))
        origins.append(np.repeat(o[None], 150, axis=0))
    points, origins = np.concatenate(points), np.concatenate(origins)
    # many endpoints near segments (ends), and a laser within 10 cm of segment 1
    i = rng.choice(len(points), 200, replace=False)
    k = rng.integers(0, len(segs), 200)
    u = rng.uniform(-0.1, 1.1, 200)[:, None]
    points[i] = segs[k, 0] + u * (segs[k, 1] - segs[k, 0]) + rng.normal(0, 0.07, (200, 2))
    origins[:150] = segs[1].mean(axis=0) + [0.0, 0.05]
    want = brute_force(segs, points, origins)
    got = judge(segs, points, origins)
    assert want[0].sum() > 500 and want[1].sum() > 100
    np.testing.assert_array_equal(got.passes, want[0])
    np.testing.assert_array_equal(got.ends, want[1])
    # tiny pair blocks and runs (the bounded-memory path) give the same counts
    monkeypatch.setattr(freespace, 'PAIR_BUDGET', 7)
    monkeypatch.setattr(freespace, 'MAX_RUN', 13)
    small = judge(segs, points, origins)
    np.testing.assert_array_equal(small.passes, want[0])
    np.testing.assert_array_equal(small.ends, want[1])


def test_every_counts_the_beams_of_every_nth_laser_position_and_inputs_are_checked():
    pts = np.array([[0.0, 3.0]] * 4 + [[0.1, 3.0]] * 4)
    org = np.array([[0.0, 0.0]] * 4 + [[0.1, 0.0]] * 4)
    assert judge(WALL, pts, org, every=2).beams == 4
    assert judge(WALL, pts, org).passes.tolist() == [8]
    with pytest.raises(ValueError, match='every must be'):
        judge(WALL, pts, org, every=0)
    with pytest.raises(ValueError, match='origins must have shape'):
        judge(WALL, pts, org[:3])
    with pytest.raises(ValueError, match='segments must have shape'):
        judge(np.zeros((3, 2)), pts, org)
    with pytest.raises(ValueError, match='NaN or inf'):
        judge(WALL, pts, np.full((8, 2), np.nan))
    assert judge(np.zeros((0, 2, 2)), pts, org).stats() == {
        'beams': 8, 'contradicted_share': 0.0, 'contradicted_segments': 0}
    assert free_space_stats(WALL, pts, None) == NO_BEAMS


@pytest.fixture(scope='module')
def room():
    """Drive through the simulated room with FLASER geometry (181 beams over 180 deg)."""
    return room_drive(mount=(0.2, -0.1, np.pi / 2), beams=181, fov=180.0, step=0.3, rng=8)


# a wall drawn across the free room (the robot drives and sees through it), and a real wall
ACROSS = np.array([[[1.2, 2.4], [2.6, 2.4]]])
REAL = np.array([[[0.5, 0.0], [7.5, 0.0]]])


def test_replay_stats_judge_free_space_with_each_scans_origin(room, tmp_path):
    bag = write_bag(tmp_path / 'room', drive_messages(room))
    res = run_replay(bag)
    st = res.stats()
    origins = res.session.origins()
    assert st['beams'] == len(res.points) == len(origins) > 1000
    assert st['contradicted_segments'] == 0 and st['contradicted_share'] == 0.0
    # every point's origin is its scan's laser position, within the laser's range of it
    assert np.isin(origins[:, 0].round(6), room.laser[:, 0].round(6)).all()
    assert np.hypot(*(res.points - origins).T).max() < room.spec.range_max
    assert judge(ACROSS, res.points, origins).contradicted.tolist() == [True]
    assert judge(REAL, res.points, origins).contradicted.tolist() == [False]
    assert 'contradicted 0.0% of map length' in res.summary('x.json')


def test_fit_of_a_log_or_bag_judges_free_space_and_of_a_point_file_says_no_beams(
        room, tmp_path, capsys):
    log = write_carmen(tmp_path / 'room.log.gz', room)
    points, origins, _ = read_beams(log)
    np.testing.assert_array_equal(points, read_points(log)[0])      # the fit's points unchanged
    assert judge(ACROSS, points, origins).contradicted.tolist() == [True]
    out = tmp_path / 'log.json'
    assert main(['fit', log, '-o', str(out)]) == 0
    assert 'contradicted ' in capsys.readouterr().out
    st = json.loads(out.read_text())['stats']
    assert st['beams'] == st['points'] == len(points)
    assert st['contradicted_share'] < 0.05 and st['contradicted_segments'] >= 0
    bag = write_bag(tmp_path / 'bag', drive_messages(room))
    assert main(['fit', bag, '-o', str(tmp_path / 'bag.json'), '-q']) == 0
    st = json.loads((tmp_path / 'bag.json').read_text())['stats']
    assert st['beams'] == st['points'] > 1000 and st['contradicted_share'] is not None
    npy = tmp_path / 'p.npy'
    np.save(npy, points)
    assert main(['fit', str(npy), '-o', str(tmp_path / 'p.json')]) == 0
    assert 'no beams: free space not judged' in capsys.readouterr().out
    st = json.loads((tmp_path / 'p.json').read_text())['stats']
    assert (st['beams'], st['contradicted_share'], st['contradicted_segments']) == (0, None, None)


def test_drive_beams_are_the_drive_points_with_the_scan_poses(office_drive):
    points, origins = drive_beams(office_drive)
    np.testing.assert_array_equal(points, office_drive.points())
    spec = office_drive.spec
    r = office_drive.ranges
    valid = np.isfinite(r) & (r >= spec.range_min) & (r < spec.range_max)
    np.testing.assert_allclose(np.hypot(*(points - origins).T), r[valid], atol=1e-9)
    assert np.isin(origins[:, 1], office_drive.poses[:, 1]).all()


def test_plot_free_space_draws_beams_and_refuses_a_point_file_in_one_line(room, tmp_path,
                                                                          capsys):
    log = write_carmen(tmp_path / 'room.log.gz', room)
    mp = tmp_path / 'm.json'
    assert main(['fit', log, '-o', str(mp), '-q']) == 0
    png = tmp_path / 'fs.png'
    assert main(['plot', str(mp), '--points', log, '--free-space', '-o', str(png)]) == 0
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'segments contradicted' in capsys.readouterr().out
    npy = tmp_path / 'p.npy'
    np.save(npy, read_points(log)[0])
    bad = tmp_path / 'bad.png'
    for extra in (['--points', str(npy)], []):
        assert main(['plot', str(mp), '--free-space', '-o', str(bad)] + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith('polyline-mapper: error: ') and \
            '--free-space' in err[0], err
        assert not bad.exists()


def test_plot_judges_a_scan_matched_maps_beams_where_the_map_placed_them(tmp_path, capsys):
    # drifting odometry, scan matching: the map's trajectory, not /odom, placed the scans;
    # plot --free-space (and plot --points) draws and judges them there, as replay's stats did
    # (at the odometry's poses the same beams contradict 3 segments, 4.9 % of map length)
    drive = 'sim:office,odom_drift=3,step=0.5'
    mp = tmp_path / 'm.json'
    assert main(['replay', drive, '--pose-source', 'odom', '--scan-matching', '-o', str(mp),
                 '-q']) == 0
    stats = json.loads(mp.read_text())['stats']
    png = tmp_path / 'fs.png'
    out = plotted_as_judged(['plot', str(mp), '--points', drive, '--pose-source', 'odom',
                             '--free-space', '-o', str(png)], stats, capsys)
    n = stats['scans_used']
    assert f"beams at the map's trajectory ({n} of {n} scans)" in out, out
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    # a trajectory none of whose stamps is a scan of the input: one warning, the input's poses
    data = json.loads(mp.read_text())
    data['trajectory'] = [[t + 0.05] + rest for t, *rest in data['trajectory']]
    moved = tmp_path / 'moved.json'
    moved.write_text(json.dumps(data))
    assert main(['plot', str(moved), '--points', drive, '--pose-source', 'odom', '--free-space',
                 '-o', str(tmp_path / 'other.png')]) == 0
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and "none of its scans is in the map's trajectory" in err[0], err
    assert "at the map's trajectory" not in cap.out and 'segments contradicted' in cap.out


def plotted_as_judged(argv: list, stats: dict, capsys) -> str:
    """Run ``plot --free-space``; assert it judges as the map's stats did; return its output."""
    assert main(argv) == 0
    out = capsys.readouterr().out
    said = re.search(r'(\d+) segments contradicted \(([\d.]+)% of map length\)', out)
    assert int(said.group(1)) == stats['contradicted_segments'], out
    assert float(said.group(2)) == pytest.approx(100 * stats['contradicted_share'], abs=0.05)
    return out


def test_plot_poses_a_bag_as_its_map_did_when_not_told(tmp_path, capsys):
    # A bag with /odom and /scan only (no /tf), the laser mounted off the base: its replay (and
    # fit) needs --pose-source odom --laser-mount. The map records them, and plot --points of
    # the same bag poses it so without them being repeated (it failed: no /tf to place the
    # scans).
    drive = room_drive(mount=(0.2, -0.1, np.pi / 2), step=0.3, rng=8)
    bag = write_bag(tmp_path / 'odom_only', drive_messages(drive, tf=False, static=False))
    mp = tmp_path / 'm.json'
    assert main(['replay', bag, '--pose-source', 'odom', '--laser-mount', '0.2,-0.1,90',
                 '--scan-matching', '-o', str(mp), '-q']) == 0
    stats = json.loads(mp.read_text())['stats']
    assert (stats['pose_source'], stats['odom_topic'], stats['scan_topic'],
            stats['laser_mount']) == ('odom', '/odom', '/scan', '0.2,-0.1,90')
    capsys.readouterr()
    out = plotted_as_judged(['plot', str(mp), '--points', bag, '--free-space', '-o',
                             str(tmp_path / 'fs.png')], stats, capsys)
    n = stats['scans_used']
    assert (f"beams at the map's trajectory ({n} of {n} scans, posed as when mapped: "
            '--pose-source odom --odom-topic /odom --laser-mount 0.2,-0.1,90 --scan-topic '
            '/scan)') in out, out
    # the same for a batch fit of the bag (no trajectory: the scans at the poses registered)
    fp = tmp_path / 'f.json'
    assert main(['fit', bag, '--pose-source', 'odom', '--laser-mount', '0.2,-0.1,90', '-o',
                 str(fp), '-q']) == 0
    fstats = json.loads(fp.read_text())['stats']
    assert (fstats['pose_source'], fstats['odom_topic'], fstats['laser_mount'],
            fstats['input']) == ('odom', '/odom', '0.2,-0.1,90', 'odom_only')
    out = plotted_as_judged(['plot', str(fp), '--points', bag, '--free-space', '-o',
                             str(tmp_path / 'ffs.png')], fstats, capsys)
    assert '(posed as when mapped: --pose-source odom' in out, out
    # options given are the user's (a pose source other than the map's is warned of): tf mode
    # finds no transform in this bag
    assert main(['plot', str(mp), '--points', bag, '--pose-source', 'tf', '-o',
                 str(tmp_path / 'tf.png'), '-q']) == 2
    err = capsys.readouterr().err
    assert 'the map was made with --pose-source odom; registered with --pose-source tf' in err
    # another recording than the map's input: its own options (tf) as before
    other = write_bag(tmp_path / 'other', drive_messages(drive, tf=False, static=False))
    assert main(['plot', str(mp), '--points', other, '-o', str(tmp_path / 'o.png'), '-q']) == 2
    # in scan mode the chord knots place the scans too: a map made with --chord-knots arc was
    # registered with the default, median (a review of 2026-12-02: 401 of a bag's 405 scans)
    arc = tmp_path / 'arc.json'
    assert main(['replay', bag, '--pose-source', 'scan', '--chord-knots', 'arc', '-o', str(arc),
                 '-q']) == 0
    astats = json.loads(arc.read_text())['stats']
    assert astats['chord_knots'] == 'arc' and 'chord_knots' not in stats
    capsys.readouterr()
    out = plotted_as_judged(['plot', str(arc), '--points', bag, '--free-space', '-o',
                             str(tmp_path / 'arc.png')], astats, capsys)
    n = astats['scans_used']
    assert (f'({n} of {n} scans, posed as when mapped: --pose-source scan --scan-topic /scan '
            '--chord-knots arc)') in out, out


def test_passing_beams_flags_each_beam_that_passes_through_any_segment():
    # Against every (segment, beam) pair tested one by one (pair_tests), seeded random walls
    # and returns around one laser position.
    from polyline_mapper.core.freespace import pair_tests, passing_beams, TOL
    rng = np.random.default_rng(7)
    segs = rng.uniform(-4, 4, (12, 2, 2))
    origin = np.array([0.3, -0.2])
    ang = rng.uniform(-np.pi, np.pi, 400)
    reach = rng.uniform(0.2, 6.0, 400)[:, None]
    points = origin + reach * np.column_stack([np.cos(ang), np.sin(ang)])
    d = points - origin
    r = np.hypot(d[:, 0], d[:, 1])
    b, k = np.meshgrid(np.arange(len(points)), np.arange(len(segs)), indexing='ij')
    b, k = b.ravel(), k.ravel()
    through, _ = pair_tests(d[b], r[b], segs[k, 0] - origin, segs[k, 1] - segs[k, 0], TOL,
                            np.sin(np.deg2rad(20.0)))
    expected = np.zeros(len(points), dtype=bool)
    expected[b[through]] = True
    got = passing_beams(segs, origin, points)
    assert 0.2 < expected.mean() < 0.9 and np.array_equal(got, expected)
    assert not passing_beams(np.zeros((0, 2, 2)), origin, points).any()
