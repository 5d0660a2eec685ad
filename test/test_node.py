"""The real node over DDS: a simulated drive in, the office's walls out, bad input survived."""

from dataclasses import replace
import json
import re
import signal
import time

import numpy as np
from polyline_mapper.formats.mapjson import read_map
from polyline_mapper.recordings import drive_messages
from polyline_mapper.ros.messages import scan_msg
import pytest
from rosnode import (map_segments, NodeProcess, Peer, RELIABLE_DEPTH, scans_of, stamp_of,
                     wall_errors)
from std_srvs.srv import Trigger

pytest.importorskip('tf2_msgs.msg', reason='tf2_msgs is not built (run tools/dev.sh setup)')
pytestmark = [pytest.mark.slow, pytest.mark.dds]
RATE = 40.0                  # Hz, scans published
TIMEOUT = 60.0               # s, for anything that should take a few seconds
CAUSES = ('no_valid_ranges', 'empty_scan', 'intensities', 'angle_increment', 'range_limits',
          'unknown_frame', 'too_old')


@pytest.fixture(scope='module')
def tf_run(office_drive, tmp_path_factory):
    """Run the node in tf mode, fed the office drive through map -> odom -> base_link -> laser."""
    folder = tmp_path_factory.mktemp('node_tf')
    node = NodeProcess(folder, {
        'map_output_path': str(folder / 'out' / 'map.json'), 'map_publish_period': 0.1,
        'warning_period': 300.0, 'stats_period': 1.0, 'transform_timeout': 0.3,
        'marker_width': 0.03,
        # No load shedding: the drive must raise no warning, and on a loaded machine updates
        # can fall behind 40 Hz for a second, when the default max_scan_latency (1 s) drops a
        # scan with a warning, as designed (test_node_load covers that; here, with two
        # busy-loop processes beside the test: one scan dropped too_late).
        'max_scan_latency': 0.0, 'scan_buffer_size': 400,
        # Reliable transport: with sensor-data QoS a loaded machine loses scans (the shutdown
        # test below received 221, 106 and fewer of 230 in CI runs), and a map of part of the
        # drive misses walls the checks below expect. The default QoS is checked on a node
        # started with the shipped parameters (test_node_modes).
        'qos_overrides./scan.subscription.reliability': 'reliable',
        'qos_overrides./scan.subscription.depth': RELIABLE_DEPTH})
    peer = Peer('test_peer_tf', reliable_scans=True)
    try:
        assert peer.wait_for_node(TIMEOUT, node=node), 'the node did not come up:\n' + \
            node.stderr()
        msgs = list(drive_messages(office_drive, mount=(0.2, -0.05, 0.3),
                                   map_to_odom=(1.0, -2.0, 0.4)))
        last = peer.play(msgs, RATE)
        got = peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            last, abs=1e-6) and len(peer.maps[-1].segments) > 0, TIMEOUT)
        assert got, 'no map with the last scan stamp arrived:\n' + node.stderr()[-3000:]
        peer.spin_until(lambda: peer.markers and stamp_of(peer.markers[-1].markers[0])
                        == pytest.approx(last, abs=1e-6), TIMEOUT)
        yield node, peer, msgs, last, folder
    finally:
        peer.close()
        node.stop()


def test_without_scan_matching_initialpose_is_left_to_the_robot_s_localizer(tf_run):
    # A robot with its own localizer (AMCL) takes pose estimates on initialpose; this node,
    # mapping at the TF poses, does not subscribe (it would take them as its own).
    _, peer, _, _, _ = tf_run
    assert peer.node.count_subscribers('/scan') == 1         # discovery has seen the node
    assert peer.node.count_subscribers('/initialpose') == 0


def test_map_of_the_drive_matches_the_walls(tf_run, office_drive):
    node, peer, _, last, _ = tf_run
    msg = peer.maps[-1]
    assert msg.header.frame_id == 'map'
    segs = map_segments(msg)
    stray, worst = wall_errors(segs, office_drive)
    assert stray <= 0.15, f'a segment strays {stray:.3f} m from every wall'
    assert worst <= 0.15, f'a wall is recovered only to {worst:.3f} m at its ends'
    assert 15 <= len(segs) <= 60
    assert all(s.support > 0 for s in msg.segments)
    # Polylines chain the segments: their vertices are segment ends.
    ends = segs.reshape(-1, 2)
    for poly in msg.polylines:
        assert len(poly.points) >= 2
        v = np.array([[p.x, p.y] for p in poly.points])
        assert np.min(np.linalg.norm(ends[None] - v[:, None], axis=2), axis=1).max() < 1e-9


