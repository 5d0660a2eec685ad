"""
Messages <-> arrays: LaserScan in, PolylineMap and MarkerArray out, transforms in.

No logic beyond the conversion: checks live in ``scan.check_scan``, the numbers come from
the core. Coordinates are metres in the map's frame; z is 0.
"""

from geometry_msgs.msg import Point
import numpy as np
from polyline_mapper_msgs.msg import Polyline, PolylineMap, Segment
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from .pipeline import MapSnapshot
from ..scan import check_scan, ScanArrays

MARKER_NAMESPACE = 'polyline_map'


def stamp_seconds(stamp) -> float:
    """Return a builtin_interfaces/Time as float seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def scan_from_msg(msg) -> ScanArrays:
    """Check a sensor_msgs/LaserScan and return its arrays (raises scan.ScanError)."""
    return check_scan(msg.ranges, msg.angle_min, msg.angle_increment, msg.range_min,
                      msg.range_max, len(msg.intensities), stamp_seconds(msg.header.stamp),
                      msg.header.frame_id, msg.header)


def transform_from_msg(ts) -> tuple:
    """Return (parent, child, stamp s, translation (3,), quaternion xyzw) of a TransformStamped."""
    t, q = ts.transform.translation, ts.transform.rotation
    return (ts.header.frame_id, ts.child_frame_id, stamp_seconds(ts.header.stamp),
            (t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


def _points(xy: np.ndarray) -> list:
    return [Point(x=x, y=y) for x, y in np.asarray(xy, dtype=np.float64).reshape(-1, 2).tolist()]


def map_to_msg(snap: MapSnapshot, frame_id: str, stamp) -> PolylineMap:
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


def map_to_markers(snap: MapSnapshot, frame_id: str, stamp, color, width: float) -> MarkerArray:
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
