"""Helpers for tests with the real node over DDS: the node process, a peer node, a drive player."""

import math
import os
import pathlib
import re
import signal
import subprocess
import sys
import time

from conftest import ALONE
import numpy as np


def node_executable() -> pathlib.Path:
    """
    Return the node's executable: beside this Python (the venv), else where ``ros2 run`` looks.

    In a colcon workspace (``colcon test`` on a ROS install) the node is installed as
    ``<prefix>/lib/polyline_mapper/polyline_mapper_node`` of a prefix on AMENT_PREFIX_PATH, and
    Python is the system's.
    """
    venv = pathlib.Path(sys.executable).parent / 'polyline_mapper_node'
    if venv.is_file():
        return venv
    for prefix in filter(None, os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)):
        exe = pathlib.Path(prefix) / 'lib' / 'polyline_mapper' / 'polyline_mapper_node'
        if exe.is_file():
            return exe
    return venv                          # (missing: starting it names the path)


NODE_EXE = node_executable()
NODE = '/polyline_mapper_node'


def _check_alone(what: str) -> None:
    """Refuse DDS in a test not marked dds (see conftest: those run one at a time)."""
    if os.environ.get(ALONE) != '1':
        raise RuntimeError(f'{what} talks over DDS: mark the test @pytest.mark.dds so that it '
                           'runs apart from the other dds tests, at normal priority')


