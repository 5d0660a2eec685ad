"""
Messages <-> plain records (``formats.records``) and the map value (``core.mapvalue``).

LaserScan, TFMessage and Odometry in as records (the node feeds them to the mapping session);
the same records out as messages (play); the MapValue out as PolylineMap and MarkerArray (and
back, for record-map); the planner map (``core.grid.GridMap``) out as nav_msgs/OccupancyGrid
(and back); the localization (scan matching) out as a planar TransformStamped and a
PoseWithCovarianceStamped, a pose estimate (``initialpose``) in; DiagnosticArray out.

No logic beyond the conversion: checks live in ``scan.check_scan``, the numbers come from
the core. Coordinates are metres in the map's frame; z is 0.
"""

import array

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import OccupancyGrid, Odometry
import numpy as np
from polyline_mapper_msgs.msg import Polyline, PolylineMap, Segment
from sensor_msgs.msg import LaserScan
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..core.grid import GridMap
from ..core.mapvalue import MapValue
from ..formats import records
from ..poses import checked_yaw, planar_covariance, pose_covariance, quaternion_from_yaw

MARKER_NAMESPACE = 'polyline_map'


def stamp_seconds(stamp) -> float:
    """Return a builtin_interfaces/Time as float seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def publisher_nodes(node, topic: str) -> set:
    """Return the full names ('/ns/name') of the nodes publishing ``topic`` (rclpy ``node``)."""
    return {f"{i.node_namespace.rstrip('/')}/{i.node_name}"
            for i in node.get_publishers_info_by_topic(topic)}


def time_msg(seconds: float) -> Time:
    """Return float seconds (>= 0) as builtin_interfaces/Time, nanoseconds rounded."""
    ns = int(round(float(seconds) * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


# -- plain records (formats.records) -> messages, for play ----------------------------------
def scan_msg(scan: records.Scan, stamp: float = None) -> LaserScan:
    """Return a records.Scan as sensor_msgs/LaserScan (stamped ``stamp`` s if given)."""
    msg = LaserScan()
    msg.header.frame_id = scan.frame_id
    msg.header.stamp = time_msg(scan.stamp if stamp is None else stamp)
    msg.angle_min = float(scan.angle_min)
    msg.angle_increment = float(scan.angle_increment)
    msg.angle_max = scan.message_angle_max()
    msg.range_min = float(scan.range_min)
    msg.range_max = float(scan.range_max)
    msg.time_increment = float(scan.time_increment)
    msg.scan_time = float(scan.scan_time)
    msg.ranges = np.asarray(scan.ranges, dtype=np.float32)
    return msg


def odometry_msg(odom: records.Odometry, stamp: float = None) -> Odometry:
    """Return a records.Odometry as nav_msgs/Odometry (pose only; zero twist, covariances)."""
    msg = Odometry()
    msg.header.frame_id = odom.frame_id
    msg.header.stamp = time_msg(odom.stamp if stamp is None else stamp)
    msg.child_frame_id = odom.child_frame_id
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in odom.translation)
    q.x, q.y, q.z, q.w = (float(v) for v in odom.rotation)
    return msg


def transform_msg(tr: records.Transform, stamp: float = None) -> TransformStamped:
    """Return a records.Transform as geometry_msgs/TransformStamped."""
    ts = TransformStamped()
    ts.header.frame_id = tr.parent
    ts.header.stamp = time_msg(tr.stamp if stamp is None else stamp)
    ts.child_frame_id = tr.child
    t, q = ts.transform.translation, ts.transform.rotation
    t.x, t.y, t.z = (float(v) for v in tr.translation)
    q.x, q.y, q.z, q.w = (float(v) for v in tr.rotation)
    return ts


def planar_transform_msg(parent: str, child: str, stamp, pose) -> TransformStamped:
    """Return ``pose`` (x, y, yaw of ``child`` in ``parent``) as geometry_msgs/TransformStamped."""
    ts = TransformStamped()
    ts.header.frame_id = parent
    ts.header.stamp = stamp
    ts.child_frame_id = child
    x, y, yaw = (float(v) for v in pose)
    ts.transform.translation.x, ts.transform.translation.y = x, y
    q = ts.transform.rotation
    q.x, q.y, q.z, q.w = (float(v) for v in quaternion_from_yaw(yaw))
    return ts


def pose_msg(frame_id: str, stamp, pose, covariance) -> PoseWithCovarianceStamped:
    """
    Build a geometry_msgs/PoseWithCovarianceStamped from a planar pose and its 3x3 covariance.

    The 6x6 covariance (row-major over x, y, z, roll, pitch, yaw) holds the x, y and yaw rows
    and columns, as AMCL fills it; z, roll and pitch are 0 (the pose is planar).
    """
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    x, y, yaw = (float(v) for v in pose)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y = x, y
    q.x, q.y, q.z, q.w = (float(v) for v in quaternion_from_yaw(yaw))
    msg.pose.covariance = pose_covariance(covariance)
    return msg


# -- messages -> plain records, for the node ---------------------------------------------------
def scan_from_msg(msg) -> records.Scan:
    """Return a sensor_msgs/LaserScan as a records.Scan (float32 fields, as the message has)."""
    return records.Scan(stamp_seconds(msg.header.stamp), records.clean_frame(msg.header.frame_id),
                        float(msg.angle_min), float(msg.angle_increment), float(msg.range_min),
                        float(msg.range_max), np.asarray(msg.ranges, dtype=np.float32),
                        time_increment=float(msg.time_increment),
                        scan_time=float(msg.scan_time), angle_max=float(msg.angle_max),
                        intensities=len(msg.intensities))


def transforms_from_msg(msg, static: bool) -> list:
    """Return the transforms of a tf2_msgs/TFMessage as records.Transform (frames cleaned)."""
    out = []
    for ts in msg.transforms:
        t, q = ts.transform.translation, ts.transform.rotation
        out.append(records.Transform(stamp_seconds(ts.header.stamp),
                                     records.clean_frame(ts.header.frame_id),
                                     records.clean_frame(ts.child_frame_id),
                                     np.array([t.x, t.y, t.z]), np.array([q.x, q.y, q.z, q.w]),
                                     static))
    return out


def odometry_from_msg(msg) -> records.Odometry:
    """Return a nav_msgs/Odometry's pose as a records.Odometry (frames cleaned)."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return records.Odometry(stamp_seconds(msg.header.stamp),
                            records.clean_frame(msg.header.frame_id),
                            records.clean_frame(msg.child_frame_id), np.array([p.x, p.y, p.z]),
                            np.array([q.x, q.y, q.z, q.w]))


