"""Replay: CARMEN <-> bag round trips, laser mounts, poses from tf and odom, skipped scans, CLI."""

import gzip
import json

from bag_helpers import drive_messages, room_drive, write_bag, write_carmen, write_ros1_bag
from conftest import radish_head
import numpy as np
from polyline_mapper.cli import main, SEEN_THROUGH_WARN
from polyline_mapper.core.index import nearest_distance
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.mapjson import read_map
from polyline_mapper.poses import mount_quaternion
from polyline_mapper.recordings import drive_messages as recordings_drive_messages, make_drive
from polyline_mapper.replay import run_replay
from polyline_mapper.session import SessionOptions as ReplayOptions
import pytest


def segments_of(result) -> np.ndarray:
    return result.mapper.polylines()[0]


def assert_same_map(a, b, tol=1e-6):
    sa, sb = segments_of(a), segments_of(b)
    assert sa.shape == sb.shape and len(sa) > 0
    assert np.abs(sa - sb).max() <= tol


def wall_error(segments, world) -> np.ndarray:
    """Distance (m) of each segment's ends and midpoint to the nearest wall of the world."""
    pts = np.concatenate([segments[:, 0], segments[:, 1], segments.mean(axis=1)])
    return nearest_distance(pts, world.walls)[0]


def long_walls_found(segments, world, min_length=2.5) -> int:
    """How many walls longer than ``min_length`` have a segment along 80 % of them within 5 cm."""
    found = 0
    for a, b in world.walls:
        length = np.hypot(*(b - a))
        if length < min_length:
            continue
        u = (b - a) / length
        covered = 0.0
        for s in segments:
            d = nearest_distance(s, np.array([[a, b]]))[0]
            if d.max() < 0.05:
                t = np.sort((s - a) @ u)
                covered += max(0.0, min(t[1], length) - max(t[0], 0.0))
        found += covered >= 0.8 * length
    return found


def test_intel_carmen_and_its_bags_replay_to_the_same_map(tmp_path):
    # the first 300 scans of the Intel log, as a log of their own
    log = radish_head('intel-corrected.log.gz', 300, tmp_path)
    direct = run_replay(str(log))
    assert direct.used == 300 and not direct.skipped and direct.fixed_frame == 'map'
    # the laser poses of the log reach the mapper: points as registered by the log's own poses
    np.testing.assert_allclose(direct.points, read_carmen(str(log)).points(), atol=1e-5)
    for storage in ('sqlite3', 'mcap'):
        bag = tmp_path / f'intel300-{storage}'
        assert main(['convert', str(log), '-o', str(bag), '--storage', storage, '-q']) == 0
        via_bag = run_replay(str(bag))
        assert via_bag.used == 300 and not via_bag.skipped
        assert_same_map(direct, via_bag)
        np.testing.assert_array_equal(direct.points, via_bag.points)
    stats = direct.stats()
    assert stats['mean_distance'] < 0.06 and stats['coverage_0_10m'] > 0.9


@pytest.mark.parametrize('spec, matching', [('office,odom_drift=3', False),
                                            ('office,odom_drift=3,moving_sensor=1', True)])
def test_a_simulated_drive_replays_as_the_same_drive_recorded(tmp_path, spec, matching):
    # A bag holds the LaserScan fields at float32: replaying the drive directly must map from
    # the same numbers (its float64 beam angles once gave 99 segments against the bag's 87).
    drive = make_drive(spec)
    bag = write_bag(tmp_path / 'drive', ((topic, record, t) for t, topic, record in
                                         recordings_drive_messages(drive, odom_drift=3)))
    options = ReplayOptions(pose_source='odom', scan_matching=matching)
    direct, via_bag = (run_replay(source, options=options) for source in (f'sim:{spec}', bag))
    # (a moving sensor's last scan ends after the last odometry: not placed, by either)
    assert direct.used == via_bag.used >= len(drive.stamps) - 1
    np.testing.assert_array_equal(segments_of(direct), segments_of(via_bag))
    np.testing.assert_array_equal(direct.map_value.trajectory, via_bag.map_value.trajectory)


