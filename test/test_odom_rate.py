"""Odometry much slower than the scans: warned once (``odom_rate``), never at usual rates."""

import dataclasses

import numpy as np
from polyline_mapper.formats.records import Scan, Transform
from polyline_mapper.recordings import (drive_messages, flat_records, make_drive, SIM_START,
                                        thin_odometry)
from polyline_mapper.replay import replay_records
from polyline_mapper.session import SessionOptions
import pytest

DRIVE = 'sim:office,step=0.05,turn=0.1,moving_sensor=1'
"""10 Hz scans, 0.5 m/s, turning in place at 1 rad/s (benchmarks/odom_rate.py)."""


@pytest.fixture(scope='module')
def records():
    """Return the drive's first 200 scans with drifting odometry (seed 1), one message a scan."""
    drive = make_drive(DRIVE, 1)
    end = SIM_START + drive.stamps[200]
    return [r for r in flat_records(drive_messages(drive, mount=(0.0, 0.0, 0.0), odom_drift=1))
            if r.stamp < end]


def _mount_on_tf(stamp: float) -> Transform:
    """Return the laser's mount (base_link -> laser, identity) sent on /tf at ``stamp``."""
    return Transform(stamp, 'base_link', 'laser', np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]),
                     False)


def _warned(records: list, pose_source: str, scan_matching: bool, **options) -> list:
    warned = []
    session = replay_records(records, options=SessionOptions(
        pose_source=pose_source, scan_matching=scan_matching, **options),
        warn=lambda cause, text: warned.append((cause, text)))
    scans = sum(isinstance(r, Scan) for r in records)
    assert session.used >= 0.95 * scans, (session.used, scans)
    return [text for cause, text in warned if cause == 'odom_rate']


@pytest.mark.parametrize('pose_source, scan_matching', [('odom', True), ('tf', False)])
def test_odometry_at_1_hz_under_10_hz_scans_is_warned_once(records, pose_source,
                                                           scan_matching):
    # Interpolated across a second, the odometry spreads each change of the turn rate over
    # it: walls F1 0.84 with matching on the whole drive, against 1.00 at 10 Hz
    # (benchmarks/odom_rate.py). One warning, naming the rate and the edge.
    said = _warned(thin_odometry(records, 10), pose_source, scan_matching)
    assert len(said) == 1, said
    assert 'every 1000 ms (1.0 Hz), 10 x the scans' in said[0]
    edge = 'the odometry' if pose_source == 'odom' else 'the transform odom -> base_link'
    assert said[0].startswith(edge), said[0]


def test_odometry_at_the_scan_rate_or_at_5_hz_is_not_warned_about(records):
    # One message per scan (the simulator, converted CARMEN logs), and 5 Hz, which maps as
    # 10 Hz does (F1 1.00): silent. Scans stamped out of order change nothing.
    assert _warned(records, 'odom', True) == []
    assert _warned(thin_odometry(records, 2), 'tf', False) == []
    scans = [i for i, r in enumerate(records) if isinstance(r, Scan)]
    swapped = list(records)
    for a in scans[20:200:30]:
        swapped[a] = dataclasses.replace(records[a], stamp=records[a].stamp + 0.15)
    assert _warned(swapped, 'odom', False) == []


def test_the_warning_needs_odometry_slower_than_the_scans_not_only_slow(records):
    # Odometry at 2.5 Hz under scans at 2.5 Hz (one of each per 0.4 s): each scan has its
    # own odometry message, nothing to interpolate across: silent.
    scans = [r for r in records if isinstance(r, Scan)]
    keep = {r.stamp for r in scans[::4]}
    sparse = [r for r in records if r.stamp in keep or getattr(r, 'static', False)]
    assert np.isclose(np.median(np.diff(sorted(keep))), 0.4)
    assert _warned(sparse, 'odom', False) == []


