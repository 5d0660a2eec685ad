"""Bag reading: rosbag2 sqlite3 / mcap (folder or file) and ROS 1, topics, damaged bags."""

from dataclasses import replace
import os
import sqlite3
import sys

from bag_helpers import drive_messages, room_drive, write_bag, write_ros1_bag
import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.formats.bag import BagError, BagReader, BagWriter
from polyline_mapper.formats.records import Odometry, Scan, Skipped, Transform
import pytest


@pytest.fixture(scope='module')
def drive():
    return room_drive(step=0.5, rng=11)


def read_all(path, **kw):
    with BagReader(str(path), **kw) as bag:
        return bag, list(bag.records())


def check_records(records, drive, slash=False):
    scans = [r for r in records if isinstance(r, Scan)]
    tfs = [r for r in records if isinstance(r, Transform)]
    odoms = [r for r in records if isinstance(r, Odometry)]
    n = len(drive.stamps)
    assert len(scans) == n and len(odoms) == n and len(tfs) == n + 1
    assert all(s.frame_id == 'laser' for s in scans)          # leading slash removed
    np.testing.assert_allclose([s.stamp for s in scans], drive.stamps, atol=1e-9)
    got = np.array([s.ranges for s in scans])
    want = drive.ranges.astype(np.float32)
    assert got.dtype == np.float32
    assert np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    assert np.array_equal(got[ok], want[ok])
    np.testing.assert_allclose(scans[0].angles(), drive.spec.angles(), atol=1e-6)
    static = [t for t in tfs if t.static]
    assert len(static) == 1 and (static[0].parent, static[0].child) == ('base_link', 'laser')
    dyn = [t for t in tfs if not t.static]
    np.testing.assert_allclose([t.translation[:2] for t in dyn], drive.base[:, :2], atol=1e-12)
    assert odoms[3].frame_id == 'odom' and odoms[3].child_frame_id == 'base_link'
    # recording order: stamps of the scans never go back
    assert np.all(np.diff([s.stamp for s in scans]) > 0)


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_rosbag2_folder_and_storage_file_read_the_same(tmp_path, drive, storage):
    path = write_bag(tmp_path / 'run', drive_messages(drive), storage)
    bag, recs = read_all(path, odometry=True)
    assert bag.scan_topic == '/scan' and bag.odom_topic == '/odom'
    assert bag.tf_topics == ['/tf', '/tf_static'] and bag.scan_count == len(drive.stamps)
    check_records(recs, drive)
    suffix = {'sqlite3': '.db3', 'mcap': '.mcap'}[storage]
    _, recs2 = read_all(os.path.join(path, 'run' + suffix), odometry=True)
    check_records(recs2, drive)


def test_ros1_bag(tmp_path, drive):
    path = write_ros1_bag(tmp_path / 'run.bag', drive_messages(drive))
    bag, recs = read_all(path, odometry=True)
    assert bag.scan_topic == '/scan'
    check_records(recs, drive)
    # the replay of the ROS 1 bag equals the replay of the same data as rosbag2
    ros2 = write_bag(tmp_path / 'run2', drive_messages(drive), 'mcap')
    out1, out2 = tmp_path / 'a.json', tmp_path / 'b.json'
    assert main(['replay', path, '-o', str(out1), '-q']) == 0
    assert main(['replay', ros2, '-o', str(out2), '-q']) == 0
    import json
    a, b = json.loads(out1.read_text()), json.loads(out2.read_text())
    assert a['segments'] == b['segments'] and len(a['segments']) >= 6


def test_scan_topic_autodetect_choice_and_errors(tmp_path, drive):
    msgs = list(drive_messages(drive))
    two = msgs + [('/scan_rear', r, t) for topic, r, t in msgs if topic == '/scan']
    path = write_bag(tmp_path / 'two', two)
    with pytest.raises(BagError, match=r'2 LaserScan topics \(/scan, /scan_rear\); choose one '
                       'with --scan-topic'):
        read_all(path)
    bag, recs = read_all(path, scan_topic='/scan_rear')
    assert bag.scan_topic == '/scan_rear'
    assert sum(isinstance(r, Scan) for r in recs) == len(drive.stamps)
    with pytest.raises(BagError, match='topic /odom is nav_msgs/msg/Odometry, not '
                       'sensor_msgs/msg/LaserScan; LaserScan topics: /scan, /scan_rear'):
        read_all(path, scan_topic='/odom')
    with pytest.raises(BagError, match='no topic /nope; LaserScan topics: /scan, /scan_rear'):
        read_all(path, scan_topic='/nope')
    odomless = write_bag(tmp_path / 'noodom', drive_messages(drive, odom=False))
    with pytest.raises(BagError, match='no nav_msgs/msg/Odometry topic in the bag'):
        read_all(odomless, odometry=True)


