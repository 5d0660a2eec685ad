"""The real node over DDS in odom mode, and with no transforms at all (after test_node.py)."""

import json
import math
import re
import signal
import subprocess
import sys

from conftest import REPO
from polyline_mapper.recordings import drive_messages
from polyline_mapper.ros.messages import scan_msg
import pytest
from rosnode import (map_segments, NodeProcess, Peer, RELIABLE_DEPTH, scans_of, stamp_of,
                     wall_errors)
from std_srvs.srv import Trigger

pytest.importorskip('tf2_msgs.msg', reason='tf2_msgs is not built (run tools/dev.sh setup)')
pytestmark = [pytest.mark.slow, pytest.mark.dds]
RATE = 40.0
TIMEOUT = 60.0


def test_odom_mode_with_an_upside_down_laser(office_drive, tmp_path):
    node = NodeProcess(tmp_path, {
        'pose_source': 'odom', 'fixed_frame': 'odom', 'laser_x': 0.15, 'laser_y': 0.05,
        'laser_yaw': math.pi / 2, 'laser_upside_down': True, 'map_publish_period': 0.0,
        'stats_period': 0.0,
        # Lossless transport, so that every scan sent must be used: with the default best-effort
        # depth-5 input, a slow machine loses scans while an update stalls (seen in CI: 225 of
        # 230 received, update p95 18 ms, latency p99 115 ms). The odometry too: this drive
        # steps 0.4 m and turns corners from one message to the next, so a scan whose odometry
        # was lost got a pose interpolated across the corner (seen in CI: a wall 0.84 m off;
        # since odom_gap_factor such a scan is skipped, test_odom_gaps.py, and here every scan
        # must be used). And no shedding in the
        # node: on a loaded machine updates fall behind 40 Hz for a while, and the default
        # max_scan_latency (1 s) then drops scans as designed (seen in CI: one scan dropped
        # too_late). test_node_load covers the shedding; here every scan must be mapped.
        'max_scan_latency': 0.0, 'scan_buffer_size': 1000,
        'qos_overrides./scan.subscription.reliability': 'reliable',
        'qos_overrides./scan.subscription.depth': RELIABLE_DEPTH,
        'qos_overrides./odom.subscription.reliability': 'reliable',
        'qos_overrides./odom.subscription.depth': 50})
    peer = Peer('test_peer_odom', reliable_scans=True)
    try:
        assert peer.wait_for_node(TIMEOUT, odom=True, node=node), node.stderr()
        for topic, depth in (('/scan', RELIABLE_DEPTH), ('/odom', 50)):   # the overrides took
            for policy, value in (('reliability', 'reliable'), ('depth', depth)):
                name = f'qos_overrides.{topic}.subscription.{policy}'
                assert peer.parameter(name) == value, name
        msgs = list(drive_messages(office_drive, mount=(0.15, 0.05, math.pi / 2),
                                   upside_down=True, map_to_odom=(0.0, 0.0, 0.0)))
        last = peer.play(msgs, RATE, mode='odom')
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            last, abs=1e-6), TIMEOUT), node.stderr()[-3000:]
        msg = peer.maps[-1]
        assert msg.header.frame_id == 'odom'
        stray, worst = wall_errors(map_segments(msg), office_drive)
        assert stray <= 0.15 and worst <= 0.15, (stray, worst)
        # (the drive's end may be warned of by now: scans_stopped, test_node.py)
        assert not [ln for ln in node.lines('WARN') if '[scans_stopped]' not in ln], \
            node.stderr()[-2000:]
    finally:
        peer.close()
        assert node.stop() == 0
    # Every scan and odometry message sent arrived, and every scan was used.
    summary = node.lines('summary:')
    got = re.search(r'(\d+) scans received, (\d+) used', summary[0])
    scans = len(scans_of(msgs))
    assert int(got[1]) == int(got[2]) == scans, summary
    odometry = sum(topic == '/odom' for _, topic, _ in msgs)
    assert f'; {odometry} odometry messages received' in summary[0], summary


