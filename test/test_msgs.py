"""The interface package: built, importable, and its messages travel over DDS."""

import os
import time

import pytest

msg = pytest.importorskip('polyline_mapper_msgs.msg',
                          reason='polyline_mapper_msgs is not built (run tools/dev.sh setup)')


def test_message_fields():
    seg = msg.Segment()
    assert {'start', 'end', 'support'} <= set(seg.get_fields_and_field_types())
    poly = msg.Polyline()
    assert poly.get_fields_and_field_types() == {'points': 'sequence<geometry_msgs/Point>',
                                                 'closed': 'boolean'}
    m = msg.PolylineMap()
    assert {'header', 'segments', 'polylines'} <= set(m.get_fields_and_field_types())


@pytest.mark.dds
def test_polyline_map_round_trip_over_dds():
    rclpy = pytest.importorskip('rclpy')
    from geometry_msgs.msg import Point
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST') == 'LOCALHOST'
    rclpy.init()
    try:
        node = rclpy.create_node('test_msgs_round_trip')
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        pub = node.create_publisher(msg.PolylineMap, 'test_polyline_map', qos)
        out = msg.PolylineMap()
        out.header.frame_id = 'map'
        out.segments = [msg.Segment(start=Point(x=0.0, y=0.0), end=Point(x=1.5, y=0.0),
                                    support=42)]
        out.polylines = [msg.Polyline(points=[Point(x=0.0), Point(x=1.5)], closed=False)]
        pub.publish(out)
        got = []
        node.create_subscription(msg.PolylineMap, 'test_polyline_map', got.append, qos)
        deadline = time.monotonic() + 10.0
        while not got and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        assert got, 'no PolylineMap arrived within 10 s'
        assert got[0].header.frame_id == 'map' and got[0].segments[0].support == 42
        assert got[0].segments[0].end.x == 1.5 and len(got[0].polylines[0].points) == 2
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