def test_the_drive_raised_no_warning_and_stats_were_logged(tf_run):
    node, peer, msgs, _, _ = tf_run
    # Throttled stats lines report map size and update times while mapping.
    assert node.lines(': map ') and node.lines('update median')
    # The drive's end, the scans stopping, is warned of once (since 2026-11-30); nothing else.
    stopped = node.lines('[scans_stopped]')
    assert len(stopped) <= 1 and all('received before' in ln for ln in stopped)
    assert not [ln for ln in node.lines('WARN') if ln not in stopped], node.stderr()[-2000:]


def test_markers_are_line_strips_after_a_deleteall(tf_run):
    from visualization_msgs.msg import Marker
    _, peer, _, last, _ = tf_run
    arr = peer.markers[-1].markers
    assert arr[0].action == Marker.DELETEALL
    strips = arr[1:]
    assert len(strips) == len(peer.maps[-1].polylines)
    assert {m.ns for m in strips} == {'polyline_map'}
    assert len({m.id for m in strips}) == len(strips)
    for m, poly in zip(strips, peer.maps[-1].polylines):
        assert m.type == Marker.LINE_STRIP and m.header.frame_id == 'map'
        assert stamp_of(m) == pytest.approx(last, abs=1e-6)
        assert m.scale.x == pytest.approx(0.03) and m.color.a > 0
        assert len(m.points) == len(poly.points) + (1 if poly.closed else 0)


def test_a_late_subscriber_gets_the_map_at_once(tf_run):
    _, peer, _, _, _ = tf_run
    late = Peer('test_peer_late')
    try:
        assert late.spin_until(lambda: late.maps and late.markers, 20.0)
        assert np.array_equal(map_segments(late.maps[-1]), map_segments(peer.maps[-1]))
        assert len(late.markers[-1].markers) == len(peer.markers[-1].markers)
    finally:
        late.close()


def test_save_map_writes_the_map_json(tf_run):
    _, peer, _, _, folder = tf_run
    resp = peer.call('/polyline_mapper_node/save_map', Trigger)
    assert resp is not None and resp.success, resp
    path = folder / 'out' / 'map.json'
    k = len(peer.maps[-1].segments)
    assert str(path) in resp.message and f'{k} segments' in resp.message
    data = json.loads(path.read_text())
    assert data['frame_id'] == 'map' and len(data['segments']) == k
    assert np.allclose(np.array(data['segments']).reshape(-1, 2, 2),
                       map_segments(peer.maps[-1]), atol=1e-4)
    assert len(data['polylines']) == len(data['closed']) == len(peer.maps[-1].polylines)
    assert data['config']['buffer_scans'] == 3 and 'kappa' in data['config']


def test_save_map_to_an_unwritable_path_fails_with_a_reason(tf_run):
    _, peer, _, _, folder = tf_run
    blocker = folder / 'blocker'
    blocker.write_text('a file, not a folder')
    assert all(r.successful for r in peer.set_parameters(map_output_path=str(blocker / 'm.json')))
    resp = peer.call('/polyline_mapper_node/save_map', Trigger)
    assert resp is not None and not resp.success
    assert str(blocker / 'm.json') in resp.message and 'cannot write' in resp.message
    assert all(r.successful for r in peer.set_parameters(
        map_output_path=str(folder / 'out' / 'map.json')))


def bad_scans(msgs, last):
    """Return scans bad in one way each, three of each, stamped within the stored transforms."""
    out = []
    scan = scans_of(msgs)[-1]
    for k in range(3):
        stamp = last - 0.5 + 0.01 * k
        m = scan_msg(scan, stamp)
        m.ranges = np.full(len(m.ranges), np.nan, dtype=np.float32)
        out.append(m)
        m = scan_msg(scan, stamp)
        m.ranges = np.full(len(m.ranges), np.inf, dtype=np.float32)
        out.append(m)
        m = scan_msg(scan, stamp)
        m.ranges = np.zeros(0, dtype=np.float32)
        out.append(m)
        m = scan_msg(scan, stamp)
        m.intensities = np.ones(len(m.ranges) - 10, dtype=np.float32)
        out.append(m)
        m = scan_msg(scan, stamp)
        m.angle_increment = 0.0
        out.append(m)
        m = scan_msg(scan, stamp)
        m.range_min, m.range_max = 5.0, 1.0
        out.append(m)
        out.append(scan_msg(replace(scan, frame_id='no_such_laser'), stamp))
        out.append(scan_msg(scan, stamp - 1000.0))            # long before any transform kept
    return out