def test_without_any_transform_scans_are_skipped_once_warned(office_drive, tmp_path):
    # Started with the shipped parameter file: every value in it has the declared type.
    from rclpy.qos import qos_profile_sensor_data
    node = NodeProcess(tmp_path, {'transform_timeout': 0.2, 'warning_period': 300.0},
                       params_file=REPO / 'config' / 'polyline_mapper.yaml')
    peer = Peer('test_peer_no_tf')
    try:
        assert peer.spin_until(lambda: peer.scan_pub.get_subscription_count() > 0
                               and peer.maps, TIMEOUT), node.stderr()
        # The scan input has sensor-data QoS: best effort (the history depth is not carried
        # by DDS discovery, so it is not checked).
        qos = peer.subscription_qos('/scan', timeout=TIMEOUT)
        assert len(qos) == 1 and qos[0].reliability == qos_profile_sensor_data.reliability, qos
        scans = scans_of(drive_messages(office_drive))
        # Scans until the first warning, then three more: all must be skipped, one warned.
        sent = 0
        while not node.lines('[no_tf]') and sent < 100:
            peer.scan_pub.publish(scan_msg(scans[sent], 100.0 + 0.1 * sent))
            sent += 1
            peer.spin_for(0.1)
        for _ in range(3):
            peer.scan_pub.publish(scan_msg(scans[sent], 100.0 + 0.1 * sent))
            sent += 1
            peer.spin_for(0.1)
        # The last scan waits transform_timeout (0.2 s) for its transform: stopped before then
        # it was received and neither used nor skipped (6 received, no_tf 5, once in a full run).
        peer.spin_for(1.0)
        assert node.lines('[no_tf]'), node.stderr()
        assert peer.call('/polyline_mapper_node/save_map', Trigger) is not None
        assert len(peer.maps[-1].segments) == 0 and node.proc.poll() is None
    finally:
        peer.close()
        assert node.stop() == 0
    assert len(node.lines('[no_tf]')) == 1
    got = re.search(r'(\d+) scans received, 0 used .* no_tf (\d+)', node.lines('summary:')[0])
    assert got and int(got[1]) == int(got[2]) >= 4, node.lines('summary:')


def test_the_diagnostics_status_says_lost_first():
    from polyline_mapper.ros.node import mapping_status
    level, message = mapping_status(10, 0, 0, 50, True, '/scan')
    assert level == 1 and message.startswith('lost: scan matching refuses the predicted pose')
    assert mapping_status(10, 0, 0, 50, False, '/scan') == (
        1, '10 scans received, none used (see the warnings)')
    assert mapping_status(10, 8, 2, 50, False, '/scan')[0] == 1
    assert mapping_status(0, 0, 0, 0, False, '/scan') == (0, 'waiting for scans on /scan')
    assert mapping_status(0, 0, 0, 0, False, '/scan', None, 0) == (0, (
        'waiting for scans on /scan: no publisher matched (none yet, or its QoS cannot match)'))
    assert mapping_status(0, 0, 0, 0, False, '/scan', None, 2) == (
        0, 'waiting for scans on /scan: 2 publishers matched, no scan received yet')
    assert mapping_status(10, 10, 0, 50, False, '/scan') == (0, 'mapping')
    # on a saved map, scans that match nothing of it: not localized (dead reckoning)
    level, message = mapping_status(10, 10, 0, 50, False, '/scan', 50, 1, None, None, None,
                                    (12, 1.2))
    assert level == 1 and message.startswith('not localized: the last 12 scans (1.2 s) matched '
                                             'nothing of the saved map')
    # the scans stopped: a node that never used one said OK 'mapping' (node audit)
    assert mapping_status(0, 0, 0, 90, False, '/scan', 0) == (
        1, '90 scans received, none used yet (see the warnings)')
    assert mapping_status(0, 0, 0, 90, False, '/scan', 90) == (0, 'mapping')
    # localizing on a saved map from a wrong place: said once in the log, OK after (audit)
    level, message = mapping_status(10, 10, 0, 50, False, '/scan', 50, 1, None, 0.5)
    assert level == 1 and message.startswith('localizing on the saved map from a wrong place: '
                                             '50 %')
    # the scans stopped
    level, message = mapping_status(0, 0, 0, 50, False, '/scan', 50, 1, 3.25)
    assert level == 1 and message.startswith('no scan on /scan for 3.2 s (50 received before)')


def _last_status(peer):
    """
    Subscribe ``peer`` to /diagnostics; return a function giving the newest status or None.

    Its ``received`` attribute is the list of DiagnosticArray messages so far (to clear).
    """
    from diagnostic_msgs.msg import DiagnosticArray
    diags = []
    peer.node.create_subscription(DiagnosticArray, '/diagnostics', diags.append, 10)

    def last():
        status = [s for d in diags for s in d.status][-1:]
        return status[0] if status else None
    last.received = diags
    return last