def test_simulated_carmen_with_mount_and_odometry_drift_round_trip(tmp_path, capsys):
    # FLASER geometry (181 beams over 180 deg), laser 4 cm behind the robot centre as in the
    # Freiburg logs, odometry drifting away from the corrected poses
    drive = room_drive(mount=(-0.04, 0.0, 0.0), beams=181, fov=180.0, step=0.25, rng=5)
    log = write_carmen(tmp_path / 'sim.log.gz', drive, odom_drift=0.01, front_offset=-0.04,
                       garbage_line=10)
    carmen = read_carmen(log)
    np.testing.assert_allclose(carmen.laser_offset, [-0.04, 0, 0])
    assert carmen.skipped == 1
    bag = tmp_path / 'sim-bag'
    assert main(['convert', log, '-o', str(bag), '--storage', 'mcap']) == 0
    out = capsys.readouterr()
    assert 'base_link -> laser (-0.04, 0, 0 deg)' in out.out
    assert 'skipped 1 malformed laser record(s), e.g. line' in out.err
    direct, via_bag = run_replay(log), run_replay(str(bag))
    assert direct.used == via_bag.used == len(drive.stamps)
    assert_same_map(direct, via_bag)
    segs = segments_of(direct)
    assert wall_error(segs, drive.world).max() < 0.1
    assert long_walls_found(segs, drive.world) >= 3    # the left wall is only seen grazing
    # /odom in that bag is the drifting odometry: its map is in the odom frame, and worse
    odom = run_replay(str(bag), options=ReplayOptions(pose_source='odom'))
    assert odom.fixed_frame == 'odom' and odom.used == len(drive.stamps)
    assert odom.stats()['mean_distance'] > direct.stats()['mean_distance']


@pytest.fixture(scope='module')
def rotated():
    """Drive with the laser 0.2 m ahead, 0.1 m right of the base, turned 90 deg left."""
    return room_drive(mount=(0.2, -0.1, np.pi / 2), step=0.3, rng=8)


def test_lidar_mounted_rotated_90_degrees_gives_a_straight_map(tmp_path, rotated):
    bag = write_bag(tmp_path / 'rot', drive_messages(rotated))
    res = run_replay(bag)
    assert res.fixed_frame == 'odom' and res.used == len(rotated.stamps)
    segs = segments_of(res)
    assert wall_error(segs, rotated.world).max() < 0.1
    assert long_walls_found(segs, rotated.world) == 4
    # the same scans with a mount claiming no rotation give no such map
    wrong = write_bag(tmp_path / 'wrong', drive_messages(rotated, mount=(0.2, -0.1, 0.0)))
    bad = run_replay(wrong)
    d = nearest_distance(bad.points, rotated.world.walls)[0]
    assert np.mean(d) > 0.5
    # odometry plus the static mount: the very same map
    odom = run_replay(bag, options=ReplayOptions(pose_source='odom'))
    assert_same_map(res, odom, tol=1e-9)
    # an explicit mount (the node's laser_* parameters) wins over a wrong /tf_static
    fixed = run_replay(wrong, options=ReplayOptions(pose_source='odom',
                                                    mount=(0.2, -0.1, np.pi / 2)))
    assert_same_map(res, fixed, tol=1e-9)


def test_upside_down_lidar_from_tf_static_and_from_the_mount_option(tmp_path):
    drive = room_drive(mount=(0.1, 0.0, np.pi / 2), step=0.3, rng=9)
    drive.ranges = drive.ranges[:, ::-1].copy()     # beams sweep clockwise seen from above
    q = mount_quaternion(np.pi / 2, upside_down=True)
    bag = write_bag(tmp_path / 'flip', drive_messages(drive, mount_quaternion=q))
    res = run_replay(bag)
    assert wall_error(segments_of(res), drive.world).max() < 0.1
    assert long_walls_found(segments_of(res), drive.world) == 4
    nostatic = write_bag(tmp_path / 'nostatic', drive_messages(drive, static=False))
    out = tmp_path / 'm.json'
    assert main(['replay', nostatic, '-o', str(out), '--pose-source', 'odom',
                 '--laser-mount', '0.1,0,90,flip', '-q']) == 0
    segs = read_map(str(out))['segments_array']
    assert wall_error(segs, drive.world).max() < 0.1
    assert main(['replay', nostatic, '-o', str(out), '--pose-source', 'odom',
                 '--laser-mount', '0.1,0,90', '-q']) == 0          # not flipped: a mirror
    assert np.mean(wall_error(read_map(str(out))['segments_array'], drive.world)) > 0.3