def test_bad_scans_leave_the_map_alone_with_one_warning_per_cause(tf_run):
    node, peer, msgs, last, _ = tf_run
    before = map_segments(peer.maps[-1])
    count = len(peer.maps)
    for m in bad_scans(msgs, last):
        peer.scan_pub.publish(m)
        peer.spin_for(0.01)
    for cause in CAUSES:
        assert node.wait_for_line(f'[{cause}]', 20.0), f'no warning [{cause}]:\n' + \
            node.stderr()[-3000:]
    assert node.proc.poll() is None, 'the node died'
    # Still serving: a service answers and a late subscriber gets the unchanged map.
    assert peer.call('/polyline_mapper_node/save_map', Trigger).success
    late = Peer('test_peer_after_bad')
    try:
        assert late.spin_until(lambda: late.maps, 20.0)
        assert np.array_equal(map_segments(late.maps[-1]), before)
    finally:
        late.close()
    assert len(peer.maps) == count, 'bad scans caused a new map'
    for cause in CAUSES:
        assert len(node.lines(f'[{cause}]')) == 1, node.lines(f'[{cause}]')


def test_runtime_parameters_apply_or_are_refused_with_a_reason(tf_run):
    _, peer, _, _, _ = tf_run
    n = len(peer.markers)
    res = peer.set_parameters(marker_width=0.2, marker_color=[1.0, 0.0, 0.0, 1.0])
    assert [r.successful for r in res] == [True, True]
    # Both apply (one by one) and the markers are republished in the new style.
    assert peer.spin_until(lambda: len(peer.markers) > n
                           and peer.markers[-1].markers[-1].scale.x == pytest.approx(0.2)
                           and peer.markers[-1].markers[-1].color.r == 1.0, 10.0)
    # Parameters rclpy declares itself are not ours to refuse.
    assert all(r.successful for r in peer.set_parameters(use_sim_time=False))
    # Markers switched off: one DELETEALL clears what RViz shows.
    assert all(r.successful for r in peer.set_parameters(publish_markers=False))
    assert peer.spin_until(lambda: len(peer.markers[-1].markers) == 1, 10.0)
    assert all(r.successful for r in peer.set_parameters(publish_markers=True))
    assert peer.spin_until(lambda: len(peer.markers[-1].markers) > 1, 10.0)
    for values, reason in (({'marker_color': [1.0, 0.0]}, 'marker_color'),
                           ({'update_every_n_scans': 500}, 'scan_buffer_size'),   # > 400
                           ({'transform_tolerance': -1.0}, 'out of range'),
                           ({'smemsf__kappa': 5.0}, 'read-only'),
                           ({'fixed_frame': 'odom'}, 'read-only')):
        res = peer.set_parameters(**values)
        assert len(res) == 1 and not res[0].successful, values
        assert reason in res[0].reason, (values, res[0].reason)


def test_reset_empties_the_map_and_its_markers(tf_run):
    from visualization_msgs.msg import Marker
    _, peer, _, _, _ = tf_run
    resp = peer.call('/polyline_mapper_node/reset', Trigger)
    assert resp is not None and resp.success and 'cleared' in resp.message
    assert peer.spin_until(lambda: len(peer.maps[-1].segments) == 0
                           and len(peer.markers[-1].markers) == 1, 10.0)
    assert peer.maps[-1].polylines == [] and peer.maps[-1].header.frame_id == 'map'
    assert peer.markers[-1].markers[0].action == Marker.DELETEALL