def test_the_diagnostics_count_the_scan_publishers_whose_qos_matches(tmp_path):
    # A laser driver that publishes best effort to a node told to subscribe reliably is never
    # matched: no scan arrives, and nothing but rclpy's one warning said why. The node now
    # counts the publishers matched on each input (the middleware's matched event), logs each
    # change and reports the count on /diagnostics, which also says what it is waiting for.
    # (An integration audit: rclpy's warning named the topic 'scan' as given, not as
    # remapped, and the status stayed OK; the node's own warning names the resolved topic,
    # and the status is WARN while the incompatible publisher is all there is.)
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import LaserScan
    node = NodeProcess(tmp_path, {'diagnostics_period': 0.2,
                                  'qos_overrides./scan.subscription.reliability': 'reliable'})
    peer = Peer('test_peer_qos')
    try:
        last = _last_status(peer)
        diags = last.received

        def report():
            """Return the node's last (message, {key: value}) on /diagnostics, or None."""
            status = last()
            return status and (status.message, {kv.key: kv.value for kv in status.values})
        best_effort = peer.node.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
        assert peer.spin_until(lambda: node.lines('[incompatible_qos_scan]'), TIMEOUT), \
            node.stderr()
        assert ('a publisher on /scan offers a QoS this node cannot match (RELIABILITY): none '
                'of its messages arrive; a best-effort publisher needs a best-effort '
                'subscription, the default: remove qos_overrides./scan.subscription.reliability'
                in node.lines('[incompatible_qos_scan]')[0])
        assert best_effort.get_subscription_count() == 0    # (Fast DDS counts matched readers)
        del diags[:]
        assert peer.spin_until(lambda: len(diags) >= 3, TIMEOUT)
        message, values = report()
        assert values['publishers_scan'] == '0' and message == (
            'no scans on /scan: a publisher there offers a QoS this node cannot match '
            '(RELIABILITY); see the incompatible_qos_scan warning')
        assert last().level == DiagnosticStatus.WARN
        for gone in (best_effort, peer.scan_pub):    # (the peer's own is best effort too)
            peer.node.destroy_publisher(gone)       # gone: back to waiting (it stayed WARN)
        del diags[:]
        assert peer.spin_until(lambda: len(diags) >= 3 and last().level == DiagnosticStatus.OK,
                               TIMEOUT), report()
        assert report()[0].startswith('waiting for scans on /scan: no publisher matched')
        assert not node.lines('/scan: 1 publisher matched')
        reliable = peer.node.create_publisher(LaserScan, 'scan', QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE))
        assert node.wait_for_line('/scan: 1 publisher matched', TIMEOUT), node.stderr()
        del diags[:]
        assert peer.spin_until(lambda: len(diags) >= 3, TIMEOUT)
        message, values = report()
        assert values['publishers_scan'] == '1' and message == (
            'waiting for scans on /scan: 1 publisher matched, no scan received yet')
        peer.node.destroy_publisher(reliable)
        assert node.wait_for_line('/scan: 0 publishers matched', TIMEOUT), node.stderr()
    finally:
        peer.close()
        node.stop()


def test_parameters_the_node_does_not_have_are_warned_of(tmp_path):
    # (An integration audit: QoS overrides with a misspelt policy, or for a topic the node
    # does not subscribe to, were taken without a word, and the scans stayed best effort.)
    node = NodeProcess(tmp_path, {'sigma': 0.03, 'scan_matchng': True,
                                  'qos_overrides./scan.subscription.reliabilty': 'reliable',
                                  'qos_overrides./front/scan.subscription.depth': 5,
                                  'qos_overrides./odom.subscription.depth': 5})
    try:
        assert node.wait_for_line('mapping scans on', TIMEOUT), node.stderr()
    finally:
        node.stop()
    warned = node.lines('parameters this node does not have')
    assert len(warned) == 1 and warned[0].endswith(
        'not used: scan_matchng (did you mean scan_matching?), sigma (did you mean '
        'smemsf.sigma?), qos_overrides./front/scan.subscription.depth (this node takes QoS '
        'overrides on: /scan), qos_overrides./odom.subscription.depth (this node takes QoS '
        'overrides on: /scan), '
        'qos_overrides./scan.subscription.reliabilty (did you mean '
        'qos_overrides./scan.subscription.reliability?)'), node.stderr()