def ros_arg(value) -> str:
    """Format a parameter value for --ros-args -p name:=value."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(ros_arg(v) for v in value) + ']'
    return repr(value) if isinstance(value, float) else str(value)


class NodeProcess:
    """polyline_mapper_node in a subprocess, its stderr in a file; always stopped by stop()."""

    def __init__(self, folder: pathlib.Path, params: dict = None, name: str = 'node',
                 params_file: pathlib.Path = None, ros_name: str = None):
        """
        Start the node; its stderr goes to ``folder / f'{name}.stderr'``.

        ``ros_name``: the node's name in the ROS graph (``__node:=``), for a test whose node
        runs beside another polyline_mapper_node (``Peer.wait_for_node`` of a peer with
        ``reliable_scans`` then waits for this one's readers by name); None keeps the default.
        """
        _check_alone('NodeProcess')
        self.err_path = folder / f'{name}.stderr'
        self.ros_name = ros_name
        cmd = [str(NODE_EXE), '--ros-args']
        if ros_name is not None:
            cmd += ['-r', f'__node:={ros_name}']
        if params_file is not None:
            cmd += ['--params-file', str(params_file)]
        for key, value in (params or {}).items():
            cmd += ['-p', f'{key}:={ros_arg(value)}']
        self._err = open(self.err_path, 'w')
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=self._err,
                                     env=dict(os.environ, RCUTILS_COLORIZED_OUTPUT='0'))

    def stderr(self) -> str:
        """Return what the node wrote to stderr so far."""
        return self.err_path.read_text()

    def lines(self, needle: str) -> list:
        """Return the stderr lines containing ``needle``."""
        return [ln for ln in self.stderr().splitlines() if needle in ln]

    def wait_for_line(self, needle: str, timeout: float) -> bool:
        """Poll stderr until a line contains ``needle`` (or the process ends / time runs out)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.lines(needle):
                return True
            if self.proc.poll() is not None:
                return bool(self.lines(needle))
            time.sleep(0.05)
        return False

    def stop(self, timeout: float = 10.0):
        """SIGINT, then SIGKILL if needed; return the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        self._err.close()
        return self.proc.returncode


RELIABLE_DEPTH = 1000
"""History of the reliable scan publisher (``Peer``) and of the node's overridden subscription."""


class Peer:
    """An in-process node (own context) that plays drives, listens to the map, calls services."""

    def __init__(self, name: str = 'test_peer', reliable_scans: bool = False):
        """
        Start the peer node in its own context.

        ``reliable_scans``: publish scans reliably, with a history of ``RELIABLE_DEPTH``
        (``polyline-mapper play`` keeps 10), instead of sensor-data QoS, for a node whose /scan
        subscription the QoS overrides make reliable with as deep a history: then no scan is
        lost in transport once both sides have matched (``wait_for_node`` waits for that).
        """
        _check_alone('Peer')
        self.reliable_scans = bool(reliable_scans)
        import rclpy
        from rclpy.event_handler import PublisherEventCallbacks
        from rclpy.executors import SingleThreadedExecutor
        from nav_msgs.msg import Odometry
        from polyline_mapper.ros.qos import MAP_QOS
        from polyline_mapper.ros.qos import TF_QOS, TF_STATIC_QOS
        from polyline_mapper_msgs.msg import PolylineMap
        from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import LaserScan
        from tf2_msgs.msg import TFMessage
        from visualization_msgs.msg import MarkerArray
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        n = self.node
        self.readers = {}           # our writer ('/scan', '/tf', '/odom') -> readers it matched

        def writer(msg_type, topic, qos):
            key = '/' + topic.lstrip('/')
            events = PublisherEventCallbacks(
                matched=lambda info: self.readers.__setitem__(key, info.current_count))
            return n.create_publisher(msg_type, topic, qos, event_callbacks=events)
        self.scan_pub = writer(LaserScan, 'scan', QoSProfile(
            depth=RELIABLE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
            if reliable_scans else qos_profile_sensor_data)
        self.tf_pub = writer(TFMessage, '/tf', TF_QOS)
        self.static_pub = n.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS)
        self.odom_pub = writer(Odometry, 'odom', 10)
        self.maps, self.markers = [], []
        n.create_subscription(PolylineMap, 'polyline_map', self.maps.append, MAP_QOS)
        n.create_subscription(MarkerArray, 'polyline_map/markers', self.markers.append, MAP_QOS)
        self.TFMessage = TFMessage

    def spin_until(self, condition, timeout: float) -> bool:
        """Spin until ``condition()`` holds or ``timeout`` seconds pass; return whether it held."""
        deadline = time.monotonic() + timeout
        while True:
            if condition():
                return True
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(left, 0.05))

    def spin_for(self, seconds: float) -> None:
        """Spin (handle incoming messages) for ``seconds``, e.g. to pace publishing."""
        self.spin_until(lambda: False, seconds)

    def subscription_qos(self, topic: str, node_name: str = 'polyline_mapper_node',
                         timeout: float = 0.0) -> list:
        """
        Return the QoS profiles of ``node_name``'s subscriptions to ``topic`` (discovery's view).

        Waits up to ``timeout`` s for at least one. Discovery carries reliability and
        durability, not the history depth.
        """
        def found():
            return [i.qos_profile for i in self.node.get_subscriptions_info_by_topic(topic)
                    if i.node_name == node_name]
        self.spin_until(lambda: found(), timeout)
        return found()

    def wait_for_node(self, timeout: float = 30.0, odom: bool = False,
                      node: NodeProcess = None) -> bool:
        """
        Wait until the node's subscriptions and map publisher are discovered.

        A peer with ``reliable_scans`` must deliver every scan (and the poses for it), so it
        also waits until both sides of its inputs have matched, each side by its matched
        event: our writers have matched every reader discovered on their topic, and ``node``
        (required then) has logged a count of publishers matched that takes in every writer
        discovered. Discovery is two-sided, and a volatile reader that matches a writer late
        starts at the writer's newest sample: a fixed wait of 3 s lost 31 of 230 scans once
        in CI on a loaded Intel Xeon VM (2026-11-29). Counts: the module's node of
        test_node.py still runs, and its peer still publishes, during the shutdown test; there
        the counts were met by the old node's reader before this node's was discovered, and the
        first 107 of 230 scans were lost (2026-12-01). A ``node`` given a ``ros_name`` must
        also have a reader of its own discovered on each input.
        """
        pub = self.odom_pub if odom else self.tf_pub
        found = self.spin_until(lambda: self.scan_pub.get_subscription_count() > 0
                                and pub.get_subscription_count() > 0
                                and self.node.count_publishers('/polyline_map') > 0, timeout)
        if not self.reliable_scans:
            self.spin_for(0.5)      # give the node's readers a moment to match our writers
            return found
        if node is None:
            raise ValueError('a peer with reliable_scans waits for the node: pass node=')

        def matched(topic):
            infos = self.node.get_subscriptions_info_by_topic(topic)
            readers = len(infos)
            if node.ros_name is not None and not any(i.node_name == node.ros_name
                                                     for i in infos):
                return False
            writers = len(self.node.get_publishers_info_by_topic(topic))
            said = node.lines(f']: {topic}: ')
            count = re.search(r': (\d+) publishers? matched$', said[-1]) if said else None
            return (0 < readers <= self.readers.get(topic, 0)
                    and count is not None and 0 < writers <= int(count[1]))
        inputs = ('/scan', '/odom' if odom else '/tf')
        return found and self.spin_until(lambda: all(matched(t) for t in inputs), timeout)

    def play(self, messages, rate: float, mode: str = 'tf', t0: float = None) -> float:
        """
        Publish a drive's records at ``rate`` scans a second; return the last scan's stamp.

        ``messages``: ``(log_time, topic, record)`` of ``recordings.drive_messages``. Scan k and
        the /tf (``mode`` 'tf') or /odom (``mode`` 'odom') before it are stamped t0 + k / rate
        (t0: now by default); /tf_static is published once, in tf mode.
        """
        from polyline_mapper.ros.messages import odometry_msg, scan_msg, transform_msg
        t0 = time.time() if t0 is None else t0
        period = 1.0 / rate
        tick = time.monotonic()
        k = 0
        for _, topic, record in messages:
            stamp = t0 + k * period
            if topic == '/tf_static' and mode == 'tf':
                self.static_pub.publish(self.TFMessage(
                    transforms=[transform_msg(tr) for tr in record]))
            elif topic == '/tf' and mode == 'tf':
                self.tf_pub.publish(self.TFMessage(
                    transforms=[transform_msg(tr, stamp) for tr in record]))
            elif topic == '/odom' and mode == 'odom':
                self.odom_pub.publish(odometry_msg(record, stamp))
            elif topic == '/scan':
                self.scan_pub.publish(scan_msg(record, stamp))
                k += 1
                tick += period
                self.spin_for(max(0.0, tick - time.monotonic()))
        return t0 + (k - 1) * period

    def call(self, name: str, srv_type, request=None, timeout: float = 10.0):
        """Call a service; return the response (None if it did not answer in time)."""
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=timeout):
                return None
            future = client.call_async(request or srv_type.Request())
            self.spin_until(future.done, timeout)
            return future.result() if future.done() else None
        finally:
            self.node.destroy_client(client)

    def parameter(self, name: str):
        """Return the node's parameter ``name`` (None when it has none)."""
        from rcl_interfaces.msg import ParameterType
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        resp = self.call(f'{NODE}/get_parameters', GetParameters,
                         GetParameters.Request(names=[name]))
        assert resp is not None and len(resp.values) == 1
        value = resp.values[0]
        return None if value.type == ParameterType.PARAMETER_NOT_SET else \
            parameter_value_to_python(value)

    def set_parameters(self, **values):
        """Set node parameters over the set_parameters service; return the SetParametersResults."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request(parameters=[Parameter(k.replace('__', '.'), value=v)
                                                .to_parameter_msg() for k, v in values.items()])
        resp = self.call(f'{NODE}/set_parameters', SetParameters, req)
        return None if resp is None else resp.results

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def scans_of(messages) -> list:
    """Return the Scan records of ``(log_time, topic, record)`` messages, in order."""
    return [record for _, topic, record in messages if topic == '/scan']


def stamp_of(msg) -> float:
    """Return a message header's stamp as float seconds."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def map_segments(msg) -> np.ndarray:
    """Return a PolylineMap's segments as a (K, 2, 2) array."""
    return np.array([[[s.start.x, s.start.y], [s.end.x, s.end.y]] for s in msg.segments],
                    dtype=float).reshape(-1, 2, 2)


