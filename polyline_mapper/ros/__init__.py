"""
The ROS 2 side of polyline_mapper: the node, message conversions and transform listeners.

rclpy is imported only by the modules in this package that need it (node, convert,
tf_listener); ``params`` is ROS-free so tests and tools can read the parameter table.
"""
