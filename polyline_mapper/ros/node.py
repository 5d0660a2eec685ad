"""
polyline_mapper_node: LaserScan in, PolylineMap and MarkerArray out, poses from TF or odometry.

Topics (relative names, remappable):

- ``scan`` (sensor_msgs/LaserScan, sensor-data QoS: best effort, depth 5) in. The standard
  QoS overrides apply: ``qos_overrides./scan.subscription.reliability`` (``reliable`` for
  lossless playback from a reliable publisher such as ``polyline-mapper play``), ``.depth`` and
  ``.history``, with the resolved topic name after remapping;
- ``/tf``, ``/tf_static`` (pose_source tf) or ``odom`` (nav_msgs/Odometry, pose_source odom,
  sensor-data QoS with the same overrides as ``scan``) in; a scan stamped in the gap a lost
  odometry message or odom -> base_link transform leaves is skipped (``odom_gap_factor``);
- ``polyline_map`` (polyline_mapper_msgs/PolylineMap) and ``polyline_map/markers``
  (visualization_msgs/MarkerArray) out, reliable + transient local, depth 1: a subscriber that
  starts late gets the current map at once.
- ``map`` (nav_msgs/OccupancyGrid) out, reliable + transient local, depth 1: the planner map
  (``core.grid``) at ``grid_resolution``, occupied cells from the polylines, free cells from
  the traced beams, unknown elsewhere; at most every ``grid_publish_period`` s (0: never).
- ``scan_matching`` on, the node is also a localizer (as AMCL or slam_toolbox): per mapped
  scan it broadcasts ``fixed_frame`` -> odometry frame (map -> odom; the odometry's frame_id,
  or in tf mode the root of the scan frame's tree) on ``/tf``, stamped with the scan's stamp
  plus ``map_odom_post_date``, and publishes the base pose with its covariance on ``pose``
  (geometry_msgs/PoseWithCovarianceStamped, reliable + transient local, depth 1). Poses are
  then predicted in the odometry frame; transforms from ``fixed_frame`` (its own map -> odom,
  read back from /tf) are never used as a pose source. In tf mode, a ``fixed_frame`` transform
  on /tf that the node did not send (another localizer) is warned about (``two_localizers``).
  It takes a pose estimate on ``initialpose`` (geometry_msgs/PoseWithCovarianceStamped in
  ``fixed_frame``, reliable, depth 10; RViz's "2D Pose Estimate", as AMCL does), queued to the
  session as a ``PoseEstimate`` record: the next scans are searched for within 3 standard
  deviations of it (``session.POSE_ESTIMATE_SIGMAS``, as ``MappingSession.set_pose``).

``/diagnostics`` (diagnostic_msgs/DiagnosticArray) every ``diagnostics_period``: scans received,
used and dropped, map size, sigma, update time and latency percentiles (ms) over the run, the
publishers matched on each input (``publishers_scan``, ``publishers_odom``, ``publishers_tf``,
``publishers_tf_static``: the middleware's matched event, so a publisher whose QoS cannot match
is not counted); WARN when scan matching
is lost (``mapping_status``), when scans came in since the last report but none could be used,
or some were dropped, when the scans stopped, and while localizing on a saved map from a wrong
start (until a pose estimate or a reset). Each change in an input's matched publishers is logged.

Services: ``~/reset`` and ``~/save_map`` (std_srvs/Trigger). Parameters: see ``params``.

The node only converts: messages to records (``convert``), fed to one
``session.MappingSession`` on wall time, and the session's map value back to messages. The
subscription callbacks only queue records; a worker thread runs one update at a time and
publishes between updates at most every ``map_publish_period`` s, so a slow update never
starves the map or /diagnostics, and when updates fall behind the oldest queued scans are shed.
Services answer while an update runs (they wait at most for the one in progress).
"""

from collections import deque
import math
import os
import signal
import sys
import threading
import time
import warnings

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid, Odometry
import numpy as np
from polyline_mapper_msgs.msg import PolylineMap
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy.event_handler import (EventHandler, QoSSubscriptionEventType,
                                 SubscriptionEventCallbacks, UnsupportedEventTypeError)
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.qos import qos_policy_name_from_kind
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import LaserScan
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from . import startup
from .messages import (diagnostics_msg, grid_to_msg, map_to_markers, map_to_msg,
                       odometry_from_msg, planar_transform_msg, pose_estimate_from_msg,
                       pose_msg, publisher_nodes, scan_from_msg, time_msg,
                       transforms_from_msg)
from .qos import check_input_qos, MAP_QOS, sensor_data, TF_QOS, TF_STATIC_QOS
from ..core.mapvalue import MapValue
from ..formats.mapjson import config_dict, write_map
from ..params import all_params, NODE_NAME, settings_from, unknown_params
from ..session import MappingSession, SessionOptions, WarningThrottle

GROUP_IDLE = 1.0
"""Seconds without a new scan after which a partial update group is mapped."""
SCAN_ARRIVALS = 20
"""Scans whose arrival times give their usual interval (``_scans_silent``)."""
SCAN_SILENCE, SCAN_SILENCE_MIN = 5.0, 1.0
"""The scans stopped: none for this many usual intervals, and at least this many seconds."""
STANDING_WARNINGS = {
    'two_localizers': 'another node broadcasts map -> odom as this one does (two localizers)',
    'map_topic_shared': 'another node publishes on the planner map topic (its grid withdrawn)',
}
"""Conflicts with other nodes that keep /diagnostics at WARN while they last (an integration
audit: two localizers fought over map -> odom while the status said OK 'mapping')."""
STANDING_SECONDS = 5.0
"""A standing conflict lasts this long after its last occurrence (map_topic_shared, checked
once a grid period: two of them, if longer)."""


