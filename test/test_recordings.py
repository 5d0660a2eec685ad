"""One opener for every input: kinds, one message order, and the poses + mount builder."""

from dataclasses import fields
import math
import os

from bag_helpers import drive_messages as bag_drive_messages
from bag_helpers import room_drive, write_bag, write_carmen
import numpy as np
from polyline_mapper.formats.bag import BagError, BagReader
from polyline_mapper.formats.carmen import read_carmen
from polyline_mapper.formats.carmen_bag import carmen_to_bag
from polyline_mapper.formats.points import read_points as read_point_file
from polyline_mapper.formats.records import Odometry, Scan, Transform
from polyline_mapper.poses import mount_quaternion, TransformBuffer2D
from polyline_mapper.recordings import (kind_of, open_recording, read_points, robot_messages,
                                        SIM_MAP_TO_ODOM, SIM_MOUNT, SIM_START)
from polyline_mapper.scan import scan_to_points
import pytest

TOPICS = ('/tf', '/odom', '/scan')


def assert_same_record(a, b, what=''):
    """Every field equal (arrays bit for bit, NaN where NaN); stamps to the nanosecond."""
    assert type(a) is type(b), what
    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == 'stamp':
            assert x == pytest.approx(y, abs=1e-9), (what, f.name)
        elif isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert np.asarray(x).dtype == np.asarray(y).dtype, (what, f.name)
            assert np.array_equal(x, y, equal_nan=True), (what, f.name)
        else:
            assert x == y, (what, f.name, x, y)


def assert_same_stream(a: list, b: list):
    assert len(a) == len(b)
    for i, (x, y) in enumerate(zip(a, b)):
        assert_same_record(x, y, f'record {i}')


def chain_poses(messages, target='map', source='laser') -> tuple:
    """Feed /tf and /tf_static to a buffer; return the scans and the laser pose of each."""
    buf = TransformBuffer2D(1e6)
    scans, poses = [], []
    for _, topic, record in messages:
        if topic in ('/tf', '/tf_static'):
            for t in record:
                buf.set_transform(t.parent, t.child, t.stamp, t.translation, t.rotation, t.static)
        elif topic == '/scan':
            scans.append(record)
    for s in scans:
        poses.append(buf.lookup_planar(target, source, s.stamp, 0.0))
    return scans, poses


def assert_recorded_order(messages, scans: int):
    """/tf_static first, then /tf, /odom, /scan per scan, at the scan's stamp."""
    topics = [m[1] for m in messages]
    assert topics == ['/tf_static'] + list(TOPICS) * scans
    for k in range(scans):
        group = messages[1 + 3 * k:4 + 3 * k]
        stamp = group[2][2].stamp
        assert [m[0] for m in group] == [stamp] * 3
        assert group[1][2].stamp == stamp and all(t.stamp == stamp for t in group[0][2])


@pytest.fixture(scope='module')
def carmen_log(tmp_path_factory):
    """Write a CARMEN log: laser 4 cm behind the base, drifting odometry, a broken line."""
    folder = tmp_path_factory.mktemp('recordings')
    drive = room_drive(beams=181, fov=180.0, step=0.4, rng=5)
    log = write_carmen(folder / 'run.log.gz', drive, odom_drift=0.01, front_offset=-0.04,
                       garbage_line=2)
    return folder, log, drive


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_a_carmen_log_and_the_bag_convert_makes_of_it_give_the_same_records(
        carmen_log, storage):
    folder, log, drive = carmen_log
    bag = str(folder / f'run-{storage}')
    if not os.path.exists(bag):
        carmen_to_bag(log, bag, storage)
    with open_recording(log) as from_log, open_recording(bag) as from_bag:
        assert (from_log.kind, from_bag.kind) == ('carmen', 'bag')
        n = len(drive.stamps)
        assert from_log.scan_count == from_bag.scan_count == n
        assert from_log.description == f'CARMEN log, {n} scans, 1 malformed record(s) skipped'
        assert len(from_log.warnings) == 1 and 'line 6: FLASER announces' in from_log.warnings[0]
        log_messages = list(from_log.messages())
        assert_recorded_order(log_messages, n)
        # The bag's messages, log times and records are the log's, in the same order.
        bag_messages = list(from_bag.messages())
        assert [m[1] for m in bag_messages] == [m[1] for m in log_messages]
        np.testing.assert_allclose([m[0] for m in bag_messages], [m[0] for m in log_messages],
                                   rtol=0, atol=1e-9)
        records = list(from_log.records())
        assert_same_stream(list(from_bag.records()), records)
        # ... and what replay read before: the bag's own reader, the log's own scans.
        with BagReader(bag, odometry='auto') as reader:
            assert_same_stream(list(reader.records()), records)
        parsed = read_carmen(log)
        stamps, _ = parsed.stamps()
        assert_same_stream([r for r in records if isinstance(r, Scan)],
                           parsed.scans(stamps, frame_id='laser', with_pose=False))
        # Every pass reads the whole recording again (the bag's second pass: a new reader).
        assert_same_stream(list(from_bag.records()), records)
        assert_same_stream(list(from_log.records()), records)
    # The chain map -> odom -> base_link -> laser is the corrected laser pose; /odom is the
    # drifting odometry, base_link in odom.
    scans, poses = chain_poses(log_messages)
    want = np.array([r.pose for r in parsed.records])
    np.testing.assert_allclose([p.xyz for p in poses], want, atol=1e-9)
    odom = [r for r in records if isinstance(r, Odometry)]
    np.testing.assert_allclose([o.translation[:2] for o in odom],
                               [r.odom[:2] for r in parsed.records], atol=1e-12)
    static = [r for r in records if isinstance(r, Transform) and r.static]
    assert len(static) == 1 and np.allclose(static[0].translation, [-0.04, 0.0, 0.0])


