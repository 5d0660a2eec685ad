"""The node under more load than it can map: it sheds scans and keeps publishing."""

import time

import numpy as np
from polyline_mapper.formats.records import Scan, Transform
from polyline_mapper.poses import quaternion_from_yaw
import pytest
from rosnode import NodeProcess, Peer

pytest.importorskip('tf2_msgs.msg', reason='tf2_msgs is not built (run tools/dev.sh setup)')
pytestmark = [pytest.mark.slow, pytest.mark.dds]
BEAMS = 100_000
RATE = 33.0                  # Hz
SECONDS = 6.0


def room_scan(beams: int, rng) -> np.ndarray:
    """Ranges (float32) of a full-circle laser at (1, 0.5) in a 10 m x 6 m room, 1 cm noise."""
    a = np.linspace(-np.pi, np.pi, beams, endpoint=False)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide='ignore'):
        tx = np.where(c > 0, (5.0 - 1.0) / c, (-5.0 - 1.0) / c)
        ty = np.where(s > 0, (3.0 - 0.5) / s, (-3.0 - 0.5) / s)
    r = np.minimum(np.abs(tx), np.abs(ty)) + rng.normal(0.0, 0.01, beams)
    return r.astype(np.float32)


def test_slow_updates_shed_scans_and_the_map_and_diagnostics_keep_coming(tmp_path):
    # 100k-beam scans at 33 Hz: each update takes far longer than the 30 ms between scans.
    # Before the one-update-per-step worker, the node ran every queued update before it
    # published: map and /diagnostics stopped for seconds and latency grew to 11.7 s.
    from diagnostic_msgs.msg import DiagnosticArray
    from polyline_mapper.ros.messages import scan_msg, transform_msg
    node = NodeProcess(tmp_path, {'diagnostics_period': 0.5, 'map_publish_period': 0.2,
                                  'stats_period': 0.0, 'warning_period': 1.0,
                                  'incremental.noise_updates': 1})
    peer = Peer('load_peer')
    diag = []
    peer.node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: diag.append((time.monotonic(), {kv.key: kv.value for s in m.status
                                                  for kv in s.values})), 10)
    try:
        assert peer.wait_for_node(60.0), node.stderr()
        peer.static_pub.publish(peer.TFMessage(transforms=[transform_msg(Transform(
            0.0, 'map', 'laser', np.array([1.0, 0.5, 0.0]), quaternion_from_yaw(0.0),
            True))]))
        rng = np.random.default_rng(0)
        scans = [room_scan(BEAMS, rng) for _ in range(4)]
        t0, start = time.time(), time.monotonic()
        k = 0
        while time.monotonic() - start < SECONDS:
            rec = Scan(t0 + k / RATE, 'laser', -np.pi, 2 * np.pi / BEAMS, 0.05, 30.0,
                       scans[k % 4])
            peer.scan_pub.publish(scan_msg(rec))
            k += 1
            peer.spin_for(max(0.0, start + k / RATE - time.monotonic()))
        end = time.monotonic()
        peer.spin_for(2.0)
    finally:
        peer.close()
        assert node.stop() == 0
    during = [t for t, _ in diag if start + 1.0 <= t <= end]
    gaps = np.diff(during)
    assert len(during) >= 4 and gaps.max() < 2.0, (len(during), gaps)
    last = diag[-1][1]
    received, used = int(last['scans_received']), int(last['scans_used'])
    dropped = int(last['scans_dropped'])
    assert received > 100 and used < received and dropped > 0, last
    # Latency is bounded by max_scan_latency (1 s) plus one update, not by the backlog.
    assert float(last['latency_ms_p99']) < 2500.0, last
    summary = node.lines('summary:')[-1]
    assert 'dropped' in summary