class ConfigError(Exception):
    """A parameter value the node cannot start with (reported as one line, exit code 1)."""


def descriptor(spec) -> ParameterDescriptor:
    """Build the ParameterDescriptor of a ParamSpec: description, range, choices, read-only."""
    d = ParameterDescriptor(name=spec.name, description=spec.description,
                            read_only=not spec.runtime)
    if spec.lo is not None and isinstance(spec.default, float):
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.lo),
                                                     to_value=float(spec.hi), step=0.0)]
    elif spec.lo is not None and isinstance(spec.default, int):
        d.integer_range = [IntegerRange(from_value=int(spec.lo), to_value=int(spec.hi), step=1)]
    if spec.choices:
        d.additional_constraints = 'one of: ' + ', '.join(spec.choices)
    return d


class _MatchedEvents(SubscriptionEventCallbacks):
    """
    rclpy's default QoS event callbacks plus ``matched``, where the middleware has that event.

    rclpy creates the other events' handlers only where the middleware supports them, but a
    ``matched`` callback on one without it raises; here the count is then left unknown.
    """

    def __init__(self, matched, supported, incompatible=None):
        super().__init__(incompatible_qos=incompatible)
        self._on_matched = matched
        self._supported = supported     # called once the event's handler is made

    def create_event_handlers(self, callback_group, subscription, topic_name: str) -> list:
        handlers = super().create_event_handlers(callback_group, subscription, topic_name)
        try:
            handlers.append(EventHandler(
                callback_group=callback_group, callback=self._on_matched,
                event_type=QoSSubscriptionEventType.RCL_SUBSCRIPTION_MATCHED,
                parent_impl=subscription))
        except UnsupportedEventTypeError:
            return handlers
        self._supported()
        return handlers


