"""The node's data path without ROS: scan checks, throttled warnings, queue, poses, updates."""

import numpy as np
from polyline_mapper.core.incremental import IncrementalMapper
from polyline_mapper.poses import quaternion_from_yaw, TransformBuffer2D
from polyline_mapper.ros.params import defaults, settings_from
from polyline_mapper.ros.pipeline import ScanPipeline, WarningThrottle
from polyline_mapper.scan import check_scan, ScanError
import pytest


class FakeClock:
    """A settable monotonic clock."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def settings(**changes):
    values = defaults()
    values.update(changes)
    return settings_from(values)


def make_pipeline(clock, buffer=None, **changes):
    node_settings, config = settings(**changes)
    buffer = buffer or TransformBuffer2D()
    lines, infos = [], []
    warnings = WarningThrottle(lines.append, node_settings.warning_period, clock)

    def lookup(frame, stamp, tol):
        return buffer.lookup_planar('map', frame, stamp, tol)
    pipe = ScanPipeline(IncrementalMapper(config), lookup, node_settings, warnings, infos.append,
                        clock)
    return pipe, buffer, lines


def scan_of(drive, i, stamp, frame='laser'):
    spec = drive.spec
    return check_scan(drive.ranges[i].astype(np.float32), spec.angle_min, spec.angle_increment,
                      spec.range_min, spec.range_max, 0, stamp, frame)


def put_pose(buffer, stamp, pose):
    buffer.set_transform('map', 'laser', stamp, (pose[0], pose[1], 0.0),
                         quaternion_from_yaw(pose[2]))


@pytest.mark.parametrize('kwargs, cause', [
    ({'ranges': []}, 'empty_scan'),
    ({'ranges': [np.nan] * 5}, 'no_valid_ranges'),
    ({'ranges': [np.inf, -np.inf, np.nan, 0.01, 50.0]}, 'no_valid_ranges'),
    ({'angle_increment': 0.0}, 'angle_increment'),
    ({'angle_min': np.nan}, 'angle_increment'),
    ({'intensities': 4}, 'intensities'),
    ({'range_min': 5.0, 'range_max': 1.0}, 'range_limits'),
    ({'range_max': np.nan}, 'range_limits'),
])
def test_check_scan_names_the_cause(kwargs, cause):
    args = {'ranges': [1.0, 2.0, np.nan, 3.0, 4.0], 'angle_min': -0.2, 'angle_increment': 0.1,
            'range_min': 0.1, 'range_max': 30.0}
    args.update(kwargs)
    with pytest.raises(ScanError) as err:
        check_scan(**args)
    assert err.value.cause == cause and isinstance(err.value, ValueError)


def test_check_scan_gives_arrays():
    scan = check_scan([1.0, np.nan, 3.0], -0.1, 0.1, 0.1, 30.0, 3, 12.5, 'laser')
    assert np.allclose(scan.angles, [-0.1, 0.0, 0.1]) and scan.ranges.dtype == np.float64
    assert scan.stamp == 12.5 and scan.frame_id == 'laser'
    assert check_scan([2.0], 0.3, 0.0, 0.1, 30.0).angles.tolist() == [0.3]   # one beam


def test_warning_throttle_logs_each_cause_once_per_period_and_counts():
    clock, lines = FakeClock(), []
    w = WarningThrottle(lines.append, 10.0, clock)
    assert w.warn('a', 'first a') and not w.warn('a', 'again a')
    assert w.warn('b', 'first b')            # another cause has its own throttle
    clock.t = 5.0
    assert not w.warn('a', 'still a')
    clock.t = 10.5
    assert w.warn('a', 'later a')
    assert lines == ['first a [a]', 'first b [b]',
                     'later a [a] (2 more since the last warning of this cause)']
    assert w.counts == {'a': 4, 'b': 1}


def test_live_updates_equal_an_offline_replay_of_the_same_scans(office_drive):
    clock = FakeClock()
    pipe, buffer, lines = make_pipeline(clock)
    n = 60
    for i in range(n):
        put_pose(buffer, float(i), office_drive.poses[i])
        pipe.add(scan_of(office_drive, i, float(i)))
        if i % 7 == 0:                       # the worker runs at its own pace
            pipe.step()
    pipe.step()
    offline = IncrementalMapper(pipe.mapper.config)
    spec = office_drive.spec
    for i in range(n):
        offline.update_scan(office_drive.ranges[i].astype(np.float32), spec.angles(),
                            office_drive.poses[i], spec.range_min, spec.range_max)
    assert pipe.used == n and pipe.updates == offline.updates and not lines
    assert np.allclose(pipe.mapper.segments, offline.segments, atol=1e-9)
    assert len(pipe.snapshot().segments) == len(offline.segments) > 5


def test_update_every_n_scans_groups_their_points(office_drive):
    clock = FakeClock()
    pipe, buffer, _ = make_pipeline(clock, update_every_n_scans=3, **{
        'incremental.noise_updates': 1})
    for i in range(10):
        put_pose(buffer, float(i), office_drive.poses[i])
        pipe.add(scan_of(office_drive, i, float(i)))
    pipe.step()
    assert pipe.used == 9 and pipe.mapper.updates == pipe.updates == 3
    assert len(pipe._ready) == 1                          # the tenth waits for two more


def test_a_scan_waits_for_its_transform_then_is_used_or_skipped(office_drive):
    clock = FakeClock()
    pipe, buffer, lines = make_pipeline(clock, transform_timeout=0.5, transform_tolerance=0.01)
    put_pose(buffer, 0.0, office_drive.poses[0])
    pipe.add(scan_of(office_drive, 1, 1.0))                   # its pose is not there yet
    pipe.add(scan_of(office_drive, 0, 0.0))
    pipe.step()
    assert pipe.used == 0 and not lines                      # waiting, and holding the order
    put_pose(buffer, 1.0, office_drive.poses[1])
    pipe.step()
    assert pipe.used == 2
    pipe.add(scan_of(office_drive, 2, 2.0))
    pipe.step()
    clock.t = 0.6                                            # its pose never comes
    pipe.step()
    assert pipe.used == 2 and len(lines) == 1 and '[too_new]' in lines[0]


def test_unknown_frames_wait_then_are_skipped_and_known_frames_go_on(office_drive):
    clock = FakeClock()
    pipe, buffer, lines = make_pipeline(clock, transform_timeout=0.2)
    put_pose(buffer, 0.0, office_drive.poses[0])
    pipe.add(scan_of(office_drive, 0, 0.0, frame='other_laser'))
    pipe.add(scan_of(office_drive, 0, 0.0))
    pipe.step()
    assert pipe.used == 0
    clock.t = 0.3
    pipe.step()
    assert pipe.used == 1 and lines == [lines[0]] and '[unknown_frame]' in lines[0]


def test_a_full_queue_drops_the_oldest_and_warns_once(office_drive):
    clock = FakeClock()
    pipe, buffer, lines = make_pipeline(clock, scan_buffer_size=5)
    for i in range(8):
        put_pose(buffer, float(i), office_drive.poses[i])
        pipe.add(scan_of(office_drive, i, float(i)))
    pipe.step()
    assert pipe.dropped == 3 and pipe.used == 5 and pipe.received == 8
    assert len(lines) == 1 and '[queue_full]' in lines[0]
    assert pipe.stats()['warnings'] == {'queue_full': 3}


def test_reset_forgets_the_map_and_the_queue(office_drive):
    clock = FakeClock()
    pipe, buffer, _ = make_pipeline(clock)
    for i in range(30):
        put_pose(buffer, float(i), office_drive.poses[i])
        pipe.add(scan_of(office_drive, i, float(i)))
    pipe.step()
    assert len(pipe.snapshot().segments) > 0 and pipe.snapshot().header is None
    pipe.add(scan_of(office_drive, 29, 29.0))
    assert pipe.reset() > 0
    pipe.step()
    snap = pipe.snapshot()
    assert len(snap.segments) == 0 and snap.polylines == [] and pipe.used == 30