def test_a_node_that_mapped_nothing_keeps_the_map_file_there(tmp_path):
    # An audit: a node stopped before its first scan (the laser down at a restart) replaced
    # the last run's map at map_output_path (the default is shared) with an empty one.
    out = tmp_path / 'keep.json'
    out.write_text('{"the last run": "kept"}')
    from nav_msgs.msg import OccupancyGrid
    from polyline_mapper.ros.qos import MAP_QOS
    node = NodeProcess(tmp_path, {'map_output_path': str(out), 'save_map_on_shutdown': True,
                                  'grid_publish_period': 0.1})
    peer = Peer('test_peer_keep')
    try:
        grids = []
        peer.node.create_subscription(OccupancyGrid, 'map', grids.append, MAP_QOS)
        assert peer.wait_for_node(TIMEOUT, node=node), node.stderr()
        assert peer.spin_until(lambda: peer.maps, TIMEOUT)      # the (empty) polyline map
        peer.spin_for(1.0)
        # no planner map before there is one (a 1 x 1 placeholder was published, audit)
        assert grids == []
        resp = peer.call('/polyline_mapper_node/save_map', Trigger)
        assert resp is not None and not resp.success and 'no scan has been mapped' in \
            resp.message
        node.proc.send_signal(signal.SIGTERM)
        assert node.proc.wait(TIMEOUT) == 0, node.stderr()[-3000:]
    finally:
        peer.close()
        node.stop()
    assert out.read_text() == '{"the last run": "kept"}'
    assert node.lines('not writing') and 'Traceback' not in node.stderr()


def test_a_node_reset_after_saving_keeps_the_saved_map_at_shutdown(office_drive, tmp_path):
    # An integration audit: ~/save_map wrote the map, ~/reset cleared it, and the shutdown
    # save then replaced the file with "0 segments in 0 polylines": the guard counted the
    # scans mapped since the start, not since the reset.
    out = tmp_path / 'keep.json'
    node = NodeProcess(tmp_path, {'map_output_path': str(out), 'save_map_on_shutdown': True})
    peer = Peer('test_peer_reset_keep')
    try:
        assert peer.wait_for_node(TIMEOUT, node=node), node.stderr()
        msgs = list(drive_messages(office_drive))
        peer.play(msgs[:[k for k, m in enumerate(msgs) if m[1] == '/scan'][80]], RATE)
        assert peer.spin_until(lambda: peer.maps and len(peer.maps[-1].segments) >= 3,
                               TIMEOUT), node.stderr()[-3000:]
        resp = peer.call('/polyline_mapper_node/save_map', Trigger)
        assert resp is not None and resp.success, node.stderr()[-3000:]
        saved = out.read_text()
        assert json.loads(saved)['segments']
        assert peer.call('/polyline_mapper_node/reset', Trigger).success
        resp = peer.call('/polyline_mapper_node/save_map', Trigger)
        assert resp is not None and not resp.success
        assert 'no scan has been mapped since ~/reset' in resp.message
        node.proc.send_signal(signal.SIGTERM)
        assert node.proc.wait(TIMEOUT) == 0, node.stderr()[-3000:]
    finally:
        peer.close()
        node.stop()
    assert out.read_text() == saved
    assert len(node.lines('not writing')) == 2 and 'Traceback' not in node.stderr()


