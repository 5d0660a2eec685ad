"""Odom mode: a scan inside a gap of the odometry (a lost message) is skipped, not mis-posed."""

import math

import numpy as np
from polyline_mapper.core.geometry import sample_segments, wrap_angle
from polyline_mapper.formats.records import Odometry, Scan
from polyline_mapper.poses import quaternion_from_yaw
from polyline_mapper.recordings import drive_messages, make_drive, SIM_START
from polyline_mapper.replay import replay_records
from polyline_mapper.session import MappingSession, SessionOptions
import pytest


def odometry(stamp, pose):
    return Odometry(float(stamp), 'odom', 'base_link', np.array([pose[0], pose[1], 0.0]),
                    quaternion_from_yaw(pose[2]))


def turning(t):
    """Return the pose at time t of a robot driving a circle of 2 m radius at 0.5 m/s."""
    yaw = 0.25 * t
    return np.array([2.0 * math.sin(yaw), 2.0 - 2.0 * math.cos(yaw), yaw])


def a_scan(stamp):
    return Scan(float(stamp), 'laser', -1.0, 0.5, 0.1, 30.0, np.full(5, 3.0, np.float32))


def posed(session, stamps):
    """Pose each scan stamped ``stamps`` (after the odometry is in); return poses and causes."""
    out = []
    for t in stamps:
        try:
            out.append(session.poses.pose(a_scan(t)).xyz)
        except LookupError as exc:
            out.append(exc.cause)
    return out


@pytest.mark.parametrize('factor', [1.5, 0.0])
def test_scans_in_an_odometry_gap_are_refused_and_jitter_is_not_a_gap(factor):
    # Odometry at 20 Hz, its stamps jittering by +-20 % of the period (seeded), message 30
    # lost; scans at 10 Hz, stamped between odometry messages.
    rng = np.random.default_rng(4)
    stamps = np.arange(60) * 0.05 + rng.uniform(-0.01, 0.01, 60)
    session = MappingSession(None, SessionOptions(pose_source='odom', fixed_frame='odom',
                                                  mount=(0.0, 0.0, 0.0),
                                                  odom_gap_factor=factor))
    for k, t in enumerate(stamps):
        if k != 30:
            session.add(odometry(t, turning(t)))
    scans = 0.5 * (stamps[1:-1:2] + stamps[2::2])          # between messages 2j+1 and 2j+2
    got = posed(session, scans)
    in_gap = (stamps[29] < scans) & (scans < stamps[31])
    assert sum(in_gap) == 1
    for pose, gap, t in zip(got, in_gap, scans):
        if gap and factor:
            assert pose == 'odom_gap'
        else:                   # interpolated between neighbours 0.05 s apart (the gap: 0.1 s)
            assert not isinstance(pose, str), pose
            assert np.allclose(pose[:2], turning(t)[:2], atol=0.002 if not gap else 0.01)


def test_a_lost_message_at_a_corner_no_longer_bends_the_map():
    # The drive of test_node_modes (0.4 m a scan, one odometry message per scan, each corner
    # turned from one message to the next), 5 % of the odometry lost at random: the scans
    # whose odometry was lost have no known pose. Interpolated across the gap (tf2's way,
    # odom_gap_factor 0) they turn walls a corner too early; skipped, the map is the true one.
    drive = make_drive('sim:office,step=0.4', 7)
    messages = drive_messages(drive, mount=(0.0, 0.0, 0.0), map_to_odom=(0.0, 0.0, 0.0))
    records = [x for _, _, r in messages for x in (r if isinstance(r, list) else [r])]
    odom = [i for i, r in enumerate(records) if isinstance(r, Odometry)]
    rng = np.random.default_rng(0)
    drop = set(rng.choice(odom[1:-1], size=round(0.05 * (len(odom) - 2)), replace=False))
    kept = [r for i, r in enumerate(records) if i not in drop]
    result = {}
    for factor in (1.5, 0.0):
        session = replay_records(kept, options=SessionOptions(
            pose_source='odom', fixed_frame='odom', mount=(0.0, 0.0, 0.0),
            grid_resolution=None, keep_points=True, odom_gap_factor=factor))
        value = session.map_value()
        traj = np.asarray(value.trajectory)
        k = np.searchsorted(SIM_START + np.asarray(drive.stamps), traj[:, 0] - 1e-6)
        heading = np.abs(wrap_angle(traj[:, 3] - drive.poses[k, 2])).max()
        samples, _ = sample_segments(value.segments, 0.02)
        result[factor] = (len(traj), heading, drive.world.distance(samples).max(),
                          session.stats()['skipped'])
    scans, heading, stray, skipped = result[1.5]
    assert skipped == {'no pose: odom_gap': len(drive.poses) - scans} and scans >= 210
    assert heading < 1e-6 and stray < 0.1, result[1.5]
    scans, heading, stray, skipped = result[0.0]
    assert scans == len(drive.poses) and not skipped
    assert heading > 0.5 and stray > 0.5, result[0.0]          # what the guard prevents


def test_the_node_parameter_reaches_the_session_and_is_checked():
    pytest.importorskip('polyline_mapper_msgs.msg', reason='the messages are not built')
    from polyline_mapper.params import defaults, settings_from
    from polyline_mapper.ros.node import session_options
    odom = defaults() | {'pose_source': 'odom', 'fixed_frame': 'odom'}
    assert session_options(settings_from(odom)[0]).odom_gap_factor == 1.5
    assert session_options(settings_from(odom | {'odom_gap_factor': 0.0})[0]) \
        .odom_gap_factor == 0.0
    for bad in (-1.0, 'wide'):
        with pytest.raises(ValueError, match='odom_gap_factor'):
            settings_from(odom | {'odom_gap_factor': bad})
