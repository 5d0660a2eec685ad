"""
The ROS 2 side of polyline_mapper: the node, message conversions, play, record-map, live demo.

rclpy is imported only here (node, messages, qos, startup, player, recorder, live_demo); the
node converts messages to records for ``session.MappingSession`` and its map value back to
messages. ``params`` is ROS-free so tests and tools can read the parameter table.
"""