class PolylineMapperNode(Node):
    """Map laser scans into polylines online; publish the map, save it on request."""

    def __init__(self, **kwargs):
        try:
            # rclpy declares use_sim_time itself: a value of the wrong type (use_sim_time:=1,
            # :=maybe) raised from here, with a traceback.
            super().__init__(NODE_NAME, **kwargs)
        except ParameterException as exc:
            raise ConfigError(' '.join(str(exc).split())) from None
        self._specs = all_params()
        try:
            for spec in self._specs:
                self.declare_parameter(spec.name, spec.default, descriptor(spec))
            self.settings, self.config = settings_from(self._values())
        except (ParameterException, ValueError, TypeError) as exc:
            text = ' '.join(str(exc).split())
            if "type 'INTEGER" in text and "expecting type 'DOUBLE" in text:
                text += ' (ROS 2 reads a number without a point as an integer: write 0.0, not 0)'
            raise ConfigError(text) from None
        log = self.get_logger()
        self.warnings = WarningThrottle(log.warning, self.settings.warning_period)
        self.save_failed = False
        """Whether the last ``_save_map`` could not write the file (the exit code at shutdown)."""
        self.session = MappingSession(self.config, session_options(self.settings),
                                      clock=time.monotonic, warn=self.warnings.warn,
                                      info=log.info)
        path = self.settings.input_path
        try:
            saved = startup.read_start_map(path)
            if saved is not None and not self.settings.mapping and not len(saved.value):
                raise startup.StartupError(f'map_input_path {path}: the saved map holds no '
                                           'segment: nothing to localize on (mapping false '
                                           'would keep it empty)')
            if saved is not None:
                self.session.load_map(saved.value, self.settings.initial_pose, saved.grid)
        except startup.StartupError as exc:
            raise ConfigError(str(exc)) from None
        except ValueError as exc:
            raise ConfigError(f'map_input_path {path}: {exc}') from None
        if saved is not None:
            log.info(f'starting from the saved map {path} ({len(saved.value)} segments) at '
                     f'{list(self.settings.initial_pose)}; '
                     + ('mapping into it' if self.settings.mapping else 'localization only'))
            if os.path.realpath(self.settings.output_path) == os.path.realpath(path):
                log.warning(f'map_output_path is the saved map the node starts from ({path}): '
                            '~/save_map and save_map_on_shutdown will not write over it; give '
                            'another map_output_path to save the map')
        self.map_pub = self.create_publisher(PolylineMap, 'polyline_map', MAP_QOS)
        self.marker_pub = self.create_publisher(MarkerArray, 'polyline_map/markers', MAP_QOS)
        self.grid_pub = self.create_publisher(OccupancyGrid, 'map', MAP_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.publishers_matched = {}        # input ('scan', 'tf', ...) -> publishers matched
        self.incompatible = {}              # input -> the QoS policy of the last refused match
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_service(Trigger, '~/save_map', self._on_save_map)
        if self.settings.pose_source == 'tf' or self.settings.scan_matching:
            try:
                from tf2_msgs.msg import TFMessage
            except ImportError as exc:
                raise ConfigError(f'tf2_msgs is not importable ({exc}); install it or run '
                                  'tools/dev.sh setup') from None
            self._tf_message = TFMessage
        self._localized = None              # the Localization last published
        self._root_waiting = None           # scan mode: its transform held back (the mount)
        self._sent = deque(maxlen=256)      # (sec, nanosec) of the map -> odom it broadcast
        self._scan_child = None             # scan mode: the frame it broadcasts under the map
        if self.settings.scan_matching:
            self.tf_pub = self.create_publisher(TFMessage, '/tf', TF_QOS)
            self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, 'pose', MAP_QOS)
            self.create_subscription(PoseWithCovarianceStamped, 'initialpose',
                                     self._on_initial_pose, 10)
        if self.settings.pose_source in ('tf', 'scan'):
            # scan mode places the scans by themselves: /tf_static says where the laser hangs
            # and /tf whether another node already gives the root of its tree a parent
            # (``MappingSession.scan_root``: what it broadcasts under fixed_frame)
            for topic, callback, qos in (('/tf', self._on_tf, TF_QOS),
                                         ('/tf_static', self._on_tf_static, TF_STATIC_QOS)):
                self.create_subscription(TFMessage, topic, callback, qos,
                                         event_callbacks=self._matched_events(topic))
        elif self.settings.pose_source == 'odom':
            self.odometry_received = 0      # counted for the summary (a lossy odometry input)
            self._sensor_input(Odometry, 'odom', self._on_odom)
        self._sensor_input(LaserScan, 'scan', self._on_scan)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._publish_lock = threading.Lock()
        self._dirty = True                  # publish the (empty) map at once for late joiners
        # The planner map only once there is one (a loaded map's at once): a 1 x 1 placeholder
        # on the transient-local 'map' reached every late subscriber, Nav2's static layer
        # among them (map_server and slam_toolbox publish nothing before they have a map).
        self._grid_dirty = self.session.loaded is not None
        self._last_grid = -math.inf
        self._published = (-1, -1, None)    # (scans used, generation, segments) last published
        self._markers_shown = False
        self._last_publish = -math.inf
        self._last_stats = time.monotonic()
        self._stats_mark = (0, 0, 0)
        self._last_diag = -math.inf
        self._diag_mark = (0, 0, 0)
        self._scan_arrivals = deque(maxlen=SCAN_ARRIVALS)   # monotonic s of the last scans
        self._first_scan_at = None                          # monotonic s of the first
        self._silence_said = False                          # this stop of the scans logged
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._work, name='polyline_mapper_updates',
                                        daemon=True)
        self._worker.start()
        s = self.settings
        unknown = unknown_params(self._parameter_overrides) + self._unknown_qos_overrides()
        if unknown:
            log.warning(f'parameters this node does not have, not used: {", ".join(unknown)}')
        log.info(f'mapping scans on {self.resolve_topic_name("scan")} into {s.fixed_frame!r}, '
                 f'poses from {s.pose_source}, update every {s.update_every_n_scans} scan(s)'
                 + (f'; scan matching: pose on {self.resolve_topic_name("pose")}'
                    + f', broadcasting {s.fixed_frame} -> '
                    + ("the root of the laser frame's tree" if s.pose_source == 'scan'
                       else 'odometry frame')
                    if s.scan_matching else ''))

    # -- parameters ----------------------------------------------------------------------------
    def _unknown_qos_overrides(self) -> list:
        """
        Return the ``qos_overrides.*`` values given that no input declared, each with a hint.

        rclpy declares an input's overrides (``qos_overrides.<resolved topic>.subscription.
        reliability``, ``depth``, ``history``) when it subscribes; any other such name was
        taken without a word: a misspelt policy (``reliabilty``) or a topic the node does
        not have (``/scan`` under ``__ns:=/robot1``, whose input is ``/robot1/scan``), and
        the scans stayed best effort (an integration audit).
        """
        import difflib
        have = sorted(n for n in self._parameters if n.startswith('qos_overrides.'))
        topics = sorted({n.split('.')[1] for n in have})
        out = []
        for name in sorted(n for n in self._parameter_overrides
                           if n.startswith('qos_overrides.') and not self.has_parameter(n)):
            topic = name.split('.')[1] if name.count('.') >= 2 else ''
            near = difflib.get_close_matches(
                name, [n for n in have if n.split('.')[1] == topic], n=1)
            out.append(f'{name} (did you mean {near[0]}?)' if near else
                       f'{name} (this node takes QoS overrides on: {", ".join(topics)})')
        return out

    def _values(self, changes=()) -> dict:
        values = {spec.name: self.get_parameter(spec.name).value for spec in self._specs}
        values.update({p.name: p.value for p in changes if p.name in values})   # ours only
        return values

    def _check_parameters(self, params) -> SetParametersResult:
        try:
            settings_from(self._values(params))
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params) -> None:
        old = self.settings
        self.settings, _ = settings_from(self._values())
        opts = self.session.options
        opts.tolerance = self.settings.transform_tolerance
        opts.wait = self.settings.transform_timeout
        opts.update_every_n_scans = self.settings.update_every_n_scans
        opts.max_latency = self.settings.max_scan_latency or None
        self.warnings.period = self.settings.warning_period
        style = ('publish_markers', 'marker_color', 'marker_width')
        if any(getattr(old, k) != getattr(self.settings, k) for k in style):
            self._dirty = True              # republish the markers in their new style

    def _sensor_input(self, msg_type, topic: str, callback) -> None:
        """
        Subscribe to ``topic`` with sensor-data QoS and the standard overrides.

        The overrides (reliability, depth, history) are read-only parameters
        ``qos_overrides.<resolved topic>.subscription.*``; a bad one (an unknown policy value, a
        depth below 1, a value of the wrong type) raises ConfigError naming it.
        """
        options = QoSOverridingOptions.with_default_policies(callback=check_input_qos)
        events = self._matched_events(topic)
        try:
            with warnings.catch_warnings():     # rclpy's own about a depth of 0: refused below
                warnings.simplefilter('ignore', UserWarning)
                self.create_subscription(msg_type, topic, callback, sensor_data(),
                                         qos_overriding_options=options, event_callbacks=events)
        except (RuntimeError, ParameterException, InvalidQosOverridesError) as exc:
            name = f'qos_overrides.{self.resolve_topic_name(topic)}.subscription'
            raise ConfigError(f"{name}: {' '.join(str(exc).split())}") from None

    # -- callbacks -----------------------------------------------------------------------------
    def _matched_events(self, topic: str) -> SubscriptionEventCallbacks:
        """Return the event callbacks of an input: rclpy's defaults plus ``_on_matched``."""
        key = topic.lstrip('/')         # 'scan', 'odom', 'tf', 'tf_static'
        return _MatchedEvents(lambda info: self._on_matched(key, topic, info),
                              lambda: self.publishers_matched.setdefault(key, 0),
                              lambda info: self._on_incompatible(key, topic, info))

    def _on_incompatible(self, key: str, topic: str, info) -> None:
        """
        Warn of a publisher on an input whose QoS cannot match, naming the topic and policy.

        rclpy's own log line named the topic as given ('scan', not '/front/scan' after a
        remap) and /diagnostics stayed OK 'waiting for scans' (an integration audit); the
        scan input's status is now WARN while no publisher matches (``mapping_status``).
        """
        policy = qos_policy_name_from_kind(info.last_policy_kind)
        self.incompatible[key] = policy
        name = self.resolve_topic_name(topic)
        if key in ('scan', 'odom') and policy == 'RELIABILITY':
            advice = ('a best-effort publisher needs a best-effort subscription, the default: '
                      f'remove qos_overrides.{name}.subscription.reliability')
        elif key in ('tf', 'tf_static'):
            advice = ("a TF broadcaster must offer tf2's QoS (reliable; /tf_static also "
                      'transient local)')
        else:
            advice = f'the publisher must offer a {policy} policy this subscription accepts'
        # one cause per input, so one input's warning does not hide another's (an audit)
        self.warnings.warn(f'incompatible_qos_{key}', (
            f'a publisher on {name} offers a QoS this node cannot match ({policy}): none of '
            f'its messages arrive; {advice}'))

    def _on_matched(self, key: str, topic: str, info) -> None:
        """Count (as ``key``) and log the publishers an input's subscription has matched."""
        count = int(info.current_count)
        if self.publishers_matched.get(key) != count:
            self.get_logger().info(f'{self.resolve_topic_name(topic)}: {count} publisher'
                                   f'{"" if count == 1 else "s"} matched')
        self.publishers_matched[key] = count

    def _on_scan(self, msg: LaserScan) -> None:
        self._scan_arrivals.append(time.monotonic())
        if self._first_scan_at is None:
            self._first_scan_at = self._scan_arrivals[-1]
        self.session.add(scan_from_msg(msg))      # (checked there, as replay checks it)

    def _on_tf(self, msg) -> None:
        if self.settings.scan_matching or self.settings.pose_source == 'scan':
            self._check_localizers(msg)
        self.session.add_many(transforms_from_msg(msg, False))

    def _check_localizers(self, msg) -> None:
        """
        Warn (throttled) when another node broadcasts fixed_frame -> X as this one does.

        X: the odometry frame this node broadcasts to (once it is known), in scan mode the root
        of the laser's tree it broadcasts (two scan-mode nodes on one unprefixed base_link went
        unwarned, the robot jumping between their poses: a multi-robot audit); another robot's
        fixed_frame -> its own frame, on a shared map frame, is not a fight.
        """
        frame = self.settings.fixed_frame
        odom = self.session.poses.odom_frame or self._scan_child
        for t in msg.transforms:
            if (t.header.frame_id.lstrip('/') == frame and odom is not None
                    and t.child_frame_id.lstrip('/') == odom
                    and (t.header.stamp.sec, t.header.stamp.nanosec) not in self._sent):
                if self.session.poses.odom_frame is None:     # scan mode
                    how, advice = ('with pose_source scan', 'give each robot its own frames '
                                   '(a frame prefix: robot1/base_link)')
                else:
                    forced = (' (scan_matching is on because map_input_path is given)'
                              if self.settings.input_path else '')
                    how, advice = (f'with scan matching{forced}', 'run this node without '
                                   'scan_matching and map_input_path to map with its poses')
                self.warnings.warn('two_localizers', f'another node broadcasts {frame} -> '
                                   f'{t.child_frame_id.lstrip("/")} on /tf, as this node does '
                                   f'{how}: two localizers fight over the robot pose. Stop '
                                   f'the other, or {advice}')
                return

    def _on_tf_static(self, msg) -> None:
        self.session.add_many(transforms_from_msg(msg, True))

    def _on_initial_pose(self, msg) -> None:
        """Queue a pose estimate (RViz's "2D Pose Estimate"): the session searches near it."""
        self.session.add(pose_estimate_from_msg(msg))

    def _on_odom(self, msg) -> None:
        self.odometry_received += 1
        self.session.add(odometry_from_msg(msg))

    def _on_reset(self, request, response):
        dropped = self.session.reset()     # as /polyline_map and ~/save_map count them
        self._publish()
        if self.settings.grid_publish_period > 0:
            self._publish_grid(cleared=True)
        response.success = True
        response.message = f'map cleared ({dropped} segments dropped)'
        if self.session.loaded is not None:     # reset goes back to the saved map
            where = ('the robot kept where it was matched' if self.session.pose_kept
                     else 'the robot back at initial_pose')
            response.message = (f'map reset to the saved map {self.settings.input_path} '
                                f'({len(self.session.loaded.segments)} segments; the map '
                                f'before the reset had {dropped}; {where})')
        self.get_logger().info(response.message)
        return response

    def _on_save_map(self, request, response):
        response.success, response.message = self._save_map()
        return response

    def _save_map(self) -> tuple:
        """
        Write the map JSON to ``map_output_path``; log and return (success, message).

        Before any scan was mapped since the start or the last ``~/reset`` (and without a
        loaded map) nothing is written: a node restarted while the laser is down, stopped
        before its first scan, or reset and then stopped, would otherwise replace the last
        run's map there (the default path is shared) with an empty one.
        """
        path = self.settings.output_path
        if self.session.used_since_reset == 0 and self.session.loaded is None:
            since = 'since ~/reset' if self.session.used else 'yet'
            message = f'not writing {path}: no scan has been mapped {since} (a file there is kept)'
            self.get_logger().warning(message)
            return False, message
        value = self.session.map_value(trajectory=True)
        try:
            # Never over the saved map the node started from (or a link to it): with mapping
            # on from a wrong start that file would be the only copy, replaced by a bad map.
            write_map(path, value, config_dict(self.config),
                      inputs=(self.settings.input_path,) if self.settings.input_path else (),
                      grid=self.session.occupancy(value.segments))
        except (OSError, ValueError) as exc:       # ValueError: formats.output refused it
            reason = getattr(exc, 'strerror', None) or exc
            message = f'cannot write {path}: {reason}'
            self.get_logger().error(message)
            self.save_failed = True
            return False, message
        message = (f'wrote {path}: {len(value.segments)} segments in {len(value.polylines)} '
                   'polylines')
        self.get_logger().info(message)
        return True, message

    # -- worker --------------------------------------------------------------------------------
    def _work(self) -> None:
        session = self.session
        busy = False
        while not self._stop.is_set():
            if not busy:
                session.wait(0.05)
            try:
                busy = session.step(max_updates=1) > 0
                if self.settings.scan_matching:
                    self._publish_localization()
                if busy:
                    self._dirty = self._grid_dirty = True
                elif session.has_partial_group() and session.idle_seconds() >= GROUP_IDLE:
                    if session.flush(final=False):      # the scans paused: map the group
                        self._dirty = self._grid_dirty = True
                now = time.monotonic()
                if self._dirty and now - self._last_publish >= self.settings.map_publish_period:
                    self._publish()
                period = self.settings.grid_publish_period
                if (period > 0 and now - self._last_grid >= period
                        and (self._grid_dirty or self.grid_pub is None)):
                    self._publish_grid()        # (withdrawn: the topic checked each period)
                period = self.settings.stats_period
                if period > 0 and now - self._last_stats >= period:
                    self._log_stats(now)
                period = self.settings.diagnostics_period
                if period > 0 and now - self._last_diag >= period:
                    self._publish_diagnostics(now)
            except Exception as exc:        # keep mapping; say what went wrong
                self.warnings.warn('internal_error', f'update failed: {exc!r}')

    def _publish(self) -> None:
        with self._publish_lock:
            self._dirty = False
            used = self.session.used
            value = self.session.map_value()
            self._published = (used, self.session.generation, value.segments)
            frame = value.frame_id          # fixed_frame, or the frame of a loaded map
            stamp = (time_msg(value.stamp) if value.stamp is not None
                     else self.get_clock().now().to_msg())
            self.map_pub.publish(map_to_msg(value, frame, stamp))
            if self.settings.publish_markers:
                self.marker_pub.publish(map_to_markers(value, frame, stamp,
                                                       self.settings.marker_color,
                                                       self.settings.marker_width))
                self._markers_shown = True
            elif self._markers_shown:         # switched off: leave no stale strips behind
                self.marker_pub.publish(map_to_markers(MapValue.empty(frame), frame, stamp,
                                                       self.settings.marker_color, 0.0))
                self._markers_shown = False
            self._last_publish = time.monotonic()

    def _publish_localization(self) -> None:
        """Broadcast map -> odom and publish the pose of the newest localized scan (once)."""
        loc = self.session.localization
        if loc is None or (loc is self._localized and loc is not self._root_waiting):
            return
        frame = self.settings.fixed_frame
        if loc is not self._localized:      # each pose once, its transform maybe later
            self._localized = loc
            self.pose_pub.publish(pose_msg(frame, time_msg(loc.stamp), loc.pose,
                                           loc.covariance))
        self._root_waiting = None
        if loc.odom_frame is None and self.settings.pose_source == 'scan':
            # scans alone: no odometry frame to correct; the robot itself goes under the map
            # frame (hector_mapping's map -> base_link), at its scan's stamp
            child, pose, why = self.session.scan_root(loc)
            if child is None:
                self.warnings.warn('tf_frames', f'not broadcasting {frame} -> the laser: {why}')
                return
            if child == loc.scan_frame and time.monotonic() - self._first_scan_at < \
                    self.settings.transform_timeout:
                # The laser without a parent yet: its mount on /tf_static may still be on its
                # way (discovery races the first scans). Broadcast as its parent, the laser would
                # get two (REP 105: one); wait as a scan waits for its transforms. The pose is
                # out already (it was published again on every pass of the worker while the
                # transform waited, about every 50 ms: one stamp several times on `pose`).
                self._root_waiting = loc
                return
            stamp = time_msg(loc.stamp)
            self._sent.append((stamp.sec, stamp.nanosec))
            self._scan_child = child
            self.tf_pub.publish(self._tf_message(transforms=[planar_transform_msg(
                frame, child, stamp, pose)]))
            return
        if loc.odom_frame is None or loc.odom_frame == frame:
            self.warnings.warn('tf_frames', f'not broadcasting {frame} -> {loc.odom_frame}: the '
                               'odometry frame must differ from fixed_frame with scan matching')
            return
        stamp = time_msg(loc.stamp + self.settings.map_odom_post_date)
        self._sent.append((stamp.sec, stamp.nanosec))
        self.tf_pub.publish(self._tf_message(transforms=[planar_transform_msg(
            frame, loc.odom_frame, stamp, loc.correction)]))

    def _publish_grid(self, cleared: bool = False) -> None:
        """
        Publish the planner map (nav_msgs/OccupancyGrid on 'map'), stamped as the map.

        Not before the published polyline map has a segment (or a saved map was loaded): the
        traced beams alone are free space with no wall, which a planner that allows unknown
        cells crosses (an audit: the first four grids of the Intel log, 4269-9901 free cells
        and none occupied). ``cleared``: after ``~/reset``, the empty grid all the same.
        Not while another node publishes on the topic (``_grid_topic_free``).
        """
        with self._publish_lock:
            self._grid_dirty = False
            used, gen, segments = self._published
            if not cleared and self.session.loaded is None and (segments is None
                                                                or not len(segments)):
                return
            if not self._grid_topic_free():
                self._last_grid = time.monotonic()
                return
            current = used == self.session.used and gen == self.session.generation
            grid = self.session.occupancy(segments if current else None)  # no 2nd polylines()
            stamp = self.session.stamp
            stamp = (time_msg(stamp) if stamp is not None else self.get_clock().now().to_msg())
            self.grid_pub.publish(grid_to_msg(grid, self.session.map_frame, stamp))
            self._last_grid = time.monotonic()

    def _grid_topic_free(self) -> bool:
        """
        Whether no other node publishes on the planner map's topic; else warn and withdraw.

        On a robot whose map comes from map_server (AMCL) or slam_toolbox, two maps on one
        topic make AMCL and the costmaps swap between them at every message (an integration
        audit: map_server's 400 x 300 map, then the node's growing partial grid every second).
        While another publisher is there the node's grid publisher is destroyed, so that its
        last grid (transient local) does not reach late subscribers either, and made again
        when the other has gone (the publish lock held).
        """
        topic = self.resolve_topic_name('map')
        others = sorted(publisher_nodes(self, topic) - {self.get_fully_qualified_name()})
        if not others:
            if self.grid_pub is None:
                self.grid_pub = self.create_publisher(OccupancyGrid, 'map', MAP_QOS)
            return True
        self.warnings.warn('map_topic_shared', f'{", ".join(others)} also publish(es) on '
                           f'{topic}: this node does not publish its planner map there while '
                           'they do (AMCL and the costmaps would swap between two maps); remap '
                           'it (-r map:=polyline_map/grid) or set grid_publish_period 0')
        if self.grid_pub is not None:
            self.destroy_publisher(self.grid_pub)
            self.grid_pub = None
        return False

    def _log_stats(self, now: float) -> None:
        p = self.session
        received, used, updates = p.received - self._stats_mark[0], p.used - \
            self._stats_mark[1], p.updates - self._stats_mark[2]
        self._stats_mark = (p.received, p.used, p.updates)
        self._last_stats = now
        times = list(p.update_seconds)[-updates:] if updates else []
        timing = (f', update median {1e3 * sorted(times)[len(times) // 2]:.1f} ms, max '
                  f'{1e3 * max(times):.1f} ms' if times else '')
        self.get_logger().info(
            f'map {self._published_count()} segments (sigma {_cm(p.mapper.sigma)}); last '
            f'{self.settings.stats_period:g} s: {received} scans in, {used} used, {updates} '
            f'updates{timing}')

    def _publish_diagnostics(self, now: float) -> None:
        p = self.session
        st = p.stats()
        received, used, dropped = (st['scans'] - self._diag_mark[0],
                                   st['scans_used'] - self._diag_mark[1],
                                   st['dropped'] - self._diag_mark[2])
        self._diag_mark = (st['scans'], st['scans_used'], st['dropped'])
        self._last_diag = now
        silent = self._scans_silent(now)
        if 'scan' in self.incompatible and not self.count_publishers(
                self.resolve_topic_name('scan')):
            del self.incompatible['scan']       # that publisher has gone (an audit: WARN stayed)
        unmatched = p.unmatched
        level, message = mapping_status(received, used, dropped, st['scans'], p.lost,
                                        self.resolve_topic_name('scan'), st['scans_used'],
                                        self.publishers_matched.get('scan'), silent,
                                        p.wrong_start, self.incompatible.get('scan'),
                                        unmatched)
        if silent is not None and not self._silence_said:
            self.warnings.warn('scans_stopped', message)    # once a stop (counted once)
        self._silence_said = silent is not None
        grid_check = max(STANDING_SECONDS, 2.0 * self.settings.grid_publish_period)
        standing = [text for cause, text in STANDING_WARNINGS.items() if self.warnings.recent(
            cause, grid_check if cause == 'map_topic_shared' else STANDING_SECONDS)]
        if standing:
            level, message = 1, '; '.join(standing + ([message] if level else []))
        sigma = p.mapper.sigma or 0.0
        r = (p.mapper.r or 0.0) if sigma else 0.0
        # the noise scale to 9 digits, not the 3 decimals of the other floats: record-map
        # stores it in the map file (stats.sigma, stats.r), as ~/save_map does
        values = {'segments': self._published_count(), 'sigma_m': f'{sigma:.9g}',
                  'r_m': f'{r:.9g}',
                  'lost': int(p.lost), 'unmatched_scans': (unmatched or (0,))[0],
                  'scans_received': st['scans'], 'scans_used': st['scans_used'],
                  'scans_dropped': st['dropped'], 'updates': st['updates']}
        for topic, count in sorted(self.publishers_matched.items()):
            values[f'publishers_{topic}'] = count
        for key in ('update_ms', 'latency_ms'):
            for q, v in st.get(key, {}).items():
                values[f'{key}_{q}'] = v
        for cause, n in sorted(self.warnings.counts.items()):
            values[f'warned_{cause}'] = n
        for key in ('scan_matching', 'match_jumps'):
            for what, n in st.get(key, {}).items():
                values[f'{key}_{what.replace(" ", "_")}'] = n
        self.diag_pub.publish(diagnostics_msg(f'{self.get_fully_qualified_name()}: mapping',
                                              level, message,
                                              values, self.get_clock().now().to_msg()))

    def _scans_silent(self, now: float):
        """
        Return the seconds since the last scan when the scans stopped, else None.

        Stopped: none for ``SCAN_SILENCE`` times their usual interval (the median of the last
        ``SCAN_ARRIVALS``), and at least ``SCAN_SILENCE_MIN`` s. A laser that stops is a real
        robot's commonest failure; without this /diagnostics stayed OK ('mapping') for as long
        as the laser was silent while map -> odom (sent per scan) aged.
        """
        times = list(self._scan_arrivals)
        if not times:
            return None
        since = now - times[-1]
        usual = float(np.median(np.diff(times))) if len(times) > 2 else 0.0
        return since if since > max(SCAN_SILENCE_MIN, SCAN_SILENCE * usual) else None

    def close(self) -> None:
        """
        Stop the worker thread and log a summary of the run.

        With ``save_map_on_shutdown`` the scans still queued are mapped first (as at the end of
        a replay) and the map is written as ``~/save_map`` writes it.
        """
        self._stop.set()
        self._worker.join(timeout=5.0)
        if self.settings.save_map_on_shutdown:
            try:
                if not self._worker.is_alive():     # (else: the map as it stands)
                    queued = self.session.queued_scans()
                    if queued:
                        self.get_logger().info(f'mapping the {queued} queued scan(s) before '
                                               f'saving the map to {self.settings.output_path}')
                    self.session.flush(final=True)
            except Exception as exc:        # the map so far is still written
                self.get_logger().error(f'mapping the queued scans at shutdown failed: {exc!r}')
            self.save_failed = False
            self._save_map()
        st = self.session.stats()
        warned = ', '.join(f'{k} {v}' for k, v in sorted(self.warnings.counts.items())) or 'none'
        # Every scan received is counted once: used, dropped (load), skipped (bad, no pose,
        # not found by scan matching: the warnings say which), cleared by ~/reset, or still
        # waiting for a pose or its update group (without save_map_on_shutdown, or waiting for
        # a transform when the node stopped).
        line = (f"summary: {st['scans']} scans received, {st['scans_used']} used in "
                f"{st['updates']} updates, {st['dropped']} dropped, {st['scans_skipped']} "
                'skipped'
                + (f", {st['scans_cleared']} cleared by ~/reset" if st['scans_cleared'] else '')
                + (f", {st['scans_queued']} not mapped at shutdown (queued)"
                   if st['scans_queued'] else '')
                + f'; warnings: {warned}')
        if self.settings.pose_source == 'odom':
            line += f'; {self.odometry_received} odometry messages received'
        for key in ('update_ms', 'latency_ms'):
            if key in st:
                v = st[key]
                line += (f"; {key} p50 {v['p50']:.1f} p95 {v['p95']:.1f} p99 {v['p99']:.1f} "
                         f"max {v['max']:.1f}")
        line += f'; map {len(self.session.map_value().segments)} segments'
        self.get_logger().info(line)

    def _published_count(self) -> int:
        """
        Return the segments of the map as last published (as /polyline_map and save_map count).

        The mapper's own segments are counted before ``polylines()`` joins them into the map
        it publishes (25 against 24 on the office drive).
        """
        segments = self._published[2]
        return 0 if segments is None else len(segments)


