"""
``polyline-mapper record-map``: take the map a running node publishes, for saving as map JSON.

Subscribes to a polyline_mapper_msgs/PolylineMap topic with the node's QoS (reliable, transient
local), so the current map arrives at once, and keeps the newest. It stops after the first map
(``once``), after ``idle`` seconds without a new map, when ``should_stop()`` says so (the
command line sets that from SIGINT / SIGTERM, see ``ros.player.stop_on_signals``) or on
KeyboardInterrupt, and returns the newest as a ``MapValue``. No map within ``timeout`` seconds,
a stop before any map, or a map whose polylines disagree with its segments (``read_map`` would
refuse the file) is an error (ValueError, one line).
"""

import math
import time
from typing import Callable, Optional

from polyline_mapper_msgs.msg import PolylineMap

from . import startup
from .messages import map_from_msg
from .qos import MAP_QOS
from ..core.mapvalue import MapValue
from ..formats.mapjson import check_edges, map_value_to_dict


class MapRecorder:
    """Keep the newest PolylineMap of ``topic`` on ``node`` (and when it came)."""

    def __init__(self, node, topic: str = 'polyline_map'):
        try:
            self.topic = node.resolve_topic_name(topic)
        except Exception as exc:                # noqa: B902 - rclpy's RCLError
            raise ValueError(f'topic {topic!r}: {startup.rcl_reason(exc)}') from None
        self.latest: Optional[PolylineMap] = None
        self.count = 0
        self.received_at = None
        node.create_subscription(PolylineMap, topic, self._on_map, MAP_QOS)

    def _on_map(self, msg: PolylineMap) -> None:
        self.latest = msg
        self.count += 1
        self.received_at = time.monotonic()

    def stamp(self) -> float:
        """Return the newest map's header time in seconds, -inf before any map."""
        if self.latest is None:
            return -math.inf
        return self.latest.header.stamp.sec + 1e-9 * self.latest.header.stamp.nanosec

    def to_value(self, extra_stats: dict = None) -> MapValue:
        """Return the newest map as a MapValue (ValueError when there is none)."""
        if self.latest is None:
            raise ValueError(f'no map received on {self.topic}')
        m = map_from_msg(self.latest)
        try:            # (a publisher other than the node may send polylines of another map)
            check_edges(m['segments'], m['polylines'], m['closed'])
        except ValueError as exc:
            raise ValueError(f'the map on {self.topic}: {exc}; not saved (a map file must '
                             'agree with itself)') from None
        stats = {'segments': int(len(m['segments'])), 'polylines': len(m['polylines']),
                 'stamp': round(m['stamp'], 6), 'topic': self.topic,
                 'maps_received': self.count}
        stats.update(extra_stats or {})
        return MapValue(m['segments'], m['support'], m['polylines'], m['closed'],
                        m['frame_id'], m['stamp'], stats)

    def to_dict(self, extra_stats: dict = None) -> dict:
        """Build the map JSON dict of the newest map (ValueError when there is none)."""
        return map_value_to_dict(self.to_value(extra_stats))


def run_record_map(topic: str = 'polyline_map', once: bool = False, idle: float = None,
                   timeout: float = 30.0, ros_args=None,
                   should_stop: Callable[[], bool] = None) -> MapValue:
    """
    Wait for the map published on ``topic``; return the newest as a MapValue.

    Runs its own rclpy context; see the module docstring for when it stops. ``timeout`` None
    or 0 waits for the first map forever. ``should_stop`` is polled every 50 ms.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    for name, value in (('idle', idle), ('timeout', timeout)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ValueError(f'--{name} must be a number of seconds >= 0, got {value!r}')
    context = rclpy.Context()
    # bad --ros-args or ROS_DOMAIN_ID: a StartupError (a ValueError), one line
    startup.init(ros_args, context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node('polyline_mapper_map_recorder', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        rec = MapRecorder(node, topic)
        t0 = time.monotonic()
        try:
            while True:
                executor.spin_once(timeout_sec=0.05)
                now = time.monotonic()
                if should_stop is not None and should_stop():
                    break
                if rec.count == 0:
                    if timeout and now - t0 >= timeout:
                        raise ValueError(f'no map on {rec.topic} within {timeout:g} s (is the '
                                         'node running, on this ROS_DOMAIN_ID?)')
                    continue
                if once or (idle is not None and now - rec.received_at >= idle):
                    break
        except KeyboardInterrupt:
            pass
        if rec.count == 0:
            raise ValueError(f'interrupted before any map arrived on {rec.topic}')
        value = rec.to_value()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return value