def run_cli(capsys, argv):
    rc = main(argv)
    err = capsys.readouterr().err
    return rc, err


def assert_one_line_error(rc, err, *fragments):
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('polyline-mapper: error: '), err
    assert 'Traceback' not in err
    for f in fragments:
        assert f in lines[0], lines[0]


def test_without_rosbags_a_bag_ends_with_one_line_saying_what_to_install(tmp_path, drive,
                                                                         capsys, monkeypatch):
    # rosbags has no rosdep key: a real ROS install may lack it (README). Reading or writing a
    # bag then says so in one line, not an ImportError traceback.
    bag = write_bag(tmp_path / 'good', drive_messages(drive), 'mcap')
    for name in ('rosbags', 'rosbags.highlevel', 'rosbags.rosbag2'):
        monkeypatch.setitem(sys.modules, name, None)        # import raises ImportError
    out = tmp_path / 'm.json'
    rc, err = run_cli(capsys, ['replay', bag, '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'needs the Python package rosbags', 'pip install rosbags')
    assert not out.exists()
    with pytest.raises(BagError, match='pip install rosbags'):     # convert's writer
        BagWriter(str(tmp_path / 'new'))


def test_damaged_and_empty_bags_end_with_one_line(tmp_path, drive, capsys):
    out = tmp_path / 'm.json'
    good = write_bag(tmp_path / 'good', drive_messages(drive), 'sqlite3')
    db3 = os.path.join(good, 'good.db3')
    # truncated sqlite3 storage file, alone and inside its rosbag2 folder
    data = open(db3, 'rb').read()
    with open(tmp_path / 'cut.db3', 'wb') as fh:
        fh.write(data[:len(data) // 3])
    rc, err = run_cli(capsys, ['replay', str(tmp_path / 'cut.db3'), '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'cut.db3')
    with open(db3, 'wb') as fh:
        fh.write(data[:len(data) // 2])
    rc, err = run_cli(capsys, ['replay', good, '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'good')
    with open(db3, 'wb') as fh:
        fh.write(data)
    # truncated mcap file and ROS 1 bag
    mc = write_bag(tmp_path / 'mc', drive_messages(drive), 'mcap')
    data = open(os.path.join(mc, 'mc.mcap'), 'rb').read()
    with open(tmp_path / 'short.mcap', 'wb') as fh:
        fh.write(data[:len(data) // 2])
    rc, err = run_cli(capsys, ['replay', str(tmp_path / 'short.mcap'), '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'short.mcap', 'ends early', "'mcap recover FILE -o")
    with open(tmp_path / 'five.mcap', 'wb') as fh:     # cut inside its magic: cut, not alien
        fh.write(data[:5])
    rc, err = run_cli(capsys, ['replay', str(tmp_path / 'five.mcap'), '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'five.mcap', 'ends early', "'mcap recover FILE -o")
    # a ROS 1 bag with nothing readable after its header (one cut short is read without its
    # index up to the cut: test_hostile_bag_index.py)
    r1 = write_ros1_bag(tmp_path / 'r1.bag', drive_messages(drive))
    data = open(r1, 'rb').read()
    with open(tmp_path / 'short.bag', 'wb') as fh:
        fh.write(data[:4096 + 13] + bytes(range(256)) * 40)
    rc, err = run_cli(capsys, ['replay', str(tmp_path / 'short.bag'), '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'short.bag', 'index is missing or damaged')
    # an empty bag (topics but no messages), a zero-byte file, a text file named .mcap
    empty = write_bag(tmp_path / 'empty', [])
    rc, err = run_cli(capsys, ['replay', empty, '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'no sensor_msgs/msg/LaserScan topic')
    (tmp_path / 'zero.db3').write_bytes(b'')
    rc, err = run_cli(capsys, ['replay', str(tmp_path / 'zero.db3'), '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'empty file')
    (tmp_path / 'text.mcap').write_text('hello\n')
    rc, err = run_cli(capsys, ['replay', str(tmp_path / 'text.mcap'), '-o', str(out), '-q'])
    # (not 'ends early ... mcap recover', the advice for a cut one: new-user audit)
    assert_one_line_error(rc, err, 'cannot open the bag',
                          'text.mcap is not an MCAP file (it does not start with the MCAP magic')
    assert 'mcap recover' not in err
    # wrong topic type
    rc, err = run_cli(capsys, ['replay', good, '-o', str(out), '--scan-topic', '/tf', '-q'])
    assert_one_line_error(rc, err, 'topic /tf is tf2_msgs/msg/TFMessage, not')
    assert not out.exists()


def test_undecodable_messages_are_counted_not_fatal(tmp_path, drive, capsys):
    path = write_bag(tmp_path / 'bad', drive_messages(drive), 'sqlite3')
    db = sqlite3.connect(os.path.join(path, 'bad.db3'))
    scan_id = db.execute("SELECT id FROM topics WHERE name = '/scan'").fetchone()[0]
    ids = [r[0] for r in db.execute('SELECT id FROM messages WHERE topic_id = ? ORDER BY '
                                    'timestamp', (scan_id,))]
    db.execute('UPDATE messages SET data = ? WHERE id IN (?, ?)', (b'\x00\x01\x00\x00\x07',
                                                                   ids[2], ids[5]))
    db.commit()
    db.close()
    _, recs = read_all(path)
    skipped = [r for r in recs if isinstance(r, Skipped)]
    assert len(skipped) == 2 and skipped[0].topic == '/scan'
    assert 'undecodable sensor_msgs/msg/LaserScan' in skipped[0].reason
    out = tmp_path / 'm.json'
    rc, err = run_cli(capsys, ['replay', path, '-o', str(out), '-q'])
    assert rc == 0 and 'Traceback' not in err
    assert 'skipped 2 scan(s)/message(s): undecodable message on /scan' in err
    import json
    stats = json.loads(out.read_text())['stats']
    assert stats['skipped'] == {'undecodable message on /scan': 2}
    assert stats['scans_used'] == len(drive.stamps) - 2


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap', 'ros1'])
def test_random_damage_never_escapes_as_a_traceback(tmp_path, storage):
    from polyline_mapper.replay import run_replay
    short = room_drive(step=1.0, rng=2)
    if storage == 'ros1':
        path = write_ros1_bag(tmp_path / 'r.bag', drive_messages(short))
    else:
        folder = write_bag(tmp_path / 'r', drive_messages(short), storage)
        path = os.path.join(folder, 'r.' + {'sqlite3': 'db3', 'mcap': 'mcap'}[storage])
    data = open(path, 'rb').read()
    rng = np.random.default_rng(5)
    outcomes = set()
    for k in range(40):
        bad = bytearray(data)
        start = int(rng.integers(0, len(data) - 8))
        n = int(rng.integers(1, 64))
        bad[start:start + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        target = tmp_path / f'bad{k}{os.path.splitext(path)[1]}'
        target.write_bytes(bytes(bad))
        try:
            res = run_replay(str(target), mapping=False)
            outcomes.add('read')
            n = len(short.stamps)
            assert res.scans <= n and res.used <= res.scans
            assert (res.scans == n) != any('damaged?' in w for w in res.warnings)
        except BagError:
            outcomes.add('error')
    assert outcomes == {'read', 'error'}


def test_plot_registers_the_points_of_a_bag(tmp_path, drive, capsys):
    bag = write_bag(tmp_path / 'p', drive_messages(drive))
    out, png = tmp_path / 'm.json', tmp_path / 'm.png'
    assert main(['replay', bag, '-o', str(out), '-q']) == 0
    assert main(['plot', str(out), '--points', bag, '-o', str(png)]) == 0
    n = int(np.sum(np.isfinite(drive.ranges) & (drive.ranges >= drive.spec.range_min)
                   & (drive.ranges < drive.spec.range_max)))
    assert f'over {n} points' in capsys.readouterr().out
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_tf_that_starts_after_the_first_scans_is_waited_for_not_mapped_at_the_mount(
        tmp_path, drive, capsys):
    # A recording whose /tf starts 0.6 s after its first scan (/tf_static first): the first
    # scans' only path to a root is the static mount base_link -> laser. The default fixed
    # frame was taken from it (base_link), and every scan was mapped at the origin.
    import json
    start = drive.stamps[0] + 0.6
    late = [m for m in drive_messages(drive) if not (m[0] == '/tf' and m[1][0].stamp < start)]
    bag = write_bag(tmp_path / 'late', late)
    out = tmp_path / 'm.json'
    rc, err = run_cli(capsys, ['replay', bag, '-o', str(out), '-q'])
    assert rc == 0 and 'Traceback' not in err
    data = json.loads(out.read_text())
    assert data['frame_id'] == 'odom' and data['stats']['fixed_frame'] == 'odom'
    traj = np.array(data['trajectory'])
    skipped = int(np.sum(drive.stamps < start - 0.1))       # beyond the 0.1 s tolerance
    assert data['stats']['skipped'] == {'no pose: too_old': skipped} and skipped >= 1
    assert len(traj) == len(drive.stamps) - skipped
    np.testing.assert_allclose(traj[:, 1:3], drive.base[skipped:, :2], atol=1e-3)
    # A sensor that never moves (only /tf_static): one line saying to name the fixed frame
    still = write_bag(tmp_path / 'still', [m for m in drive_messages(drive)
                                           if m[0] in ('/tf_static', '/scan')])
    rc, err = run_cli(capsys, ['replay', still, '-o', str(out), '-q'])
    assert_one_line_error(rc, err, 'only through static transforms', "e.g. 'base_link'")
    assert main(['replay', still, '-o', str(out), '-q', '--fixed-frame', 'base_link']) == 0
    assert json.loads(out.read_text())['frame_id'] == 'base_link'


def test_a_metadata_yaml_nested_too_deeply_is_one_line(tmp_path, drive, capsys):
    # rosbags' YAML parser recursed until RecursionError: a traceback of 3000 lines
    bag = write_bag(tmp_path / 'deep', drive_messages(drive))
    with open(os.path.join(bag, 'metadata.yaml'), 'w') as fh:
        fh.write('rosbag2_bagfile_information: ' + '[' * 100_000 + ']' * 100_000 + '\n')
    out = tmp_path / 'm.json'
    for argv in (['replay', bag, '-o', str(out)], ['fit', bag, '-o', str(out)]):
        rc, err = run_cli(capsys, argv + ['-q'])
        assert_one_line_error(rc, err, 'deep: cannot open the bag (RecursionError')
    assert not out.exists()


def test_fit_and_plot_of_a_bag_say_which_scans_they_left_out_as_replay_does(tmp_path, drive,
                                                                            capsys):
    # A new-user audit: `fit BAG` of a bag whose later scans name a frame without transforms
    # exited 0 with the points of half the scans and no word on the rest; replay warned.
    def renamed(messages):
        for topic, record, t in messages:
            if topic == '/scan' and t > drive.stamps[len(drive.stamps) // 2]:
                record = replace(record, frame_id='nowhere')
            yield topic, record, t

    bag = write_bag(tmp_path / 'half', renamed(drive_messages(drive)))
    left_out = int(np.sum(drive.stamps + 0.001 > drive.stamps[len(drive.stamps) // 2]))
    words = f'skipped {left_out} scan(s)/message(s): no pose: unknown_frame, e.g. frame '
    said = {}
    for command in ('replay', 'fit'):
        out = tmp_path / f'{command}.json'
        rc, err = run_cli(capsys, [command, bag, '-o', str(out), '-q'])
        assert rc == 0 and words in err, err
        said[command] = [line for line in err.splitlines() if 'skipped' in line]
    assert said['fit'] == said['replay']
    rc, err = run_cli(capsys, ['plot', str(tmp_path / 'replay.json'), '--points', bag, '-o',
                               str(tmp_path / 'p.png'), '-q'])
    assert rc == 0 and words in err, err


def test_a_bag_whose_ranges_do_not_fit_angle_max_is_refused_scan_by_scan(tmp_path, drive,
                                                                         capsys):
    # A driver that lists twice the ranges its angles hold (360 for a 180-degree scan, say:
    # angle_max says where they end) mapped without a word to 16 cm mean distance; each such
    # scan is now a bad scan, named.
    def doubled(messages):
        for topic, record, t in messages:
            if topic == '/scan':
                half = record.angle_increment * (len(record.ranges) - 1) / 2
                record = replace(record, angle_max=record.angle_min + half)
            yield topic, record, t

    good = write_bag(tmp_path / 'good', drive_messages(drive))
    with BagReader(good) as reader:
        scans = [r for r in reader.records() if isinstance(r, Scan)]
    assert scans and all(s.angle_max == pytest.approx(s.angle_min + s.angle_increment
                                                      * (len(s.ranges) - 1)) for s in scans)
    bad = write_bag(tmp_path / 'doubled', doubled(drive_messages(drive)))
    rc, err = run_cli(capsys, ['replay', bad, '-o', str(tmp_path / 'm.json'), '-q'])
    assert_one_line_error(rc, err, f'{len(drive.stamps)} bad scan: angle_max',
                          'the ranges do not fit the angles')


def test_an_empty_map_of_skipped_scans_names_the_skips_not_the_noise_estimate(tmp_path, drive,
                                                                              capsys):
    # A new-user audit: a bag whose scans all carry one stamp (a stuck clock) mapped 1 scan of
    # 60 and advised 'give more scans, or lower noise_updates'.
    def stuck(messages):
        for topic, record, t in messages:
            if topic == '/scan':
                record = replace(record, stamp=float(drive.stamps[0]))
            yield topic, record, t

    bag = write_bag(tmp_path / 'stuck', stuck(drive_messages(drive)))
    rc, err = run_cli(capsys, ['replay', bag, '-o', str(tmp_path / 'm.json'), '-q'])
    assert rc == 0 and 'no segment' in err and 'noise_updates' not in err, err
    assert (f'{len(drive.stamps) - 1} were skipped (bad scan: stamp_order: '
            f'{len(drive.stamps) - 1}, see below)') in err, err