def test_lasers_clocks_and_mounts_that_only_look_like_slow_odometry(records):
    # Found by a helper audit of the first version: two lasers at 1 Hz each, 0.1 s apart,
    # over 1 Hz odometry (each laser has its own odometry message: nothing to warn about) were
    # taken as scans every 0.1 s; a mount sent on /tf at 1 Hz (a ROS 1 habit) instead of
    # /tf_static was judged as the odometry edge although it never moves.
    scans = [r for r in records if isinstance(r, Scan)]
    first, second = {id(r) for r in scans[0::10]}, {id(r) for r in scans[1::10]}
    two = []
    for r in thin_odometry(records, 10):
        if isinstance(r, Scan):
            if id(r) in first or id(r) in second:
                two.append(r if id(r) in first else dataclasses.replace(r, frame_id='laser2'))
        else:
            two.append(r)
            if isinstance(r, Transform) and r.static:
                two.append(dataclasses.replace(r, child='laser2'))
    assert _warned(two, 'tf', False) == []
    mount = [r for r in records if not (isinstance(r, Transform) and r.static)]
    mount = [m for r in mount for m in ([r, _mount_on_tf(r.stamp)]
                                        if isinstance(r, Transform) and round(
                                            (r.stamp - SIM_START) * 10) % 10 == 0 else [r])]
    assert _warned(mount, 'tf', False, tolerance=1.0) == []


def test_slow_odometry_above_a_mount_sent_on_tf_is_warned_about(records):
    # Scan matching without a map frame looks the poses up in the odometry frame: the mount
    # on /tf (still) is passed over and the odometry edge above it is judged; with the
    # odometry at 1 Hz as well the warning was missing (noted 2026-12-01). (Without scan
    # matching the poses are looked up in the fixed frame, where a still edge may be a
    # parked robot's under a localizer's map -> odom: only the lowest edge is judged there,
    # the test below.)
    both = []
    for r in thin_odometry(records, 10):
        if isinstance(r, Transform) and r.static:
            continue
        both.append(r)
        if isinstance(r, Transform):
            both.append(_mount_on_tf(r.stamp))
    assert {(r.parent, r.child) for r in both if isinstance(r, Transform)} == {
        ('odom', 'base_link'), ('base_link', 'laser')}
    said = _warned(both, 'tf', True, tolerance=1.0)
    assert len(said) == 1 and said[0].startswith('the transform odom -> base_link'), said
    assert 'every 1000 ms (1.0 Hz)' in said[0]


def test_a_parked_robot_under_a_localizer_is_no_slow_odometry(records):
    # Found by a helper audit of the test above's fix: odom -> base_link at 10 Hz, always the
    # same pose (the robot parked), under a localizer's map -> odom at 1 Hz, the poses looked
    # up in map. The still odometry edge was passed over like a mount and map -> odom judged:
    # "the transform map -> odom comes every 1000 ms".
    first = next(r for r in records if isinstance(r, Transform) and not r.static)
    parked, k = [], 0
    for r in records:
        if not isinstance(r, Transform) or r.static:
            parked.append(r)
            continue
        parked.append(dataclasses.replace(r, translation=first.translation,
                                          rotation=first.rotation))
        if round((r.stamp - SIM_START) * 10) % 10 == 0:
            k += 1
            parked.append(Transform(r.stamp, 'map', first.parent, np.array([0.001 * k, 0, 0]),
                                    np.array([0.0, 0.0, 0.0, 1.0]), False))
    assert _warned(parked, 'tf', False, tolerance=1.0) == []


def test_the_warning_comes_after_the_clock_jumps_back(records):
    # 10 s at 10 Hz odometry, then the clock 100 s back (a bag played again, a restarted
    # driver) and 1 Hz odometry: warned (the first version kept the old stamps and waited
    # for the new ones to pass them).
    end = SIM_START + 10.0
    before = [r for r in records if r.stamp < end]
    after = [dataclasses.replace(r, stamp=r.stamp - 100.0) for r in thin_odometry(records, 10)
             if r.stamp >= end]
    assert len(_warned(before + after, 'tf', False)) == 1