def test_save_map_on_shutdown_writes_the_map_with_the_queued_scans(office_drive, tmp_path):
    # A group of 8 scans: the last scans that came wait for theirs when SIGINT comes; they are
    # mapped before the map is written.
    # Reliable transport (as `polyline-mapper play` publishes): with sensor-data QoS a loaded
    # machine lost scans (221, 106 of 230 came in CI runs), and a map of half the drive then
    # missed 8.3 m of a wall the reference saw (CI at 4a02332); now every scan must come.
    out = tmp_path / 'saved' / 'map.json'
    node = NodeProcess(tmp_path, {'map_output_path': str(out), 'save_map_on_shutdown': True,
                                  'update_every_n_scans': 8, 'scan_buffer_size': 400,
                                  'max_scan_latency': 0.0,
                                  'qos_overrides./scan.subscription.reliability': 'reliable',
                                  'qos_overrides./scan.subscription.depth': RELIABLE_DEPTH},
                       # named: the module's node (tf_run) still runs in this ROS domain, and
                       # its reader alone met the peer's counts once (107 scans lost)
                       ros_name='polyline_mapper_save')
    peer = Peer('test_peer_save', reliable_scans=True)
    try:
        assert peer.wait_for_node(TIMEOUT, node=node), 'the node did not come up:\n' + \
            node.stderr()
        msgs = list(drive_messages(office_drive, mount=(0.2, -0.05, 0.3),
                                   map_to_odom=(1.0, -2.0, 0.4)))
        scans = sum(topic == '/scan' for _, topic, _ in msgs)
        assert scans % 8 != 0
        last = peer.play(msgs, RATE)
        # A map at least as new as the last full group of 8: the node has taken the scans up
        # to it, and the few sent after it are queued behind (reliable and in order). A loaded
        # node is seconds behind the player: a signal sent before then found scans not yet
        # taken (192 and 110 of 230 with three busy loops beside the test). (A node that fell
        # behind maps every scan queued in one update: in CI all 230 in 25 updates, so the
        # map's stamp may pass that group's.)
        full = last - (scans % 8) / RATE
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) >= full - 1e-6,
                               TIMEOUT), node.stderr()[-3000:]
        peer.spin_for(0.5)
        published = stamp_of(peer.maps[-1])
        assert not out.exists()
        # Ctrl-C and, right after, the SIGTERM that ros2 launch sends when a node is slow to stop
        # (or a second Ctrl-C): the second signal raised KeyboardInterrupt inside the shutdown's
        # flush, printed a traceback, and the map was not written. It is ignored, once said.
        node.proc.send_signal(signal.SIGINT)
        time.sleep(0.02)                    # (at once, the two signals may come as one)
        node.proc.send_signal(signal.SIGTERM)
        assert node.proc.wait(TIMEOUT) == 0, node.stderr()[-3000:]
    finally:
        peer.close()
        node.stop()
    assert 'Traceback' not in node.stderr(), node.stderr()[-3000:]
    assert node.lines('while shutting down: ignored'), node.stderr()[-3000:]
    saved = read_map(out)
    assert len(saved.value.segments) > 10
    # every scan sent came and was mapped, the last partial group by the flush at shutdown (so
    # the saved map holds the last scan, newer than any map published before the signal)
    assert published - 1e-6 <= saved.value.stamp
    assert saved.value.stamp == pytest.approx(last, abs=1e-6)
    summary = node.lines('summary: ')
    assert summary, node.stderr()[-3000:]
    counts = re.search(r'summary: (\d+) scans received, (\d+) used', summary[-1])
    # (the node's log with it: which inputs matched when, what was skipped; once in a loaded
    # run, 2026-11-30, 139 of 230 scans came over reliable transport, cause unknown)
    assert int(counts[2]) == int(counts[1]) == scans, (summary, node.stderr()[-6000:])
    assert node.lines(f'wrote {out}: {len(saved.value.segments)} segments')
    # the summary counts the map as written (it counted the mapper's segments before polylines()
    # joined them: 25 against 24 on the office drive)
    assert summary[-1].endswith(f'; map {len(saved.value.segments)} segments'), summary
    assert max(wall_errors(saved.value.segments, office_drive)) <= 0.15


@pytest.mark.parametrize('params, reason', [
    ({'smemsf.kappa': -1.0}, 'smemsf.kappa'),
    ({'pose_source': 'gps'}, 'pose_source must be one of tf, odom'),
    ({'update_every_n_scans': 80}, 'scan_buffer_size'),
    ({'smemsf.shrink_fast': 0.9}, 'shrink_fast'),
    ({'incremental.buffer_scans': 'three'}, 'incremental.buffer_scans'),
])
def test_bad_parameters_at_start_exit_1_with_one_line(tmp_path, params, reason):
    node = NodeProcess(tmp_path, params)
    try:
        rc = node.proc.wait(TIMEOUT)
    finally:
        node.stop()
    lines = node.stderr().strip().splitlines()
    assert rc == 1 and len(lines) == 1, lines
    assert 'cannot start' in lines[0] and reason in lines[0]
    assert 'Traceback' not in node.stderr()