def pose_estimate_from_msg(msg) -> records.PoseEstimate:
    """Return a geometry_msgs/PoseWithCovarianceStamped (``initialpose``) as a PoseEstimate."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return records.PoseEstimate(stamp_seconds(msg.header.stamp),
                                records.clean_frame(msg.header.frame_id),
                                np.array([p.x, p.y, checked_yaw(q.x, q.y, q.z, q.w)]),
                                planar_covariance(msg.pose.covariance))


def _points(xy: np.ndarray) -> list:
    return [Point(x=x, y=y) for x, y in np.asarray(xy, dtype=np.float64).reshape(-1, 2).tolist()]


def map_to_msg(snap: MapValue, frame_id: str, stamp) -> PolylineMap:
    """
    Build a polyline_mapper_msgs/PolylineMap: segments (ends joined) with support, polylines.

    ``stamp`` (builtin_interfaces/Time) is the last scan's stamp, or now for an empty map.
    """
    msg = PolylineMap()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    support = np.rint(np.clip(np.asarray(snap.support, dtype=np.float64), 0, 2 ** 32 - 1))
    msg.segments = [Segment(start=Point(x=a[0], y=a[1]), end=Point(x=b[0], y=b[1]), support=s)
                    for (a, b), s in zip(np.asarray(snap.segments).tolist(),
                                         support.astype(np.int64).tolist())]
    msg.polylines = [Polyline(points=_points(p), closed=bool(c))
                     for p, c in zip(snap.polylines, snap.closed)]
    return msg


def map_to_markers(snap: MapValue, frame_id: str, stamp, color, width: float) -> MarkerArray:
    """
    Build a visualization_msgs/MarkerArray: DELETEALL, then one LINE_STRIP per polyline.

    All strips share one namespace with ids 0..P-1; the leading DELETEALL removes strips of an
    earlier, larger map. Closed polylines repeat their first vertex.
    """
    out = MarkerArray()
    clear = Marker(action=Marker.DELETEALL, ns=MARKER_NAMESPACE)
    clear.header.frame_id = frame_id
    clear.header.stamp = stamp
    out.markers.append(clear)
    rgba = ColorRGBA(r=float(color[0]), g=float(color[1]), b=float(color[2]), a=float(color[3]))
    for i, (poly, closed) in enumerate(zip(snap.polylines, snap.closed)):
        m = Marker(ns=MARKER_NAMESPACE, id=i, type=Marker.LINE_STRIP, action=Marker.ADD)
        m.header.frame_id = frame_id
        m.header.stamp = stamp
        m.pose.orientation.w = 1.0
        m.scale.x = float(width)
        m.color = rgba
        pts = np.asarray(poly, dtype=np.float64)
        if closed and len(pts) > 2 and not np.array_equal(pts[0], pts[-1]):
            pts = np.vstack([pts, pts[:1]])
        m.points = _points(pts)
        out.markers.append(m)
    return out


def map_from_msg(msg: PolylineMap) -> dict:
    """
    Return a PolylineMap's content as arrays.

    Keys: ``segments`` (K, 2, 2), ``support`` (K,), ``polylines`` (list of (M, 2)),
    ``closed``, ``frame_id``, ``stamp`` (seconds).
    """
    segs = np.array([[(s.start.x, s.start.y), (s.end.x, s.end.y)] for s in msg.segments],
                    dtype=np.float64).reshape(-1, 2, 2)
    return {'segments': segs,
            'support': np.array([s.support for s in msg.segments], dtype=np.float64),
            'polylines': [np.array([(p.x, p.y) for p in pl.points],
                                   dtype=np.float64).reshape(-1, 2) for pl in msg.polylines],
            'closed': [bool(pl.closed) for pl in msg.polylines],
            'frame_id': msg.header.frame_id, 'stamp': stamp_seconds(msg.header.stamp)}


def grid_to_msg(grid: GridMap, frame_id: str, stamp) -> OccupancyGrid:
    """
    Build a nav_msgs/OccupancyGrid: -1 unknown, 0 free, 100 occupied, row-major from origin.

    ``stamp`` (builtin_interfaces/Time) goes into the header and ``info.map_load_time``.
    """
    msg = OccupancyGrid()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    info = msg.info
    info.map_load_time = stamp
    info.resolution = float(grid.resolution)
    info.width, info.height = grid.width, grid.height
    info.origin.position.x, info.origin.position.y = (float(v) for v in grid.origin)
    info.origin.orientation.w = 1.0
    msg.data = array.array('b', np.ascontiguousarray(grid.data, dtype=np.int8).tobytes())
    return msg


def grid_from_msg(msg: OccupancyGrid) -> GridMap:
    """Return a nav_msgs/OccupancyGrid as a GridMap (its orientation is taken as identity)."""
    data = np.asarray(msg.data, dtype=np.int8).reshape(msg.info.height, msg.info.width)
    # The message's float32 as its shortest decimal (0.05, not 0.05000000074505806: what
    # ~/save_map stores and map_server's YAML then says)
    return GridMap(data, float(str(np.float32(msg.info.resolution))),
                   (float(msg.info.origin.position.x), float(msg.info.origin.position.y)))


def diagnostics_msg(name: str, level: int, message: str, values: dict, stamp) -> DiagnosticArray:
    """
    Build a diagnostic_msgs/DiagnosticArray with one status: ``level`` 0 OK, 1 WARN, 2 ERROR.

    ``values`` become KeyValue pairs in order (floats with 3 decimals).
    """
    status = DiagnosticStatus(level=bytes([level]), name=name, message=message,
                              hardware_id='')
    status.values = [KeyValue(key=str(k), value=f'{v:.3f}' if isinstance(v, float) else str(v))
                     for k, v in values.items()]
    out = DiagnosticArray(status=[status])
    out.header.stamp = stamp
    return out