def mapping_status(received: int, used: int, dropped: int, total: int, lost: bool,
                   topic: str, total_used: int = None, publishers: int = None,
                   silent: float = None, wrong_start: float = None,
                   incompatible: str = None, unmatched: tuple = None) -> tuple:
    """
    Return the /diagnostics (level, message) of one period: 0 OK, 1 WARN.

    ``received`` / ``used`` / ``dropped``: scans in the period; ``total``: scans ever
    received; ``lost``: scan matching does not know where the scans are
    (``MappingSession.lost``); ``total_used``: scans ever used; ``publishers``: publishers
    matched on the scan topic (None: not known); ``silent``: seconds since the last scan when
    the scans stopped (``PolylineMapperNode._scans_silent``), else None; ``wrong_start``: on a
    saved map, the share of the first scans' beams through its walls when they were matched
    onto a wrong place (``MappingSession.wrong_start``), else None; ``incompatible``: the
    QoS policy of the last scan publisher whose QoS could not match, else None; ``unmatched``:
    on a saved map, (scans, seconds) not matched in a row when they make the localizer not
    localized (``MappingSession.unmatched``), else None.
    """
    if silent is not None and total:
        return 1, (f'no scan on {topic} for {silent:.1f} s ({total} received before): has the '
                   'laser or its driver stopped? Nothing is mapped (nor a map -> odom of this '
                   'node sent) until scans come again')
    if wrong_start is not None:
        return 1, (f'localizing on the saved map from a wrong place: {100 * wrong_start:.0f} % '
                   "of the first scans' beams pass through its walls; the poses, map -> odom "
                   "and the map are not to be trusted until the robot's pose is given "
                   '(initial_pose, or a pose estimate on initialpose)')
    if lost:
        return 1, ('lost: scan matching refuses the predicted pose (wheel slip, a kidnapped '
                   'robot?) or searches for the scans (after a gap in them, near a pose '
                   'estimate); scans are not mapped until one matches the map again')
    if unmatched is not None:
        return 1, (f'not localized: the last {unmatched[0]} scans ({unmatched[1]:.1f} s) matched '
                   'nothing of the saved map (the laser blocked, or the robot off the map?); '
                   'the pose follows the odometry until a search finds the scans on the map')
    if received and not used:
        return 1, f'{received} scans received, none used (see the warnings)'
    if dropped:
        return 1, f'{dropped} scans dropped: updates fall behind'
    if not total:
        if incompatible is not None and not publishers:
            return 1, (f'no scans on {topic}: a publisher there offers a QoS this node cannot '
                       f'match ({incompatible}); see the incompatible_qos_scan warning')
        if publishers is None:
            return 0, f'waiting for scans on {topic}'
        return 0, (f'waiting for scans on {topic}: ' + (
            'no publisher matched (none yet, or its QoS cannot match)' if not publishers
            else f'{publishers} publisher{"" if publishers == 1 else "s"} matched, no scan '
            'received yet'))
    if total_used == 0:         # the scans stopped, and not one of them was ever used
        return 1, f'{total} scans received, none used yet (see the warnings)'
    return 0, 'mapping'


