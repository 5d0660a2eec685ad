"""QoS profiles shared by the node, the player, the recorder and the tests."""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

MAP_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""The map and its markers: a late subscriber gets the current map at once."""
# The QoS tf2_ros uses for its listener: /tf reliable and volatile, /tf_static transient local
# so a late listener still gets every static transform.
TF_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


def sensor_data() -> QoSProfile:
    """
    Return a new copy of rclpy's sensor-data profile (best effort, volatile, depth 5).

    A subscription with ``qos_overriding_options`` writes its overrides into the profile it is
    given: given rclpy's shared ``qos_profile_sensor_data``, the overrides of one topic (odom
    made reliable) would become every later subscription's (the scans', which then hear nothing
    from a best-effort laser driver).
    """
    return QoSProfile(depth=5, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def check_input_qos(qos: QoSProfile):
    """
    Return whether an input's overridden QoS is usable (``QoSOverridingOptions`` callback).

    rclpy itself passes a depth below 1 with history keep_last on to rcl, which refuses it as
    an "invalid allocator".
    """
    from rcl_interfaces.msg import SetParametersResult
    if qos.history == HistoryPolicy.KEEP_LAST and qos.depth < 1:
        return SetParametersResult(successful=False, reason=f'depth must be >= 1 with history '
                                   f'keep_last, got {qos.depth}')
    return SetParametersResult(successful=True)
