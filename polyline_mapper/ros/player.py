"""
``polyline-mapper play``: publish a recording on live topics with its timing.

Like ``ros2 bag play --clock``.

Each message of a ``recordings.Recording`` is published when its receive time comes, the
recording's time running at ``rate`` x wall time, on the topic it was recorded on:
sensor_msgs/LaserScan, nav_msgs/Odometry, geometry_msgs/PoseWithCovarianceStamped (pose estimates
on /initialpose, reliable) and tf2_msgs/TFMessage on /tf, with /tf_static
published as tf2's static broadcaster does (transient local, every static transform seen so far
in one message, so a late joiner gets them all). rosgraph_msgs/Clock on /clock carries the
recording's time (``clock_hz`` ticks a second between messages, and one just before each
message), so nodes with ``use_sim_time:=true`` run on the recording's clock.

``loop``: after the end, start again with every stamp (headers and /clock) shifted by the
recording's length plus one scan period, so time never runs backwards (tf2 buffers discard
their content when it does). Messages keep their recorded header stamps otherwise.
"""

from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
import math
import signal
import threading
import time
from typing import Callable, Optional

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from . import startup
from .messages import odometry_msg, pose_msg, scan_msg, time_msg, transform_msg
from .qos import TF_QOS
from ..formats.records import Odometry, PoseEstimate, Scan, Skipped

