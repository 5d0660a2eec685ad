"""Pose sources of the node without DDS: /tf topics, odometry + mount, and the tf2_ros adapter."""

import math
import types

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
import numpy as np
from polyline_mapper.poses import quaternion_from_yaw, se2_compose, TransformLookupError
from polyline_mapper.ros.convert import time_msg
from polyline_mapper.ros.params import defaults, settings_from
from polyline_mapper.ros.tf_listener import OdomSource, Tf2RosSource, TfTopicSource
import pytest


class StubNode:
    """Records subscriptions; their callbacks are called by the test."""

    def __init__(self):
        self.callbacks = {}

    def create_subscription(self, msg_type, topic, callback, qos):
        self.callbacks[topic] = callback


def transform(parent, child, stamp, x, y, yaw, quat=None):
    ts = TransformStamped()
    ts.header.frame_id, ts.child_frame_id = parent, child
    ts.header.stamp = time_msg(stamp)
    ts.transform.translation.x, ts.transform.translation.y = x, y
    q = ts.transform.rotation
    q.x, q.y, q.z, q.w = (float(v) for v in (quaternion_from_yaw(yaw) if quat is None else quat))
    return ts


def test_tf_topics_feed_the_buffer_and_bad_transforms_are_warned():
    tf2_msgs = pytest.importorskip('tf2_msgs.msg')
    node, warned = StubNode(), []
    src = TfTopicSource(node, 2.0, lambda cause, text: warned.append(cause))
    node.callbacks['/tf_static'](tf2_msgs.TFMessage(transforms=[
        transform('base_link', 'laser', 0.0, 0.2, 0.0, 0.0)]))
    node.callbacks['/tf'](tf2_msgs.TFMessage(transforms=[
        transform('odom', 'base_link', 5.0, 1.0, 0.0, math.pi / 2),
        transform('odom', 'base_link', 6.0, 2.0, 0.0, math.pi / 2),
        transform('odom', 'x', 6.0, 0.0, 0.0, 0.0, quat=(0.0, 0.0, 0.0, 0.0))]))
    assert warned == ['bad_transform']
    pose = src.lookup('odom', 'laser', 5.5, 0.1)
    assert np.allclose(pose.xyz, [1.5, 0.2, math.pi / 2]) and not pose.flip
    with pytest.raises(TransformLookupError) as err:
        src.lookup('odom', '', 5.5, 0.1)
    assert err.value.cause == 'unknown_frame'
    # The clock jumps back (a bag loops): the old time line is dropped, the mount kept.
    node.callbacks['/tf'](tf2_msgs.TFMessage(transforms=[
        transform('odom', 'base_link', 1.0, 7.0, 0.0, 0.0)]))
    assert warned == ['bad_transform', 'time_jump']
    assert np.allclose(src.lookup('odom', 'laser', 1.0, 0.1).xyz, [7.2, 0.0, 0.0])
    with pytest.raises(TransformLookupError):
        src.lookup('odom', 'laser', 5.5, 0.1)


def test_odometry_with_a_mount_gives_the_laser_pose_and_checks_the_frame():
    values = defaults()
    values.update({'pose_source': 'odom', 'fixed_frame': 'odom', 'laser_x': 0.3,
                   'laser_y': -0.1, 'laser_yaw': 0.5, 'laser_upside_down': True})
    node_settings, _ = settings_from(values)
    node, warned = StubNode(), []
    src = OdomSource(node, node_settings, lambda cause, text: warned.append(cause))
    with pytest.raises(TransformLookupError) as err:
        src.lookup('odom', 'laser', 1.0, 0.1)
    assert err.value.cause == 'no_tf'
    for stamp, x in ((1.0, 2.0), (2.0, 3.0)):
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = 'odom', 'base_link'
        msg.header.stamp = time_msg(stamp)
        msg.pose.pose.position.x = x
        q = msg.pose.pose.orientation
        q.x, q.y, q.z, q.w = (float(v) for v in quaternion_from_yaw(1.0))
        node.callbacks['odom'](msg)
    wrong = Odometry()
    wrong.header.frame_id = 'map'
    node.callbacks['odom'](wrong)
    assert warned == ['odom_frame']
    pose = src.lookup('odom', 'whatever_frame', 1.5, 0.1)
    want = se2_compose((2.5, 0.0, 1.0), (0.3, -0.1, 0.5))
    assert np.allclose(pose.xyz, want) and pose.flip