def test_the_simulated_drive_is_recorded_through_map_odom_base_laser():
    with open_recording('sim:office', seed=1) as rec:
        drive = rec.drive
        n = len(drive.poses)
        assert rec.kind == 'sim' and rec.scan_count == n
        messages = list(rec.messages())
        assert_recorded_order(messages, n)
        assert_same_stream(list(rec.records()), [
            r for m in rec.messages() for r in (m[2] if isinstance(m[2], list) else [m[2]])])
    scans, poses = chain_poses(messages)
    assert [s.stamp for s in scans] == (SIM_START + drive.stamps).tolist()
    np.testing.assert_allclose([p.xyz[:2] for p in poses], drive.poses[:, :2], atol=1e-9)
    dyaw = np.angle(np.exp(1j * (np.array([p.yaw for p in poses]) - drive.poses[:, 2])))
    assert np.abs(dyaw).max() < 1e-9 and not any(p.flip for p in poses)
    assert all(np.array_equal(s.ranges, r.astype(np.float32), equal_nan=True)
               for s, r in zip(scans, drive.ranges))
    tf = [m[2] for m in messages if m[1] == '/tf']
    assert all([(t.parent, t.child) for t in ts] == [('map', 'odom'), ('odom', 'base_link')]
               for ts in tf)
    assert np.allclose(tf[0][0].translation[:2], SIM_MAP_TO_ODOM[:2])
    static = messages[0][2][0]
    assert (static.parent, static.child) == ('base_link', 'laser')
    assert np.allclose(static.translation[:2], SIM_MOUNT[:2])
    # the odometry is base_link in odom: the same pose as the odom -> base_link transform
    for ts, odom in zip(tf, [m[2] for m in messages if m[1] == '/odom']):
        assert np.array_equal(odom.translation, ts[1].translation)
        assert np.array_equal(odom.rotation, ts[1].rotation)


def test_an_upside_down_laser_lists_its_beams_reversed_and_maps_the_same_points():
    drive = room_drive(beams=181, fov=270.0, step=0.6, rng=2)
    scans = drive.scans()
    mount = (0.15, 0.05, math.pi / 2)
    laser = drive.laser
    upright = list(robot_messages(drive.stamps, laser, scans, mount, map_to_odom=(1, -2, 0.3)))
    flipped = list(robot_messages(drive.stamps, laser, scans, mount, upside_down=True,
                                  map_to_odom=(1, -2, 0.3)))
    assert np.array_equal(flipped[0][2][0].rotation, mount_quaternion(mount[2], True))
    up_scans, up_poses = chain_poses(upright)
    fl_scans, fl_poses = chain_poses(flipped)
    assert len(fl_scans) == len(scans) and not any(p.flip for p in up_poses)
    assert all(p.flip for p in fl_poses)
    for a, b, pa, pb in zip(up_scans, fl_scans, up_poses, fl_poses):
        assert np.array_equal(b.ranges, a.ranges[::-1], equal_nan=True)
        pts_a = scan_to_points(a.ranges, pa.beam_angles(a.angles()), pa.xyz, 0.0, 12.0)
        pts_b = scan_to_points(b.ranges, pb.beam_angles(b.angles()), pb.xyz, 0.0, 12.0)
        np.testing.assert_allclose(pts_b[::-1], pts_a, atol=1e-5)
    # a fan not symmetric about the laser's x axis cannot be flipped by reordering
    skewed = [Scan(s.stamp, s.frame_id, s.angle_min + 0.1, s.angle_increment, s.range_min,
                   s.range_max, s.ranges) for s in scans]
    with pytest.raises(ValueError, match='symmetric'):
        list(robot_messages(drive.stamps, laser, skewed, mount, upside_down=True))