def wall_errors(segments: np.ndarray, drive) -> tuple:
    """
    Return (worst distance of any segment point to the world, worst wall end-point error).

    The end-point error of a wall is that of the best segment against the part of the wall
    the laser saw (from the simulator's hit ids), ends matched either way round.
    """
    from conftest import end_errors
    from polyline_mapper.core.geometry import sample_segments
    samples, _ = sample_segments(segments, 0.02)
    stray = float(drive.world.distance(samples).max()) if len(samples) else math.inf
    pts, hits = drive.points(with_hits=True)
    worst = 0.0
    for i, (a, b) in enumerate(drive.world.walls):
        u = (b - a) / np.linalg.norm(b - a)
        t = (pts[hits == i] - a) @ u
        err = end_errors(segments, a + t.min() * u, a + t.max() * u).min()
        worst = max(worst, float(err))
    return stray, worst


def start_refusals(argvs: list, timeout: float = 60.0, workers: int = 4) -> dict:
    """
    Start the node once per argv (after --ros-args; ``workers`` at a time) and let it refuse.

    Returns {index: (argv, returncode, stdout and stderr)}.
    """
    from concurrent.futures import ThreadPoolExecutor

    def run(argv):
        proc = subprocess.run([str(NODE_EXE), '--ros-args'] + argv, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, timeout=timeout,
                              env=dict(os.environ, RCUTILS_COLORIZED_OUTPUT='0'))
        return proc.returncode, proc.stdout.decode(errors='replace')
    with ThreadPoolExecutor(workers) as pool:
        results = list(pool.map(run, argvs))
    return {i: (argv, rc, out) for i, (argv, (rc, out)) in enumerate(zip(argvs, results))}


def assert_refused_in_one_line(outcome: tuple, fragments) -> None:
    """Assert a ``start_refusals`` outcome: exit 1, one 'cannot start:' line with each fragment."""
    argv, rc, out = outcome
    lines = out.strip().splitlines()
    assert rc == 1 and len(lines) == 1, (argv, out)
    assert 'Traceback' not in out and '[rcl]' not in out
    assert 'cannot start: ' in lines[0], lines[0]
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