def session_options(settings) -> SessionOptions:
    """Return the mapping session's options for the node's settings (live, wall time)."""
    odom = settings.pose_source == 'odom'
    return SessionOptions(
        pose_source=settings.pose_source, fixed_frame=settings.fixed_frame,
        tolerance=settings.transform_tolerance, wait=settings.transform_timeout,
        mount=(settings.laser_x, settings.laser_y, settings.laser_yaw) if odom else None,
        mount_upside_down=settings.laser_upside_down, cache_seconds=settings.transform_cache,
        odom_gap_factor=settings.odom_gap_factor, scan_time_offset=settings.scan_time_offset,
        update_every_n_scans=settings.update_every_n_scans,
        max_waiting=settings.scan_buffer_size, max_queue=settings.scan_buffer_size,
        max_latency=settings.max_scan_latency or None, grid_resolution=settings.grid_resolution,
        scan_matching=settings.scan_matching, mapping=settings.mapping,
        chord_knots=settings.chord_knots, odom_frame=settings.odom_frame or None)


def _cm(sigma) -> str:
    return 'not yet estimated' if sigma is None else f'{100 * sigma:.1f} cm'


def _interrupt(signum, frame):
    """Stop the spin loop at the first SIGINT or SIGTERM; later ones must not end the close."""
    signal.signal(signal.SIGINT, _while_closing)
    signal.signal(signal.SIGTERM, _while_closing)
    raise KeyboardInterrupt