def test_the_builder_refuses_mismatched_inputs():
    drive = room_drive(step=1.0, rng=1)
    scans = drive.scans()
    cases = [((drive.stamps[:-1], drive.laser, scans), {}, 'laser_poses must be'),
             ((drive.stamps, drive.laser, scans + scans[:1]), {}, 'more scans than'),
             ((drive.stamps, drive.laser, drive.scans('lidar')), {}, "not 'laser'"),
             ((drive.stamps, drive.laser, scans), {'odom_poses': drive.base,
                                                   'map_to_odom': (0, 0, 0)}, 'not both')]
    for args, kwargs, needle in cases:
        with pytest.raises(ValueError, match=needle):
            list(robot_messages(*args, **kwargs))


def test_kind_of_names_every_input_and_refuses_the_rest_with_one_line(tmp_path):
    np.save(tmp_path / 'p.npy', np.zeros((3, 2)))
    for name in ('p.csv', 'p.TXT', 'p.xy', 'run.log', 'run.LOG.gz', 'run.clf', 'b.db3',
                 'b.mcap', 'b.bag', 'odd name.carmen.gz'):
        (tmp_path / name).write_text('x')
    (tmp_path / 'folder').mkdir()
    (tmp_path / 'folder' / 'metadata.yaml').write_text('x')
    (tmp_path / 'plain').mkdir()
    (tmp_path / 'killed').mkdir()           # a recording stopped before metadata.yaml
    (tmp_path / 'killed' / 'killed_0.db3').write_text('x')
    (tmp_path / 'p.xyz').write_text('1 2\n')
    os.mkfifo(tmp_path / 'pipe.log')
    os.symlink(tmp_path / 'gone.log', tmp_path / 'dangling.log')
    want = {'p.npy': 'points', 'p.csv': 'points', 'p.TXT': 'points', 'p.xy': 'points',
            'run.log': 'carmen', 'run.LOG.gz': 'carmen', 'run.clf': 'carmen',
            'odd name.carmen.gz': 'carmen', 'b.db3': 'bag', 'b.mcap': 'bag', 'b.bag': 'bag',
            'folder': 'bag'}
    for name, kind in want.items():
        assert kind_of(tmp_path / name) == kind, name
    for name in ('sim:office', 'sim:hall', 'sim:corridors'):
        assert kind_of(name) == 'sim'
    refused = [(tmp_path / 'p.xyz', 'unknown input type'),
               (tmp_path / 'missing.log', 'no such file or folder'),
               (tmp_path / 'dangling.log', 'no such file or folder'),
               (tmp_path / 'plain', 'a folder without metadata.yaml'),
               (tmp_path / 'killed', 'its storage file can be read alone: give '
                f"{tmp_path / 'killed' / 'killed_0.db3'}"),
               (tmp_path / 'pipe.log', 'not a regular file'),
               ('sim:nowhere', 'unknown simulated drive (expected one of sim:office'),
               ('', 'no such file or folder')]
    for path, needle in refused:
        with pytest.raises(ValueError) as err:
            kind_of(path)
        text = str(err.value)
        assert needle in text and '\n' not in text and text.startswith(str(path)), text
    # An unknown type is answered with every accepted kind.
    with pytest.raises(ValueError) as err:
        kind_of(tmp_path / 'p.xyz')
    for accepted in ('.npy', '.csv', '.log.gz', 'rosbag2 folder', '.mcap', '.bag',
                     'sim:office', 'sim:corridors'):
        assert accepted in str(err.value), accepted