class FakeTf2:
    """The parts of tf2_ros the adapter uses, over a dict of (target, source) -> transforms."""

    class TransformException(Exception):
        pass

    class LookupException(TransformException):
        pass

    class ConnectivityException(TransformException):
        pass

    class ExtrapolationException(TransformException):
        pass

    def __init__(self, stamps):
        fake = self
        self.stamps = stamps            # stamps (s) of the odom -> laser transforms held

        class Buffer:
            def __init__(self, cache_time=None, node=None):
                pass

            def all_frames_as_string(self):
                return 'Frame laser exists with parent odom.\n' if fake.stamps else ''

            def lookup_transform(self, target, source, when):
                if not fake.stamps:
                    raise fake.LookupException('"odom" passed to lookupTransform does not exist')
                if source != 'laser':
                    raise fake.LookupException(f'"{source}" does not exist')
                if target != 'odom':
                    raise fake.ConnectivityException('not connected')
                t = when.nanoseconds * 1e-9
                if t == 0:
                    t = max(fake.stamps)
                elif not min(fake.stamps) <= t <= max(fake.stamps):
                    raise fake.ExtrapolationException('extrapolation')
                return transform('odom', 'laser', t, t, 0.0, 0.25)

        self.Buffer = Buffer
        self.TransformListener = lambda buffer, node: None


@pytest.mark.parametrize('stamp, tolerance, want', [
    (1.5, 0.1, 1.5),                     # interpolated by tf2
    (2.05, 0.1, 2.0),                    # past the newest within the tolerance: the newest
    (2.5, 0.1, 'too_new'),
    (0.5, 0.1, 'too_old'),
])
def test_tf2_ros_adapter_applies_the_tolerance(stamp, tolerance, want):
    src = Tf2RosSource(None, 10.0, FakeTf2([1.0, 2.0]))
    if isinstance(want, str):
        with pytest.raises(TransformLookupError) as err:
            src.lookup('odom', 'laser', stamp, tolerance)
        assert err.value.cause == want
    else:
        pose = src.lookup('odom', 'laser', stamp, tolerance)
        assert pose.x == pytest.approx(want) and pose.yaw == pytest.approx(0.25)


@pytest.mark.parametrize('stamps, target, source, cause', [
    ([], 'odom', 'laser', 'no_tf'),
    ([1.0], 'odom', 'other', 'unknown_frame'),
    ([1.0], 'map', 'laser', 'not_connected'),
    ([1.0], 'odom', '', 'unknown_frame'),
])
def test_tf2_ros_adapter_names_the_cause(stamps, target, source, cause):
    src = Tf2RosSource(None, 10.0, FakeTf2(stamps))
    with pytest.raises(TransformLookupError) as err:
        src.lookup(target, source, 1.0, 0.1)
    assert err.value.cause == cause


def test_make_tf_source_prefers_tf2_ros(monkeypatch):
    import sys
    from polyline_mapper.ros import tf_listener
    fake = types.ModuleType('tf2_ros')
    fake.__dict__.update({k: getattr(FakeTf2([1.0]), k) for k in (
        'Buffer', 'TransformListener', 'TransformException', 'LookupException',
        'ConnectivityException', 'ExtrapolationException')})
    monkeypatch.setitem(sys.modules, 'tf2_ros', fake)
    assert isinstance(tf_listener.make_tf_source(StubNode(), 10.0, None), Tf2RosSource)
