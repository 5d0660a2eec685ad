"""
``polyline-mapper record-map``: take the map a running node publishes, for saving as map JSON.

Subscribes to a polyline_mapper_msgs/PolylineMap topic with the node's QoS (reliable, transient
local), so the current map arrives at once, and keeps the newest; and to the node's planner map
(nav_msgs/OccupancyGrid on ``map``, the same QoS), kept with it so that the file holds the grid
as the node's ``~/save_map`` writes it (``export`` then gives map_server the free space the
beams saw, not only the segments). It stops after the first map (``once``), after ``idle``
seconds without a new map, when ``should_stop()`` says so (the command line sets that from
SIGINT / SIGTERM, see ``ros.player.stop_on_signals``) or on KeyboardInterrupt, then waits up to
``GRID_WAIT`` s for a grid as new as the map (the node publishes it at most every
``grid_publish_period``), and returns the newest map as a ``MapValue`` with the grid and the
mapper configuration of the node that published it (its ``smemsf.*`` and ``incremental.*``
parameters, read through its ``get_parameters`` service as the node's ``~/save_map`` writes its
own ``config``; None, with the reason, when the publisher is not such a node) and its noise
scale (sigma and r as its /diagnostics report them, the map file's ``stats.sigma`` and
``stats.r`` that a localization on the map needs, as ``~/save_map`` writes them). No map
within ``timeout`` seconds, a stop before any map, or a map whose polylines disagree with its
segments (``read_map`` would refuse the file) is an error (ValueError, one line).
"""

import math
import time
from typing import Callable, NamedTuple, Optional

from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid
from polyline_mapper_msgs.msg import PolylineMap

from . import startup
from .messages import grid_from_msg, map_from_msg, publisher_nodes, stamp_seconds
from .qos import MAP_QOS
from ..core.grid import GridMap
from ..core.mapvalue import MapValue
from ..formats.mapjson import check_edges, map_value_to_dict

PARAMS_WAIT = 3.0
"""Seconds ``run_record_map`` waits for the publishing node's parameters."""

NOISE_NODES = 64
"""Mapping nodes whose noise scale ``MapRecorder`` keeps from /diagnostics (a bound)."""

SCAN_COUNTS = ('scans_received', 'scans_used', 'scans_dropped')
"""The node's scan counts on /diagnostics that ``run_record_map`` writes into the map's stats."""

GRID_WAIT = 3.0
"""Seconds ``run_record_map`` waits, once it stops, for a planner map as new as the map (the
node publishes one at most every ``grid_publish_period``, 1 s by default)."""


class RecordedMap(NamedTuple):
    """What ``run_record_map`` took: the map, and its planner map (None when none came)."""

    value: MapValue
    grid: Optional[GridMap]
    config: Optional[dict] = None
    """The publishing node's mapper configuration (``formats.mapjson.config_dict``), or None."""
    no_config: str = ''
    """Why ``config`` is None ('' when it is not)."""
    noise_scale: Optional[tuple] = None
    """The publishing node's (sigma, r) in metres (r None when not reported), or None."""


def _resolved(node, topic: str) -> str:
    """Return ``topic`` resolved on ``node`` (ValueError, one line, for an invalid name)."""
    try:
        return node.resolve_topic_name(topic)
    except Exception as exc:                    # noqa: B902 - rclpy's RCLError
        raise ValueError(f'topic {topic!r}: {startup.rcl_reason(exc)}') from None