def test_open_recording_refuses_what_it_cannot_play_with_one_line(tmp_path, carmen_log):
    _, log, _ = carmen_log
    np.save(tmp_path / 'p.npy', np.zeros((3, 2)))
    (tmp_path / 'empty.mcap').write_bytes(b'')
    cases = [((str(tmp_path / 'p.npy'),), {}, 'a point file holds no scans'),
             ((log,), {'scan_topic': '/scan'}, 'apply to bags, not CARMEN logs'),
             (('sim:hall',), {'odom_topic': '/odom'}, 'apply to bags, not simulated drives'),
             ((log,), {'period': 0.0}, 'period must be a positive number'),
             ((log,), {'period': float('nan')}, 'period must be a positive number'),
             (('sim:hall',), {'noise': -1.0}, 'noise must be'),
             ((str(tmp_path / 'empty.mcap'),), {}, 'empty file'),
             (('sim:hall',), {'odometry': 'yes'}, 'odometry must be')]
    for args, kwargs, needle in cases:
        with pytest.raises(ValueError) as err:
            with open_recording(*args, **kwargs):
                pass
        assert needle in str(err.value) and '\n' not in str(err.value), (args, kwargs)


def test_a_bag_with_two_odometry_topics_opens_unless_odometry_is_required(tmp_path):
    drive = room_drive(step=0.8, rng=4)
    msgs = []
    for topic, record, t in bag_drive_messages(drive):
        msgs.append((topic, record, t))
        if topic == '/odom':
            msgs.append(('/wheel_odom', record, t))
    bag = write_bag(tmp_path / 'two-odom', msgs)
    for odometry in ('auto', None, False):
        with open_recording(bag, odometry=odometry) as rec:
            got = list(rec.records())
        assert not any(isinstance(r, Odometry) for r in got), odometry
        assert sum(isinstance(r, Scan) for r in got) == len(drive.stamps)
    with pytest.raises(BagError, match='2 Odometry topics .* choose one with --odom-topic'):
        with open_recording(bag, odometry=True):
            pass
    with open_recording(bag, odom_topic='/wheel_odom', odometry=True) as rec:
        assert sum(isinstance(r, Odometry) for r in rec.records()) == len(drive.stamps)
        assert '/wheel_odom' in rec.description and not rec.warnings
    # a bag without /tf is opened with a warning saying how its scans can be placed
    notf = write_bag(tmp_path / 'no-tf', bag_drive_messages(drive, tf=False, static=False))
    with open_recording(notf) as rec:
        assert len(rec.warnings) == 1 and 'no /tf or /tf_static topic' in rec.warnings[0]
    for placed in ('odom', 'scan'):             # ... unless the caller places them so already
        with open_recording(notf, pose_source=placed) as rec:
            assert rec.warnings == [], placed


def test_read_points_reads_point_files_and_logs_and_refuses_the_rest(tmp_path, carmen_log):
    _, log, _ = carmen_log
    pts = np.random.default_rng(3).normal(size=(50, 2))
    np.save(tmp_path / 'p.npy', pts)
    got, desc = read_points(tmp_path / 'p.npy')
    assert np.array_equal(got, read_point_file(str(tmp_path / 'p.npy'))) and desc == 'point file'
    warned = []
    got, desc = read_points(log, warn=warned.append)
    assert np.array_equal(got, read_carmen(log).points())
    assert desc.startswith('CARMEN log, ') and '1 malformed record(s) skipped' in desc
    assert len(warned) == 1 and 'line 6: FLASER announces' in warned[0]
    near, _ = read_points(log, range_max=2.0)
    assert 0 < len(near) < len(got)
    assert np.array_equal(near, read_carmen(log).points(range_max=2.0))
    seen = []
    read_points(log, progress=lambda items: (seen.append(1) or item for item in items))
    assert len(seen) == len(read_carmen(log).records)
    bag = str(tmp_path / 'bag')
    carmen_to_bag(log, bag)
    cases = [((bag,), {}, 'a bag holds scans, not points'),
             (('sim:office',), {}, 'a simulated drive holds scans'),
             ((tmp_path / 'p.npy',), {'range_max': 5.0}, 'applies to laser logs only'),
             ((log,), {'range_max': float('nan')}, 'range_max must be a number > 0'),
             ((log,), {'range_max': -1.0}, 'range_max must be a number > 0'),
             ((log,), {'range_max': 'far'}, 'range_max must be a number > 0'),
             ((tmp_path / 'nothing.csv',), {}, 'no such file')]
    for args, kwargs, needle in cases:
        with pytest.raises(ValueError) as err:
            read_points(*args, **kwargs)
        assert needle in str(err.value) and '\n' not in str(err.value), (args, kwargs)