def _while_closing(signum, frame):
    """Say once that a signal during shutdown is ignored: the map is still being finished."""
    if not getattr(_while_closing, 'said', False):
        _while_closing.said = True
        get_logger(NODE_NAME).warn(f'{signal.Signals(signum).name} while shutting down: ignored '
                                   '(finishing the map; SIGKILL stops the node at once)')


def _named_logger():
    """
    Return the logger of the node as it would run (its namespace and name remaps applied).

    A node that could not start leaves none: a stand-in of the same name is made for the
    line, so /robot1's failure says [robot1.polyline_mapper_node], not [polyline_mapper_node].
    """
    try:
        stand_in = rclpy.create_node(NODE_NAME, start_parameter_services=False,
                                     enable_rosout=False)
    except Exception:                   # noqa: B902 (the plain name is the fallback)
        return get_logger(NODE_NAME)
    logger = stand_in.get_logger()
    stand_in.destroy_node()
    return logger


def main(args=None) -> int:
    """
    Run the node until SIGINT / SIGTERM; exit code 1 with one line on bad parameters.

    Bad ROS arguments (a missing, broken or binary ``--params-file``, ``-p name:=`` without a
    value) are refused the same way, before rclpy starts (``startup``).

    rclpy's own signal handlers are off: a signal raises KeyboardInterrupt in the spin loop
    (within its 0.1 s wait), so the worker is stopped and the summary logged while the context
    is still valid, before the node is destroyed and rclpy shut down.
    """
    try:
        startup.init(args, signal_handler_options=SignalHandlerOptions.NO)
    except startup.StartupError as exc:         # bad ROS arguments or parameter file
        get_logger(NODE_NAME).fatal(f'cannot start: {exc}')
        return 1
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        node = PolylineMapperNode()
    except ConfigError as exc:
        _named_logger().fatal(f'cannot start: {exc}')
        rclpy.try_shutdown()
        return 1
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return 0
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # A second Ctrl-C, or the SIGTERM ros2 launch sends after a SIGINT, must not break off
        # the shutdown: it raised KeyboardInterrupt inside the flush, with a traceback, and
        # save_map_on_shutdown wrote nothing. (_interrupt swaps the handlers already; this
        # covers a shutdown from outside, ExternalShutdownException.)
        signal.signal(signal.SIGINT, _while_closing)
        signal.signal(signal.SIGTERM, _while_closing)
        node.close()
        executor.remove_node(node)
        node.destroy_node()
        rclpy.try_shutdown()
    # A map that save_map_on_shutdown could not write: exit 1, so that a supervisor (or the
    # user's script) knows the run's map is not on disk.
    return 1 if node.settings.save_map_on_shutdown and node.save_failed else 0


if __name__ == '__main__':
    sys.exit(main())
