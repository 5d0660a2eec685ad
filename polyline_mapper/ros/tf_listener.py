"""
Pose sources for the node: the laser's planar pose in the fixed frame at a scan's stamp.

Each source has ``lookup(target, source, stamp, tolerance) -> PlanarPose`` and raises
``poses.TransformLookupError`` (with its ``cause``) when it cannot give one.

- ``Tf2RosSource``: tf2_ros.Buffer + TransformListener, used when tf2_ros imports (a real ROS
  install). tf2 interpolates; a stamp past the newest transform uses the newest one when it is
  within the tolerance (tf2 itself would refuse to extrapolate).
- ``TfTopicSource``: our TransformBuffer2D fed from /tf and /tf_static (tf2_msgs/TFMessage),
  where tf2_ros is missing (the PyPI-only set-up).
- ``OdomSource``: nav_msgs/Odometry on ``odom`` (child frame in the odometry frame) plus a
  static laser mount from parameters; the scan's frame name is not used.
"""

import math
import threading

from nav_msgs.msg import Odometry
import numpy as np
from rclpy.duration import Duration
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from rclpy.time import Time

from .convert import stamp_seconds, transform_from_msg
from ..poses import (planar_pose, PlanarPose, quaternion_from_yaw, quaternion_matrix,
                     TransformBuffer2D, TransformLookupError)

# The QoS tf2_ros uses for its listener: /tf reliable and volatile, /tf_static transient local
# so a late listener still gets every static transform.
TF_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
ODOM_FRAME_BASE = '_odom_base'
ODOM_FRAME_LASER = '_odom_laser'


class TfTopicSource:
    """TransformBuffer2D fed by /tf and /tf_static subscriptions on ``node``."""

    def __init__(self, node, cache_seconds: float, warn):
        from tf2_msgs.msg import TFMessage
        self.buffer = TransformBuffer2D(cache_seconds)
        self.newest = -math.inf
        self._lock = threading.Lock()
        self._warn = warn
        node.create_subscription(TFMessage, '/tf', self._on_tf, TF_QOS)
        node.create_subscription(TFMessage, '/tf_static', self._on_tf_static, TF_STATIC_QOS)

    def _on_tf(self, msg) -> None:
        self._add(msg, False)

    def _on_tf_static(self, msg) -> None:
        self._add(msg, True)

    def _add(self, msg, static: bool) -> None:
        for ts in msg.transforms:
            parent, child, stamp, t, q = transform_from_msg(ts)
            try:
                with self._lock:
                    if not static and stamp < self.newest - self.buffer.cache_seconds:
                        # The clock jumped back (a bag restarted, a simulation reset): what is
                        # stored is from another time line, as tf2_ros does, forget it.
                        self._warn('time_jump', f'transform stamped {stamp:.3f}, '
                                   f'{self.newest - stamp:.1f} s before the newest: the clock '
                                   'jumped back, dropping the stored dynamic transforms')
                        self.buffer.clear(keep_static=True)
                        self.newest = stamp
                    self.buffer.set_transform(parent, child, stamp, t, q, static)
                    if not static:
                        self.newest = max(self.newest, stamp)
            except ValueError as exc:
                self._warn('bad_transform', f'ignored transform {parent} -> {child}: {exc}')

    def lookup(self, target: str, source: str, stamp: float, tolerance: float) -> PlanarPose:
        """Return the planar pose of ``source`` in ``target`` at ``stamp`` (s)."""
        if not source:
            raise TransformLookupError('unknown_frame', 'the scan has an empty frame_id')
        with self._lock:
            return self.buffer.lookup_planar(target, source, stamp, tolerance)