class MapRecorder:
    """Keep the newest PolylineMap of ``topic`` on ``node`` (and when it came), and its grid."""

    def __init__(self, node, topic: str = 'polyline_map', grid_topic: Optional[str] = None):
        """
        Subscribe to ``topic`` and, unless ``grid_topic`` is empty, to the planner map.

        ``grid_topic`` None: ``map`` beside ``topic`` (the node publishes both in its
        namespace): /robot2/map for /robot2/polyline_map (it was ``map`` in the recorder's
        own namespace, so another robot's map was stored without its grid: an audit).
        """
        self.topic = _resolved(node, topic)
        if grid_topic is None:
            grid_topic = self.topic.rpartition('/')[0] + '/map'
        self.grid_topic = _resolved(node, grid_topic) if grid_topic else None
        self.latest: Optional[PolylineMap] = None
        self.latest_grid: Optional[OccupancyGrid] = None
        self.count = 0
        self.received_at = None
        self.grid_shared_with = []
        """Nodes besides the map's publisher that publish on ``grid_topic`` (``check_grid``):
        its grid is then not taken."""
        self.noise = {}
        """Per diagnostics status name ('<node>: mapping'): the (sigma, r) it last reported."""
        self.scans = {}
        """Per diagnostics status name: the scans received, used and dropped it last reported
        (``SCAN_COUNTS``)."""
        node.create_subscription(PolylineMap, topic, self._on_map, MAP_QOS)
        if grid_topic:
            node.create_subscription(OccupancyGrid, grid_topic, self._on_grid, MAP_QOS)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)

    def _on_map(self, msg: PolylineMap) -> None:
        self.latest = msg
        self.count += 1
        self.received_at = time.monotonic()

    def _on_grid(self, msg: OccupancyGrid) -> None:
        self.latest_grid = msg

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if not status.name.endswith(': mapping'):
                continue
            values = {kv.key: kv.value for kv in status.values}
            try:
                counts = {key: int(values[key]) for key in SCAN_COUNTS}
            except (KeyError, ValueError):
                counts = None
            if counts is not None and (status.name in self.scans
                                       or len(self.scans) < NOISE_NODES):
                self.scans[status.name] = counts
            try:
                sigma, r = float(values['sigma_m']), float(values.get('r_m', 'nan'))
            except (KeyError, ValueError):
                continue
            if not (math.isfinite(sigma) and sigma > 0):
                continue                        # (not estimated yet)
            if status.name in self.noise or len(self.noise) < NOISE_NODES:
                self.noise[status.name] = (sigma, r if math.isfinite(r) and r > 0 else None)

    def grid_current(self) -> bool:
        """Whether the newest grid is of the newest map's frame and at least as new."""
        g, m = self.latest_grid, self.latest
        return (g is not None and m is not None and g.header.frame_id == m.header.frame_id
                and stamp_seconds(g.header.stamp) >= stamp_seconds(m.header.stamp) - 1e-9)

    def check_grid(self, node) -> None:
        """
        Note the nodes that publish on the grid topic but not on the map topic.

        Beside map_server the node withdraws its grid from a shared topic, and the grid that
        came was map_server's (an audit: record-map stored it, 400 x 300 cells, with the
        node's polylines); the grid is then not taken.
        """
        if self.grid_topic:
            self.grid_shared_with = sorted(publisher_nodes(node, self.grid_topic)
                                           - publisher_nodes(node, self.topic))

    def grid(self) -> Optional[GridMap]:
        """Return the newest planner map of the map's frame as a GridMap, else None."""
        g = self.latest_grid
        if (g is None or self.latest is None or self.grid_shared_with
                or g.header.frame_id != self.latest.header.frame_id):
            return None
        if g.info.width * g.info.height != len(g.data) or not g.info.resolution > 0:
            return None                         # not a grid a map file can hold
        return grid_from_msg(g)

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
        if self.grid_topic:
            grid = self.grid()
            stats['grid_topic'] = self.grid_topic
            stats['grid_stamp'] = (None if grid is None else
                                   round(stamp_seconds(self.latest_grid.header.stamp), 6))
            if self.grid_shared_with:
                stats['grid_shared_with'] = list(self.grid_shared_with)
        stats.update(extra_stats or {})
        return MapValue(m['segments'], m['support'], m['polylines'], m['closed'],
                        m['frame_id'], m['stamp'], stats)

    def to_dict(self, extra_stats: dict = None) -> dict:
        """Build the map JSON dict of the newest map and its grid (ValueError without a map)."""
        return map_value_to_dict(self.to_value(extra_stats), grid=self.grid())