STREAM_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
"""Scans and odometry: reliable (reaches best-effort sensor-data subscribers too), depth 10."""
STATIC_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""/tf_static as tf2_ros.StaticTransformBroadcaster offers it."""
CLOCK_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
ACK_TIMEOUT = 5.0
"""Longest wait (s) at the end of a play for reliable subscribers to acknowledge."""


@dataclass
class PlayStats:
    """What a play published."""

    published: Counter = field(default_factory=Counter)
    """Messages per topic."""
    skipped: Counter = field(default_factory=Counter)
    """Undecodable messages per topic (not published)."""
    passes: int = 0
    scans: int = 0
    wall_seconds: float = 0.0
    recording_seconds: float = 0.0
    """Recording time covered (all passes), seconds."""
    max_late_ms: float = 0.0
    """Largest delay of a message behind its due time, milliseconds."""
    last_scan_stamp: Optional[float] = None
    """Header stamp of the last scan published (shift of its pass included), seconds."""
    interrupted: bool = False
    stop_signal: Optional[int] = None
    """The signal (SIGINT, SIGTERM) that stopped playing, if one did."""

    def summary(self) -> str:
        """One line for a person."""
        topics = ', '.join(f'{n} {t}' for t, n in sorted(self.published.items()))
        skipped = sum(self.skipped.values())
        return (f'played {self.scans} scans in {self.passes} pass(es): {topics or "nothing"}; '
                f'{self.recording_seconds:.1f} s of recording in {self.wall_seconds:.1f} s, '
                f'largest delay {self.max_late_ms:.1f} ms'
                + (f'; {skipped} undecodable message(s) not played' if skipped else '')
                + (' (interrupted)' if self.interrupted else ''))


class Player:
    """
    Publish timed records on ``node``: call ``play(messages_factory)``.

    ``messages_factory()`` returns an iterator of (log_time, topic, record), as
    ``recordings.Recording.messages``. ``stop`` (a threading.Event, for other threads) or
    ``request_stop`` (safe in a signal handler, see ``stop_on_signals``) ends playing early.
    """

    POLL = 0.05
    """Longest sleep (s) between two looks at the stop request."""

    def __init__(self, node, rate: float = 1.0, loop: bool = False, clock: bool = True,
                 clock_hz: float = 40.0, stop: threading.Event = None,
                 on_message: Callable = None):
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f'rate must be a positive number, got {rate!r}')
        if not (math.isfinite(clock_hz) and clock_hz > 0):
            raise ValueError(f'clock rate must be a positive number (Hz), got {clock_hz!r}')
        self.node = node
        self.rate = float(rate)
        self.loop = bool(loop)
        self.clock_period = 1.0 / clock_hz
        self.stop = stop or threading.Event()
        self.stop_signal = None
        self.on_message = on_message
        self._pubs = {}
        self._statics = {}
        self._clock_pub = None
        if clock:
            from rosgraph_msgs.msg import Clock
            self._clock_pub = node.create_publisher(Clock, '/clock', CLOCK_QOS)
            self._clock_type = Clock
        self.stats = PlayStats()

    # -- stopping -------------------------------------------------------------------------------
    def request_stop(self, signum: int = None) -> None:
        """Stop at the next look (within ``POLL`` s); only sets an attribute, takes no lock."""
        self.stop_signal = signal.SIGINT if signum is None else signum

    @property
    def stopped(self) -> bool:
        """Whether a stop was requested (``stop`` set or ``request_stop`` called)."""
        return self.stop_signal is not None or self.stop.is_set()

    def _sleep(self, seconds: float) -> bool:
        """Sleep ``seconds`` unless stopped meanwhile; return whether still running."""
        end = time.monotonic() + seconds
        while not self.stopped:
            left = end - time.monotonic()
            if left <= 0:
                return True
            time.sleep(min(left, self.POLL))
        return False

    # -- publishers -----------------------------------------------------------------------------
    def publisher(self, topic: str, record):
        """
        Return the publisher for ``topic`` (created on first use, typed by the record).

        ``record``: a record or its class (Scan, Odometry, PoseEstimate; else transforms).
        """
        kind = record if isinstance(record, type) else type(record)
        if topic not in self._pubs:
            if kind is Scan:
                from sensor_msgs.msg import LaserScan
                self._pubs[topic] = self.node.create_publisher(LaserScan, topic, STREAM_QOS)
            elif kind is Odometry:
                from nav_msgs.msg import Odometry as OdometryMsg
                self._pubs[topic] = self.node.create_publisher(OdometryMsg, topic, STREAM_QOS)
            elif kind is PoseEstimate:                  # reliable, as RViz publishes it
                from geometry_msgs.msg import PoseWithCovarianceStamped
                self._pubs[topic] = self.node.create_publisher(PoseWithCovarianceStamped,
                                                               topic, 10)
            else:
                from tf2_msgs.msg import TFMessage
                static = topic == '/tf_static'
                self._pubs[topic] = self.node.create_publisher(
                    TFMessage, topic, STATIC_QOS if static else TF_QOS)
        return self._pubs[topic]

    def wait_for_subscriber(self, topic: str, record, timeout: float,
                            settle: float = 0.5) -> bool:
        """
        Wait up to ``timeout`` s until ``topic`` has a subscriber; return whether it has.

        Then wait ``settle`` s more: DDS discovery is two-sided, the publisher can see the
        subscription before the subscriber has matched the publisher, and a best-effort
        subscriber (sensor-data QoS, as the node's scan input by default) drops what an
        unmatched writer sends. A reliable subscriber gets every sample written after this
        publisher matched it; best effort may still drop samples later on.
        """
        pub = self.publisher(topic, record)
        deadline = time.monotonic() + timeout
        while pub.get_subscription_count() == 0:
            if time.monotonic() >= deadline or self.stopped:
                return False
            time.sleep(0.02)
        return self._sleep(settle)

    def _publish(self, topic: str, record, shift: float) -> None:
        pub = self.publisher(topic, record)
        if isinstance(record, Scan):
            pub.publish(scan_msg(record, record.stamp + shift))
            self.stats.scans += 1
            self.stats.last_scan_stamp = record.stamp + shift
        elif isinstance(record, Odometry):
            pub.publish(odometry_msg(record, record.stamp + shift))
        elif isinstance(record, PoseEstimate):
            pub.publish(pose_msg(record.frame_id, time_msg(record.stamp + shift), record.pose,
                                 record.covariance))
        elif topic == '/tf_static' or all(t.static for t in record):
            fresh = {t.child: t for t in record}
            if all(self._statics.get(c) is not None and _same(self._statics[c], t)
                   for c, t in fresh.items()):
                return                      # a later pass: nothing new to latch
            self._statics.update(fresh)
            from tf2_msgs.msg import TFMessage
            pub.publish(TFMessage(transforms=[transform_msg(t) for t in self._statics.values()]))
        else:
            from tf2_msgs.msg import TFMessage
            pub.publish(TFMessage(transforms=[transform_msg(t, t.stamp + shift)
                                              for t in record]))
        self.stats.published[pub.topic_name] += 1     # (after --ros-args -r remapping)

    def wait_for_acks(self, timeout: float) -> list:
        """
        Wait up to ``timeout`` s in all for reliable subscribers to acknowledge every message.

        Return the topics whose messages are not all acknowledged by then. Destroying a writer
        drops what it has not delivered yet, so without this the last messages of a play can
        miss a reliable subscriber (what ``ros2 bag play --wait-for-all-acked`` guards against).
        """
        from rclpy.duration import Duration
        deadline = time.monotonic() + timeout
        late = []
        for topic, pub in list(self._pubs.items()):
            left = max(0.0, deadline - time.monotonic())
            if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                late.append(topic)
        return late

    def _clock(self, t: float) -> None:
        if self._clock_pub is not None and t >= 0:
            self._clock_pub.publish(self._clock_type(clock=time_msg(t)))

    # -- playing --------------------------------------------------------------------------------
    def play(self, messages) -> PlayStats:
        """Publish every message of ``messages()`` on time (all passes with ``loop``)."""
        st = self.stats
        t_origin = wall_origin = None
        shift = 0.0
        wall_start = time.monotonic()
        while not self.stopped:
            first = last = None
            scans_before = st.scans
            for log_t, topic, record in messages():
                if isinstance(record, Skipped):
                    st.skipped[record.topic] += 1
                    continue
                v = log_t + shift               # the (shifted) recording time of the message
                if t_origin is None:
                    t_origin, wall_origin = v, time.monotonic()
                first = log_t if first is None else first
                last = log_t
                due = wall_origin + (v - t_origin) / self.rate
                if not self._wait_until(due, t_origin, wall_origin):
                    break
                self._clock(v)
                self._publish(topic, record, shift)
                st.recording_seconds = v - t_origin
                st.max_late_ms = max(st.max_late_ms, 1e3 * (time.monotonic() - due))
                if self.on_message is not None:
                    self.on_message(topic, record)
            if self.stopped:
                break
            st.passes += 1
            scans = st.scans - scans_before
            if first is None or not self.loop:
                break
            # Next pass: shift by the length plus one mean scan period, time keeps increasing.
            span = last - first
            shift += span + (span / (scans - 1) if scans > 1 else 1.0)
        st.wall_seconds = time.monotonic() - wall_start
        st.interrupted = self.stopped
        st.stop_signal = self.stop_signal
        return st

    def _wait_until(self, due: float, t_origin: float, wall_origin: float) -> bool:
        """Sleep until ``due`` (monotonic), ticking /clock; False when stopped meanwhile."""
        while True:
            now = time.monotonic()
            if now >= due:
                return True
            if not self._sleep(min(due - now, self.clock_period)):
                return False
            if self._clock_pub is not None and time.monotonic() < due:
                self._clock(t_origin + (time.monotonic() - wall_origin) * self.rate)


def _same(a, b) -> bool:
    """Return whether two Transform records carry the same frames and numbers."""
    return (a.parent == b.parent and a.child == b.child
            and list(a.translation) == list(b.translation)
            and list(a.rotation) == list(b.rotation))


@contextmanager
def stop_on_signals(request_stop: Callable[[int], None]):
    """
    Inside, SIGINT and SIGTERM call ``request_stop(signum)`` instead of raising at once.

    A player stops at its next look at the request (``Player.POLL``), never in the middle of a
    publish, a DDS call or a thread start, so it always ends with its summary and a clean
    shutdown; a second signal raises KeyboardInterrupt for whatever is stuck. A SIGINT the
    process inherited as ignored (a background job of a non-interactive shell) stays ignored,
    as POSIX intends. Outside the main thread (where signals cannot be set) nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    calls = []

    def handler(signum, frame):
        calls.append(signum)
        if len(calls) > 1:
            raise KeyboardInterrupt
        request_stop(signum)

    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        prev = signal.getsignal(sig)
        if sig == signal.SIGINT and prev == signal.SIG_IGN:
            continue
        old[sig] = signal.SIG_DFL if prev is None else prev
        signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, prev in old.items():
            signal.signal(sig, prev)


def run_play(path: str, rate: float = 1.0, loop: bool = False, clock: bool = True,
             clock_hz: float = 40.0, scan_topic: str = None, odom_topic: str = None,
             wait_for_subscriber: float = 0.0, progress: bool = False, seed: int = 1,
             noise: float = 0.01, period: float = 1.0, ros_args=None,
             log: Callable[[str], None] = print) -> PlayStats:
    """
    Play ``path`` (bag, CARMEN log or ``sim:`` drive) on live topics until done or stopped.

    Runs its own rclpy context and node ``polyline_mapper_player``. ``wait_for_subscriber``:
    seconds to wait, before starting, for a subscriber on the scan topic (0: start at once).
    SIGINT (Ctrl-C) or SIGTERM stop it (``stop_on_signals``); the stats say which
    (``interrupted``, ``stop_signal``). ValueError (one line) for a bad input or option.
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from ..recordings import open_recording
    with open_recording(path, scan_topic, odom_topic, period=period, seed=seed,
                        noise=noise) as rec:
        for w in rec.warnings:
            log(f'warning: {w}')
        context = rclpy.Context()
        # bad --ros-args or ROS_DOMAIN_ID: a StartupError (a ValueError), one line
        startup.init(ros_args, context=context,
                     signal_handler_options=SignalHandlerOptions.NO)  # ours: stop_on_signals
        node = rclpy.create_node('polyline_mapper_player', context=context)
        bar = None
        try:
            player = Player(node, rate, loop, clock, clock_hz)
            if rec.estimate_topic is not None:  # discovered before the one-off estimates come
                player.publisher(rec.estimate_topic, PoseEstimate)
            with stop_on_signals(player.request_stop):
                if wait_for_subscriber > 0:
                    first_scan = first_scan_of(rec)
                    if (first_scan is not None and not player.wait_for_subscriber(
                            first_scan[0], first_scan[1], wait_for_subscriber)
                            and not player.stopped):
                        name = player.publisher(*first_scan).topic_name     # remapped
                        log(f'warning: no subscriber on {name} after '
                            f'{wait_for_subscriber:g} s; playing anyway')
                if progress:
                    import sys
                    from tqdm import tqdm
                    bar = tqdm(total=None if loop else rec.scan_count, desc='play',
                               unit='scan', leave=False, disable=None, file=sys.stderr)
                    player.on_message = lambda topic, r: bar.update(1) \
                        if isinstance(r, Scan) else None
                stats = player.play(rec.messages)
                late = player.wait_for_acks(ACK_TIMEOUT)
                if late:
                    log('warning: not every subscriber acknowledged the last messages on '
                        f"{', '.join(late)} within {ACK_TIMEOUT:g} s")
                return stats
        finally:
            if bar is not None:
                bar.close()
            node.destroy_node()
            rclpy.try_shutdown(context=context)


def first_scan_of(rec) -> Optional[tuple]:
    """(topic, record) of the recording's first scan, or None."""
    messages = rec.messages()
    try:
        for _, topic, record in messages:
            if isinstance(record, Scan):
                return topic, record
        return None
    finally:
        close = getattr(messages, 'close', None)
        if close is not None:
            close()