class Tf2RosSource:
    """tf2_ros.Buffer and TransformListener on ``node`` (a real ROS install)."""

    def __init__(self, node, cache_seconds: float, tf2_ros):
        self.tf2 = tf2_ros
        self.buffer = tf2_ros.Buffer(cache_time=Duration(seconds=cache_seconds), node=node)
        self.listener = tf2_ros.TransformListener(self.buffer, node)

    def lookup(self, target: str, source: str, stamp: float, tolerance: float) -> PlanarPose:
        """Return the planar pose of ``source`` in ``target`` at ``stamp`` (s)."""
        tf2 = self.tf2
        if not source:
            raise TransformLookupError('unknown_frame', 'the scan has an empty frame_id')
        when = Time(nanoseconds=int(round(stamp * 1e9)))
        try:
            ts = self.buffer.lookup_transform(target, source, when)
        except tf2.ExtrapolationException as exc:
            ts = self._latest_within(target, source, stamp, tolerance, exc)
        except tf2.LookupException as exc:
            empty = not self.buffer.all_frames_as_string().strip()
            raise TransformLookupError('no_tf' if empty else 'unknown_frame', str(exc)) from None
        except tf2.ConnectivityException as exc:
            raise TransformLookupError('not_connected', str(exc)) from None
        except tf2.TransformException as exc:
            raise TransformLookupError('tf_error', str(exc)) from None
        return planar_from_transform(ts, f'frame {source!r} in {target!r}')

    def _latest_within(self, target, source, stamp, tolerance, exc):
        """Return the newest transform when the stamp is past it by at most ``tolerance``."""
        try:
            ts = self.buffer.lookup_transform(target, source, Time())
        except self.tf2.TransformException:
            raise TransformLookupError('too_new', str(exc)) from None
        newest = stamp_seconds(ts.header.stamp)
        if stamp >= newest and stamp - newest <= tolerance:
            return ts
        cause = 'too_new' if stamp > newest else 'too_old'
        raise TransformLookupError(cause, str(exc)) from None


class OdomSource:
    """Odometry on ``odom`` composed with a laser mount (x, y, yaw, upside down)."""

    def __init__(self, node, settings, warn):
        self.buffer = TransformBuffer2D(settings.transform_cache)
        self.frame = settings.fixed_frame
        self._lock = threading.Lock()
        self._warn = warn
        if settings.laser_upside_down:       # yaw, then roll 180 deg: q_yaw * (1, 0, 0, 0)
            half = 0.5 * settings.laser_yaw
            q = np.array([math.cos(half), math.sin(half), 0.0, 0.0])
        else:
            q = quaternion_from_yaw(settings.laser_yaw)
        self.buffer.set_transform(ODOM_FRAME_BASE, ODOM_FRAME_LASER, 0.0,
                                  (settings.laser_x, settings.laser_y, 0.0), q, static=True)
        self._have_odom = False
        node.create_subscription(Odometry, 'odom', self._on_odom, qos_profile_sensor_data)

    def _on_odom(self, msg) -> None:
        if msg.header.frame_id.lstrip('/') != self.frame:
            self._warn('odom_frame', f'ignored odometry in frame {msg.header.frame_id!r}: '
                       f'fixed_frame is {self.frame!r} (in odom mode the map is in the '
                       'odometry frame: set fixed_frame to it)')
            return
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        try:
            with self._lock:
                self.buffer.set_transform(self.frame, ODOM_FRAME_BASE,
                                          stamp_seconds(msg.header.stamp), (p.x, p.y, p.z),
                                          (q.x, q.y, q.z, q.w))
                self._have_odom = True
        except ValueError as exc:
            self._warn('bad_odometry', f'ignored odometry: {exc}')

    def lookup(self, target: str, source: str, stamp: float, tolerance: float) -> PlanarPose:
        """Return the laser's planar pose in the odometry frame at ``stamp`` (s)."""
        with self._lock:
            if not self._have_odom:
                raise TransformLookupError('no_tf', 'no odometry received yet on odom')
            return self.buffer.lookup_planar(self.frame, ODOM_FRAME_LASER, stamp, tolerance)


def planar_from_transform(ts, what: str = 'frame') -> PlanarPose:
    """Project a geometry_msgs/TransformStamped to a PlanarPose (flip for upside-down frames)."""
    t, q = ts.transform.translation, ts.transform.rotation
    quat = np.array([q.x, q.y, q.z, q.w])
    norm = np.linalg.norm(quat)
    if not np.isfinite(norm) or norm < 1e-9:
        raise TransformLookupError('tf_error', f'{what}: invalid rotation {quat.tolist()}')
    return planar_pose(quaternion_matrix(quat / norm), np.array([t.x, t.y, t.z]), what=what)


def make_tf_source(node, cache_seconds: float, warn):
    """Return Tf2RosSource when tf2_ros imports, else TfTopicSource (needs tf2_msgs)."""
    try:
        import tf2_ros
    except ImportError:
        try:
            return TfTopicSource(node, cache_seconds, warn)
        except ImportError as exc:
            raise RuntimeError(f'neither tf2_ros nor tf2_msgs is importable ({exc}); install '
                               'tf2_msgs or run tools/dev.sh setup') from None
    return Tf2RosSource(node, cache_seconds, tf2_ros)