def run_record_map(topic: str = 'polyline_map', once: bool = False, idle: float = None,
                   timeout: float = 30.0, ros_args=None,
                   should_stop: Callable[[], bool] = None,
                   grid_topic: Optional[str] = None) -> RecordedMap:
    """
    Wait for the map published on ``topic``; return the newest, with its planner map.

    Runs its own rclpy context; see the module docstring for when it stops. ``timeout`` None
    or 0 waits for the first map forever. ``should_stop`` is polled every 50 ms. The planner
    map comes from ``grid_topic`` (nav_msgs/OccupancyGrid; None: ``map`` beside ``topic``; '':
    none is taken); a grid
    older than the map after ``GRID_WAIT`` s is taken as it is (``stats['grid_stamp']``).
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
        rec = MapRecorder(node, topic, grid_topic)
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
        taken = take_map(rec, node, executor, should_stop)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return taken


def take_map(rec: MapRecorder, node, executor, should_stop=None) -> RecordedMap:
    """
    Return what ``rec`` holds once the recording ends, with what a map file needs besides.

    The grid as new as the map (up to ``GRID_WAIT`` s, unless a signal ended the recording:
    then the newest already received; a Ctrl-C does not wait), the publisher's mapper
    settings, noise scale and scan counts. ``executor`` spins ``node``'s callbacks (an
    object whose ``spin_once`` only waits, when another thread spins them: the live demo).
    """
    try:
        end = time.monotonic() + GRID_WAIT
        while (rec.grid_topic and not rec.grid_current() and time.monotonic() < end
               and not (should_stop is not None and should_stop())):
            executor.spin_once(timeout_sec=0.05)
    except KeyboardInterrupt:
        pass
    rec.check_grid(node)
    grid = rec.grid()
    config, why, publisher = publisher_config(node, executor, rec.topic, should_stop)
    noise = None if publisher is None else publisher_noise_scale(
        rec, executor, publisher, should_stop)
    extra = {} if noise is None else {'sigma': noise[0], 'r': noise[1]}
    if publisher is not None:       # (reported with the noise scale, or before it)
        extra.update(rec.scans.get(f'{publisher}: mapping', {}))
    return RecordedMap(rec.to_value(extra), grid, config, why, noise)


def publisher_noise_scale(rec: MapRecorder, executor, publisher: str,
                          should_stop=None) -> Optional[tuple]:
    """
    Return the (sigma, r) node ``publisher`` (its full name) reports on /diagnostics, or None.

    Waits up to ``PARAMS_WAIT`` s for a report (the node sends one every
    ``diagnostics_period`` s, 1 by default; none while it has not estimated sigma yet).
    """
    name = f'{publisher}: mapping'
    end = time.monotonic() + PARAMS_WAIT
    while name not in rec.noise and time.monotonic() < end and not (
            should_stop is not None and should_stop()):
        executor.spin_once(timeout_sec=0.05)
    return rec.noise.get(name)


def publisher_config(node, executor, topic: str, should_stop=None) -> tuple:
    """
    Read the mapper settings of the node publishing ``topic``: (config, why, publisher).

    The publisher's ``get_parameters`` service is asked for every ``smemsf.*`` and
    ``incremental.*`` parameter (``params.all_params``), within ``PARAMS_WAIT`` s. A publisher
    without them (another mapper, a bag being played) gives config None and why, else ''.
    ``publisher``: the full name of the one node publishing ``topic``, None when there is not
    one known.
    """
    end = time.monotonic() + PARAMS_WAIT
    while True:
        # (the publisher's endpoint is discovered before its node's name: '_NODE_NAME_UNKNOWN_'
        # until the participant's data comes)
        nodes = sorted(publisher_nodes(node, topic))
        known = all('_UNKNOWN_' not in n.rpartition('/')[2] for n in nodes)
        if should_stop is not None and should_stop():
            return None, f"stopped before the parameters of {topic}'s publisher were read", None
        if (nodes and known) or time.monotonic() >= end:
            break
        executor.spin_once(timeout_sec=0.05)
    if len(nodes) != 1 or not known:
        return None, (f'the node publishing {topic} did not make itself known' if nodes
                      and not known else f'{len(nodes)} nodes publish {topic}' if nodes
                      else f'the publisher of {topic} has left'), None
    publisher = nodes[0]
    config, why = _mapper_parameters(node, executor, publisher, should_stop, end)
    return config, why, publisher


def _mapper_parameters(node, executor, publisher: str, should_stop, end: float) -> tuple:
    """Ask node ``publisher`` for its mapper parameters until ``end``: (config, why)."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python
    from ..formats.mapjson import config_dict
    from ..params import all_params, mapper_config
    name = publisher.rpartition('/')[2]
    service = f'{publisher}/get_parameters'
    names = [p.name for p in all_params() if p.name.startswith(('smemsf.', 'incremental.'))]
    client = node.create_client(GetParameters, service)
    try:
        future = None
        while future is None or not future.done():
            if should_stop is not None and should_stop():
                return None, f'stopped before {service} answered'
            if time.monotonic() >= end:
                return None, f'{service} did not answer within {PARAMS_WAIT:g} s'
            if future is None and client.service_is_ready():
                future = client.call_async(GetParameters.Request(names=names))
            executor.spin_once(timeout_sec=0.05)
        values = future.result().values
        got = {n: parameter_value_to_python(v) for n, v in zip(names, values)}
        if not values or all(v is None for v in got.values()):
            return None, f'{name} is not a polyline_mapper node (it has none of its parameters)'
        if len(values) != len(names) or any(v is None for v in got.values()):
            return None, (f'{name} has {sum(v is not None for v in got.values())} of the '
                          f'{len(names)} mapper parameters of this version')
        return config_dict(mapper_config(got)), ''
    except (ValueError, TypeError) as exc:
        return None, f'{name} has parameters this version cannot read ({exc})'
    finally:
        node.destroy_client(client)