def test_missing_and_stale_transforms_are_counted_or_fatal(tmp_path, rotated, capsys):
    out = tmp_path / 'm.json'
    # no /tf_static: the laser frame is never connected -> nothing to map -> exit 2
    nostatic = write_bag(tmp_path / 'nostatic', drive_messages(rotated, static=False))
    assert main(['replay', nostatic, '-o', str(out), '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'no scan could be mapped' in err[0]
    assert f'{len(rotated.stamps)} no pose: unknown_frame' in err[0]
    # ... and says how the scans can be placed: by the odometry and the laser's mount
    assert err[0].endswith("no transform names the scans' frame 'laser': give the laser's pose "
                           'on the robot with --pose-source odom --laser-mount X,Y,YAW_DEG (the '
                           'odometry then places the robot)')
    assert not out.exists()
    assert main(['replay', nostatic, '-o', str(out), '--pose-source', 'odom', '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frame 'laser' is unknown" in err[0]
    assert 'the robot with --laser-mount X,Y,YAW_DEG' in err[0]
    assert main(['replay', nostatic, '-o', str(out), '--pose-source', 'odom', '--laser-mount',
                 ','.join(f'{v:g}' for v in (*rotated.mount[:2], np.degrees(rotated.mount[2]))),
                 '-q']) == 0
    assert wall_error(read_map(str(out))['segments_array'], rotated.world).max() < 0.1
    # /odom and /tf_static but no moving transform (a ROS 1 robot recorded without /tf): the
    # error pointed only to a fixed frame for a sensor that does not move, which mapped the
    # moving robot as standing still; it names the odometry now, which places it
    static = write_ros1_bag(tmp_path / 'static.bag', drive_messages(rotated, tf=False))
    assert main(['replay', static, '-o', str(out), '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'only through static transforms' in err[0]
    assert err[0].endswith('the recording has odometry (nav_msgs/Odometry): --pose-source odom '
                           'places the robot by it, the laser on it as /tf_static mounts it')
    assert main(['replay', static, '-o', str(out), '--pose-source', 'odom', '-q']) == 0
    assert wall_error(read_map(str(out))['segments_array'], rotated.world).max() < 0.1
    # a fixed frame that is not in the tree
    bag = write_bag(tmp_path / 'ok', drive_messages(rotated))
    assert main(['replay', bag, '-o', str(out), '--fixed-frame', 'map', '-q']) == 2
    assert "frame 'map' is unknown" in capsys.readouterr().err
    # odom mode wants the map in the odometry frame
    assert main(['replay', bag, '-o', str(out), '--pose-source', 'odom', '--fixed-frame',
                 'map', '-q']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "odometry in frame 'odom', expected 'map'" in err[0]
    # /tf stops half way: the later scans have stale poses, counted and reported
    cut = rotated.stamps[len(rotated.stamps) // 2]
    stale = write_bag(tmp_path / 'stale', drive_messages(rotated, tf_until=cut))
    assert main(['replay', stale, '-o', str(out)]) == 0
    cap = capsys.readouterr()
    late = int(np.sum(rotated.stamps > cut + 0.1))
    assert f'skipped {late} scan(s)/message(s): no pose: too_new' in cap.err
    assert f'({late} no pose: too_new skipped)' in cap.out
    stats = read_map(str(out))['stats']
    assert stats['skipped'] == {'no pose: too_new': late}
    assert stats['scans_used'] == len(rotated.stamps) - late


def test_replay_cli_writes_the_map_schema_png_and_config(tmp_path, rotated, capsys):
    bag = write_bag(tmp_path / 'b', drive_messages(rotated), 'mcap')
    out, png = tmp_path / 'm.json', tmp_path / 'm.png'
    assert main(['replay', bag, '-o', str(out), '--plot', str(png), '--every', '2',
                 '--set', 'buffer_scans=2', '--set', 'sigma=0.02']) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f'wrote {out}: ') and 'update median' in line
    data = read_map(str(out))
    assert data['frame_id'] == 'odom' and data['schema_version'] == 1
    assert len(data['support']) == len(data['segments']) > 0
    assert sum(len(p) - 1 + c for p, c in zip(data['polylines'], data['closed'])) == \
        len(data['segments'])
    cfg = data['config']
    assert cfg['buffer_scans'] == 2 and cfg['sigma'] == 0.02 and 'merge_threshold' in cfg
    stats = data['stats']
    n = len(rotated.stamps)
    assert stats['scans'] == n and stats['scans_used'] == (n + 1) // 2
    assert stats['pose_source'] == 'tf' and stats['every'] == 2
    for key in ('mean_distance', 'p95_distance', 'coverage_0_10m', 'update_ms_median',
                'update_ms_p99', 'points', 'segments', 'polylines'):
        assert stats[key] is not None
    assert stats['mean_distance'] < 0.03 and stats['coverage_0_10m'] > 0.95
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    # bad settings end in one line, exit 2, no output
    for argv in (['--set', 'buffer_scans=0'], ['--set', 'nonsense=1'], ['--every', '0'],
                 ['--laser-mount', '1,2'], ['--scan-topic', '/scan']):
        target = tmp_path / 'never.json'
        rc = main(['replay', argv[0] == '--scan-topic' and str(tmp_path / 'x.log') or bag,
                   '-o', str(target), '-q'] + argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and err[0].startswith('polyline-mapper: error:'), argv
        assert not target.exists()


def test_corrupt_carmen_lines_are_skipped_and_reported(tmp_path, capsys):
    drive = room_drive(beams=181, fov=180.0, step=0.5, rng=4)
    log = write_carmen(tmp_path / 'c.log.gz', drive, garbage_line=3)
    out = tmp_path / 'c.json'
    assert main(['replay', log, '-o', str(out), '-q']) == 0
    err = capsys.readouterr().err
    assert 'skipped 1 malformed laser record(s), e.g. line 6: FLASER announces 181' in err
    stats = read_map(str(out))['stats']
    assert '1 malformed record(s) skipped' in stats['input_type']
    assert stats['scans_used'] == len(drive.stamps)
    # a log whose every laser line is broken, and a truncated gzip: one line, exit 2
    bad = tmp_path / 'bad.log'
    bad.write_text('FLASER 3 1 2\nFLASER x\n')
    assert main(['replay', str(bad), '-o', str(out), '-q']) == 2
    assert 'no usable FLASER or ROBOTLASER1 record (2 malformed)' in capsys.readouterr().err
    data = open(log, 'rb').read()
    trunc = tmp_path / 'trunc.log.gz'
    trunc.write_bytes(data[:len(data) // 2])
    assert main(['replay', str(trunc), '-o', str(out), '-q']) == 2
    assert 'unreadable or truncated log' in capsys.readouterr().err
    assert json.loads(out.read_text())['stats']['scans_used'] == len(drive.stamps)
    # readings that are no range are dropped as the mapper drops them, and counted (a new-user
    # audit: a log of negative readings mapped with no word on them)
    lines = gzip.open(log, 'rt').read().splitlines(True)
    fields = lines[4].split()
    fields[2:5] = ['-1.5', 'nan', '-0.2']
    neg = tmp_path / 'neg.log'
    neg.write_text(''.join(lines[:4] + [' '.join(fields) + '\n'] + lines[5:]))
    for command in ('replay', 'fit'):
        assert main([command, str(neg), '-o', str(out), '-q']) == 0
        assert (f'polyline-mapper: warning: {neg}: dropped 3 reading(s) that are no range '
                '(negative or NaN)\n') in capsys.readouterr().err


def test_bad_scans_are_checked_like_the_node_and_counted(tmp_path, rotated, capsys):
    msgs = list(drive_messages(rotated))
    scans = [i for i, (topic, _, _) in enumerate(msgs) if topic == '/scan']
    for k in (2, 4):
        msgs[scans[k]][1].ranges = np.full_like(msgs[scans[k]][1].ranges, np.nan)
    broken = msgs[scans[6]][1]
    broken.range_min, broken.range_max = 5.0, 1.0
    bag = write_bag(tmp_path / 'bad-scans', msgs)
    out = tmp_path / 'm.json'
    assert main(['replay', bag, '-o', str(out), '-q']) == 0
    err = capsys.readouterr().err
    assert 'skipped 2 scan(s)/message(s): bad scan: no_valid_ranges' in err
    assert 'skipped 1 scan(s)/message(s): bad scan: range_limits' in err
    stats = read_map(str(out))['stats']
    assert stats['skipped'] == {'bad scan: no_valid_ranges': 2, 'bad scan: range_limits': 1}
    assert stats['scans_used'] == len(rotated.stamps) - 3


def test_convert_errors_leave_nothing_behind(tmp_path, capsys, monkeypatch):
    drive = room_drive(beams=181, fov=180.0, step=0.5, rng=6)
    log = write_carmen(tmp_path / 'c.log.gz', drive)
    (tmp_path / 'taken').mkdir()
    bad = tmp_path / 'bad.log'
    bad.write_text('FLASER 2 oops\n')
    for argv in ([log, '-o', str(tmp_path / 'taken')], [str(bad), '-o', str(tmp_path / 'x')],
                 [str(tmp_path / 'missing.log'), '-o', str(tmp_path / 'x')],
                 [log, '-o', str(tmp_path / 'x'), '--period', '0']):
        assert main(['convert'] + argv + ['-q']) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith('polyline-mapper: error:'), (argv, err)
    # a bag (here a ROS 1 one) or a simulated drive is not read as a CARMEN log: said so
    ros1 = write_ros1_bag(tmp_path / 'r.bag', drive_messages(drive))
    for given, what in ((ros1, 'this is a bag: replay, fit, plot and play read bags'),
                        ('sim:office', 'this is a simulated drive')):
        assert main(['convert', given, '-o', str(tmp_path / 'x'), '-q']) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and 'convert writes a rosbag2 from a CARMEN log' in err[0], err
        assert what in err[0]
    # a failure half way through writing: no bag, no temporary folder
    from polyline_mapper.formats import bag as bagmod
    calls = []

    def failing(self, topic, record, log_time):
        calls.append(topic)
        if len(calls) > 20:
            raise OSError(28, 'No space left on device', 'x.db3')
    monkeypatch.setattr(bagmod.BagWriter, 'write', failing)
    assert main(['convert', log, '-o', str(tmp_path / 'x'), '-q']) == 2
    assert 'No space left on device' in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bad.log', 'c.log.gz', 'r.bag',
                                                          'taken']


def test_replays_of_the_same_input_write_the_same_map_but_for_timing(tmp_path, rotated, capsys):
    # Map content is bit-identical run to run; only timing fields may differ.
    bag = write_bag(tmp_path / 'again', drive_messages(rotated))
    maps = []
    for k in range(2):
        out = tmp_path / f'run{k}.json'
        assert main(['replay', bag, '-o', str(out), '-q']) == 0
        data = json.loads(out.read_text())
        for key in ('seconds', 'total_seconds', 'update_ms', 'update_ms_median',
                    'update_ms_p99'):
            data['stats'].pop(key, None)
        maps.append(data)
    assert maps[0] == maps[1] and len(maps[0]['segments']) > 5


def test_replay_groups_scans_into_updates_like_the_node(tmp_path, rotated, capsys):
    bag = write_bag(tmp_path / 'grouped', drive_messages(rotated))
    maps = {}
    for n in (1, 3):
        out = tmp_path / f'n{n}.json'
        assert main(['replay', bag, '-o', str(out), '-q', '--update-every-n-scans', str(n)]) == 0
        maps[n] = json.loads(out.read_text())
    assert maps[3]['stats']['updates'] < maps[1]['stats']['updates']
    assert maps[1]['stats']['scans_used'] == maps[3]['stats']['scans_used']
    assert main(['replay', bag, '-o', str(tmp_path / 'x.json'), '-q',
                 '--update-every-n-scans', '0']) == 2


def test_a_scan_matched_odometry_replay_is_in_the_map_frame(tmp_path, rotated):
    # With --pose-source odom the map is the odometry frame, unless the scans are matched: the
    # matched map leaves the odometry frame as the odometry drifts, and is 'map' (the node's
    # default fixed_frame, REP 105) or the --fixed-frame given; the name alone differs.
    bag = write_bag(tmp_path / 'odo', drive_messages(rotated))
    maps = {}
    for extra, frame in (([], 'odom'), (['--scan-matching'], 'map'),
                         (['--scan-matching', '--fixed-frame', 'world'], 'world')):
        out = tmp_path / f'{frame}.json'
        assert main(['replay', bag, '-o', str(out), '--pose-source', 'odom', '-q'] + extra) == 0
        data = read_map(str(out))
        assert data['frame_id'] == frame and data['stats']['fixed_frame'] == frame, extra
        # the free-space window: -1 ('by the pose source') as configured, the one used in the
        # stats (an export audit: the file did not say whether the evidence was on)
        assert data['config']['free_space_window'] == -1
        assert data['stats']['free_space_window'] == (0 if extra else 10), extra
        maps[frame] = data
    assert maps['map']['segments'] == maps['world']['segments']
    assert maps['map']['trajectory'] == maps['world']['trajectory']


def test_a_scan_matched_tf_replay_without_a_map_frame_is_in_the_map_frame(tmp_path):
    # A robot without a localizer: /tf odom -> base_link drifts and there is no map frame.
    # Unmatched, the map is the tree's root (odom); matched, it leaves odom as the odometry
    # drifts and is 'map' above it, as the same recording's odom-mode replay and the node's
    # (it was labelled 'odom'). The map and trajectory are the odom mode's, number for number.
    drive, maps = 'sim:office,odom_drift=2', {}
    for source, extra, frame in (('tf', [], 'odom'), ('tf', ['--scan-matching'], 'map'),
                                 ('odom', ['--scan-matching'], 'map')):
        out = tmp_path / f'{source}{len(extra)}.json'
        assert main(['replay', drive, '-o', str(out), '--pose-source', source, '-q']
                    + extra) == 0
        data = read_map(str(out))
        assert data['frame_id'] == frame and data['stats']['fixed_frame'] == frame, extra
        assert data['stats']['scans_used'] == 355
        maps[source, len(extra)] = data
    assert maps['tf', 1]['segments'] == maps['odom', 1]['segments']
    assert maps['tf', 1]['trajectory'] == maps['odom', 1]['trajectory']
    assert maps['tf', 1]['segments'] != maps['tf', 0]['segments']


def test_a_map_the_beams_see_through_warns_of_the_mount_and_the_poses(tmp_path, rotated, capsys):
    # The laser is mounted turned 90 deg; given as turned -90 deg, the scans disagree and the
    # beams pass through most of the map: one warning naming the mount and the poses (a new
    # user's replay with a backwards laser given yaw 0 printed a good-looking summary only).
    bag = write_bag(tmp_path / 'odo', drive_messages(rotated, static=False))
    out = tmp_path / 'm.json'
    x, y = rotated.mount[:2]
    for yaw, warned in ((90, False), (-90, True)):
        assert main(['replay', bag, '-o', str(out), '--pose-source', 'odom', '--laser-mount',
                     f'{x:g},{y:g},{yaw}', '-q']) == 0
        share = read_map(str(out))['stats']['contradicted_share']
        err = [line for line in capsys.readouterr().err.splitlines() if 'pass through' in line]
        assert (share > SEEN_THROUGH_WARN) == warned and len(err) == warned, (yaw, share, err)
    assert err[0].endswith("check the laser's mount (--laser-mount: a laser facing backwards "
                           'has yaw 180, one upside down flip) and the poses (drifting '
                           'odometry: --scan-matching)')
    # fit of the same bag warned of nothing (new-user audit: 31 % contradicted, 62.6 %
    # coverage, no word); it has no --scan-matching, so replay's is named
    assert main(['fit', bag, '-o', str(out), '--pose-source', 'odom', '--laser-mount',
                 f'{x:g},{y:g},-90', '-q']) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if 'scans disagree' in line]
    assert len(err) == 1 and err[0].endswith('(drifting odometry: replay --scan-matching)'), err


def test_the_disagreement_warning_names_what_the_user_can_still_change():
    # It told users already matching (scan mode, a saved map) to add --scan-matching; with a
    # saved map the likely cause is the initial pose (new-user audit).
    from argparse import Namespace
    from polyline_mapper.cli import _seen_through
    bad = {'segments': 10, 'contradicted_share': 0.3, 'coverage_0_10m': 0.6}
    hint = {}
    for name, args in (('tf', Namespace(pose_source='tf', scan_matching=False, map=None)),
                       ('matched', Namespace(pose_source='tf', scan_matching=True, map=None)),
                       ('scan', Namespace(pose_source='scan', scan_matching=False, map=None)),
                       ('saved', Namespace(pose_source='tf', scan_matching=False, map='m.json')),
                       ('fit', Namespace(pose_source='tf'))):
        hint[name] = _seen_through(bad, args).partition('; check ')[2]
    assert hint['tf'] == 'the poses (drifting odometry: --scan-matching)'
    assert hint['matched'] == hint['scan'] == 'the poses'
    assert hint['saved'] == ('the initial pose (--initial-pose X,Y,YAW_DEG) and that the saved '
                             'map is of this place')
    assert hint['fit'] == 'the poses (drifting odometry: replay --scan-matching)'
    assert _seen_through({**bad, 'contradicted_share': 0.01, 'coverage_0_10m': 0.97},
                         Namespace(pose_source='tf', scan_matching=False, map=None)) == ''


def test_a_map_of_drifting_odometry_warns_though_the_evidence_cut_what_the_beams_saw(tmp_path,
                                                                                     capsys):
    # The first 300 Intel scans with wheel-odometry drift (seed 2), mapped by the odometry
    # alone: the free-space evidence cuts what later beams see through, so only 6 % of the map
    # is contradicted (under the 10 % warning) while a third of the points lie off it. A
    # new-user audit's whole drifted Intel log (8.5 %, coverage 66 %) was written without a
    # word; the coverage now warns too.
    from polyline_mapper.cli import UNCOVERED_WARN
    from polyline_mapper.formats.carmen_bag import carmen_to_bag
    log = radish_head('intel-corrected.log.gz', 300, tmp_path)
    carmen_to_bag(str(log), str(tmp_path / 'bag'), drift_seed=2)
    out = tmp_path / 'm.json'
    assert main(['replay', str(tmp_path / 'bag'), '--pose-source', 'odom', '-o', str(out),
                 '-q']) == 0
    stats = read_map(str(out))['stats']
    assert stats['contradicted_share'] < SEEN_THROUGH_WARN < 0.5 < stats['coverage_0_10m'] \
        < UNCOVERED_WARN, stats
    err = [line for line in capsys.readouterr().err.splitlines() if 'disagree' in line]
    assert len(err) == 1 and 'more than 0.10 m off' in err[0] and 'pass through' not in err[0]
    assert err[0].endswith('and the poses (drifting odometry: --scan-matching)')
    # ... and the same scans matched are consistent: no warning
    assert main(['replay', str(tmp_path / 'bag'), '--pose-source', 'odom', '--scan-matching',
                 '-o', str(out), '-q']) == 0
    assert 'disagree' not in capsys.readouterr().err


def test_the_written_trajectory_keeps_yaw_in_its_half_open_range(tmp_path):
    # The office drive heads west (yaw pi, or -pi as atan2 gives it) along its corridor:
    # rounded to 1e-6 rad, 61 of its 355 rows were written as -3.141593, below -pi, and
    # `export --trajectory -o X.tum` wrote their qw as -0.000000.
    out = tmp_path / 'office.json'
    assert main(['replay', 'sim:office', '-o', str(out), '-q']) == 0
    yaw = np.array(json.loads(out.read_text())['trajectory'])[:, 3]
    assert np.all((yaw >= -np.pi) & (yaw < np.pi)), yaw.min()
    assert (np.abs(yaw) > 3.14159).sum() >= 30          # the rows at the edge are there
    tum = tmp_path / 'office.tum'
    assert main(['export', str(out), '--trajectory', '-o', str(tum)]) == 0
    assert '-0.000000' not in tum.read_text()