def test_the_grid_yields_its_topic_to_another_map_publisher(office_drive, tmp_path):
    # An integration audit: beside map_server (AMCL's map) the node's growing grid went out on
    # the same topic every second, and AMCL and the costmaps swap maps at every message.
    from diagnostic_msgs.msg import DiagnosticStatus
    from nav_msgs.msg import OccupancyGrid
    from polyline_mapper.ros.node import STANDING_SECONDS as STANDING
    from polyline_mapper.ros.qos import MAP_QOS
    node = NodeProcess(tmp_path, {'map_publish_period': 0.1, 'grid_publish_period': 0.3,
                                  'diagnostics_period': 0.2, 'warning_period': 300.0})
    peer = Peer('test_peer_map_server')
    try:
        last = _last_status(peer)
        other = peer.node.create_publisher(OccupancyGrid, 'map', MAP_QOS)
        theirs = OccupancyGrid()
        theirs.header.frame_id = 'map'
        theirs.info.width, theirs.info.height, theirs.info.resolution = 7, 5, 0.5
        theirs.data = [0] * 35
        other.publish(theirs)
        assert peer.wait_for_node(TIMEOUT, node=node), node.stderr()
        msgs = list(drive_messages(office_drive))
        peer.play(msgs[:len(msgs) // 2], RATE)
        assert peer.spin_until(lambda: node.lines('[map_topic_shared]'), TIMEOUT), \
            node.stderr()[-3000:]
        assert 'test_peer_map_server also publish(es) on /map' in \
            node.lines('[map_topic_shared]')[0]
        assert peer.spin_until(lambda: last() is not None and last().level ==
                               DiagnosticStatus.WARN and 'planner map topic' in last().message,
                               10.0), last()
        late = Peer('test_peer_map_late')      # gets map_server's map alone
        try:
            grids = []
            late.node.create_subscription(OccupancyGrid, 'map', grids.append, MAP_QOS)
            assert late.spin_until(lambda: grids, 10.0)
            late.spin_for(1.0)
            assert [(g.info.width, g.info.height) for g in grids] == [(7, 5)]
        finally:
            late.close()
        # record-map stored map_server's grid with the node's polylines (an audit): none now
        out = tmp_path / 'recorded.json'
        rec = subprocess.run([sys.executable, '-m', 'polyline_mapper.cli', 'record-map', '-o',
                              str(out), '--once', '--timeout', '20'], capture_output=True,
                             text=True, timeout=120)
        assert rec.returncode == 0 and 'with its planner map' not in rec.stdout, rec.stderr
        assert ('has no grid: /map is also published by /test_peer_map_server' in rec.stderr
                and '--grid-topic polyline_map/grid' in rec.stderr), rec.stderr
        saved = json.loads(out.read_text())
        assert 'grid' not in saved and saved['segments']
        assert saved['stats']['grid_shared_with'] == ['/test_peer_map_server']
        # the scans stopped: the conflict stands (it faded once no new grid was made)
        peer.spin_for(2.0 * STANDING)
        assert last().level == DiagnosticStatus.WARN and 'planner map topic' in last().message
        peer.node.destroy_publisher(other)      # map_server gone: the node's grid again,
        got = []                                # without a new scan
        peer.node.create_subscription(OccupancyGrid, 'map', got.append, MAP_QOS)
        assert peer.spin_until(lambda: any(g.info.width != 7 for g in got), TIMEOUT), \
            node.stderr()[-3000:]
        assert peer.spin_until(lambda: 'planner map topic' not in last().message, 4 * STANDING)
    finally:
        peer.close()
        node.stop()


def test_the_diagnostics_warn_when_the_scans_stop(office_drive, tmp_path):
    # A node audit: with the laser stopped (odometry still coming, the publisher still
    # matched) /diagnostics said OK 'mapping' for as long as it lasted, and nothing was
    # logged, while map -> odom, sent per scan, aged. Now WARN, and a warning in the log.
    from diagnostic_msgs.msg import DiagnosticStatus
    node = NodeProcess(tmp_path, {'diagnostics_period': 0.2})
    peer = Peer('test_peer_silence')
    try:
        last = _last_status(peer)
        assert peer.wait_for_node(TIMEOUT, node=node), node.stderr()
        msgs = list(drive_messages(office_drive))
        scans = [i for i, (_, topic, _) in enumerate(msgs) if topic == '/scan']
        peer.play(msgs[:scans[60]], RATE)
        assert peer.spin_until(lambda: last() is not None and last().message == 'mapping',
                               TIMEOUT), node.stderr()[-2000:]
        assert peer.spin_until(lambda: last().message.startswith('no scan on /scan for'),
                               TIMEOUT), node.stderr()[-2000:]
        status = last()
        assert status.level == DiagnosticStatus.WARN and 'received before' in status.message
        assert node.wait_for_line('[scans_stopped]', TIMEOUT), node.stderr()[-2000:]
    finally:
        peer.close()
        node.stop()


def test_the_summary_counts_the_scans_still_queued_at_shutdown(office_drive, tmp_path):
    # Twelve scans with update_every_n_scans 8: one group mapped, four queued. Stopped without
    # save_map_on_shutdown, the four were received and neither used nor dropped, and the
    # summary did not say where they went (noted with the no-transform test above).
    node = NodeProcess(tmp_path, {
        'update_every_n_scans': 8, 'map_publish_period': 0.1, 'max_scan_latency': 0.0,
        'qos_overrides./scan.subscription.reliability': 'reliable',
        'qos_overrides./scan.subscription.depth': RELIABLE_DEPTH})
    peer = Peer('test_peer_queued', reliable_scans=True)
    try:
        assert peer.wait_for_node(TIMEOUT, node=node), node.stderr()
        msgs = list(drive_messages(office_drive))
        twelfth = [k for k, m in enumerate(msgs) if m[1] == '/scan'][11]
        t0 = peer.play(msgs[:twelfth + 1], RATE) - 11 / RATE
        # the map of the first group (its newest scan the eighth)
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            t0 + 7 / RATE, abs=1e-6), TIMEOUT), node.stderr()[-3000:]
        peer.spin_for(0.5)
    finally:
        peer.close()
        assert node.stop() == 0
    summary = node.lines('summary: ')
    # (in 0 updates: the first groups estimate the noise scale before the map starts)
    assert summary and re.search(r'12 scans received, 8 used in \d+ updates, 0 dropped, 0 '
                                 r'skipped, 4 not mapped at shutdown \(queued\); warnings: none',
                                 summary[-1]), node.stderr()[-3000:]
