"""The node on a saved map over DDS: map_input_path, initial_pose, mapping false; bad starts."""

import json
import time

import numpy as np
from polyline_mapper.cli import main
from polyline_mapper.formats.mapjson import read_map
from polyline_mapper.poses import se2_compose, se2_inverse
from polyline_mapper.recordings import make_drive, SIM_MOUNT
from polyline_mapper.ros.messages import time_msg
import pytest
from rosnode import (assert_refused_in_one_line, map_segments, NodeProcess, Peer, stamp_of,
                     start_refusals)
from std_srvs.srv import Trigger
from test_localization import drifted_messages

pytest.importorskip('tf2_msgs.msg', reason='tf2_msgs is not built (run tools/dev.sh setup)')
pytestmark = [pytest.mark.slow, pytest.mark.dds]
RATE = 20.0
TIMEOUT = 60.0


@pytest.fixture(scope='module')
def office():
    """Return the drive of ``sim:office``, as replay opens it."""
    return make_drive('sim:office')


@pytest.fixture(scope='module')
def saved_map(tmp_path_factory):
    """Map sim:office with true poses (replay); return the MAP.json path."""
    path = tmp_path_factory.mktemp('node_localization') / 'office.json'
    assert main(['replay', 'sim:office', '-o', str(path), '-q']) == 0
    return path


def test_the_node_localizes_on_a_saved_map_and_publishes_it_unchanged(saved_map, office,
                                                                      tmp_path):
    # A robot without a localizer: /tf odom -> base_link drifts (issue 19's model), no map
    # frame; the saved map makes the node its localizer (scan matching, map -> odom), with
    # the defaults: the map and the trajectory are in the map's frame.
    # The robot starts at its true pose (the odometry too), 0.8 m, 6 m from the map's origin.
    out = tmp_path / 'saved.json'
    start = se2_compose(np.asarray(office.poses[0]), se2_inverse(np.asarray(SIM_MOUNT)))
    node = NodeProcess(tmp_path, {'map_input_path': str(saved_map), 'mapping': False,
                                  'initial_pose': [float(v) for v in start],
                                  'map_output_path': str(out),
                                  'map_publish_period': 0.1, 'transform_timeout': 0.3})
    peer = Peer('test_peer_localization')
    try:
        assert peer.wait_for_node(TIMEOUT), 'the node did not come up:\n' + node.stderr()
        messages = [(t, topic, record) for topic, record, t in drifted_messages(office, 1)]
        last = peer.play(messages, RATE)
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            last, abs=1e-6), TIMEOUT), node.stderr()[-3000:]
        loaded = read_map(saved_map).value
        msg = peer.maps[-1]
        assert msg.header.frame_id == 'map'
        assert np.array_equal(map_segments(msg), loaded.segments)
        response = peer.call('/polyline_mapper_node/save_map', Trigger)
        assert response is not None and response.success, node.stderr()[-3000:]
        # ~/reset goes back to the saved map, and says so (it said "map cleared")
        response = peer.call('/polyline_mapper_node/reset', Trigger)
        assert response is not None and response.success, node.stderr()[-3000:]
        assert response.message.startswith(
            f'map reset to the saved map {saved_map} ({len(loaded.segments)} segments; '), \
            response.message
        # localized: the robot stays where it was matched, and the reply says so (an audit)
        assert response.message.endswith('; the robot kept where it was matched)'), \
            response.message
    finally:
        peer.close()
        assert node.stop() == 0
    data = json.loads(out.read_text())
    with open(saved_map) as fh:
        before = json.load(fh)
    for key in ('frame_id', 'segments', 'support', 'polylines', 'closed'):
        assert data[key] == before[key], key
    rows = np.array(data['trajectory'])
    first = last - (len(office.poses) - 1) / RATE
    index = np.round((rows[:, 0] - first) * RATE).astype(int)
    assert len(rows) > 0.9 * len(office.poses) and np.all(np.diff(index) > 0)
    base = se2_compose(np.asarray(office.poses), se2_inverse(np.asarray(SIM_MOUNT)))
    err = rows[:, 1:3] - base[index, :2]          # the trajectory holds the robot base
    rms = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    assert rms <= 0.05, rms
    assert 'localization only' in node.stderr()
    assert data['stats']['scan_matching']['matched'] >= len(rows) - 2


def test_the_node_takes_a_pose_estimate_on_initialpose(saved_map, office, tmp_path):
    # The odometry starts 1.7 m and 0.4 rad from the map's origin and no initial_pose is
    # given: the node matches the first scans onto a wrong place (0.78 m off in replay). After
    # 30 scans an operator gives RViz's "2D Pose Estimate" (its covariance: 0.5 m, 0.26 rad),
    # 0.3 m and 0.15 rad off the truth. One in the odometry frame first: ignored, warned.
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from polyline_mapper.ros.messages import pose_msg
    out = tmp_path / 'saved.json'
    node = NodeProcess(tmp_path, {'map_input_path': str(saved_map), 'mapping': False,
                                  'map_output_path': str(out),
                                  'map_publish_period': 0.1, 'transform_timeout': 0.3})
    peer = Peer('test_peer_estimate')
    estimates = peer.node.create_publisher(PoseWithCovarianceStamped, 'initialpose', 10)
    messages = [(t, topic, record) for topic, record, t in
                drifted_messages(office, 1, odom_origin=(1.5, -0.8, 0.4))]
    split = [k for k, m in enumerate(messages) if m[1] == '/scan'][29] + 1
    base = se2_compose(np.asarray(office.poses), se2_inverse(np.asarray(SIM_MOUNT)))
    try:
        assert peer.wait_for_node(TIMEOUT), 'the node did not come up:\n' + node.stderr()
        assert peer.spin_until(lambda: estimates.get_subscription_count() > 0, TIMEOUT)
        assert peer.node.count_subscribers('/initialpose') == 1      # the node's, reliable
        first = time.time()
        last = peer.play(messages[:split], RATE, t0=first)
        cov = np.diag([0.25, 0.25, 0.06853892326654787])
        for frame in ('odom', 'map'):
            estimates.publish(pose_msg(frame, time_msg(last), base[29] + [0.3, -0.2, 0.15],
                                       cov))
        assert node.wait_for_line('pose estimate (', TIMEOUT), node.stderr()[-3000:]
        last = peer.play(messages[split:], RATE, t0=last + 1.0 / RATE)
        assert peer.spin_until(lambda: peer.maps and stamp_of(peer.maps[-1]) == pytest.approx(
            last, abs=1e-6), TIMEOUT), node.stderr()[-3000:]
        response = peer.call('/polyline_mapper_node/save_map', Trigger)
        assert response is not None and response.success, node.stderr()[-3000:]
    finally:
        peer.close()
        assert node.stop() == 0
    warned = node.lines('skipped pose estimate: at ')
    assert len(warned) == 1 and "in frame 'odom': it must be in 'map'" in warned[0]
    rows = np.array(json.loads(out.read_text())['trajectory'])
    index = np.round((rows[:, 0] - first) * RATE).astype(int)
    err = np.hypot(*(rows[:, 1:3] - base[index, :2]).T)
    assert err[index < 30].mean() > 0.3, err[index < 30]
    late = index >= 40
    assert late.sum() > 0.9 * (len(office.poses) - 40)
    assert np.sqrt(np.mean(err[late] ** 2)) <= 0.05, err[late]


# argv after --ros-args ('{dir}' a scratch folder, '{map}' the saved map) -> the one line says.
CASES = [
    (['-p', 'map_input_path:={dir}/missing.json'],
     ['map_input_path', 'missing.json: no such file']),
    (['-p', 'map_input_path:={dir}/points.json'], ['points.json', 'missing key "frame_id"']),
    (['-p', 'map_input_path:={dir}/binary.json'], ['binary.json: not a readable map JSON']),
    (['-p', 'map_input_path:={dir}'], ['map_input_path', 'not a regular file']),
    (['-p', 'map_input_path:='], ['map_input_path: no value after ":="', 'leave the parameter']),
    (['-p', 'map_input_path:={map}', '-p', 'initial_pose:=[1.0, 2.0]'],
     ['initial_pose must be 3 finite numbers', '[1.0, 2.0]']),
    (['-p', 'map_input_path:={map}', '-p', 'initial_pose:=[.nan, 0.0, 0.0]'],
     ['initial_pose must be 3 finite numbers']),
    (['-p', 'mapping:=maybe'], ['mapping']),
]


@pytest.fixture(scope='module')
def outcomes(saved_map, tmp_path_factory):
    """Start the node once per case (four at a time); return (argv, rc, output) per case."""
    folder = tmp_path_factory.mktemp('start_map')
    (folder / 'points.json').write_text('{"points": [[0, 0], [1, 1]]}')
    (folder / 'binary.json').write_bytes(bytes(range(256)) * 4)
    argvs = [[a.format(dir=folder, map=saved_map) for a in argv] for argv, _ in CASES]
    return start_refusals(argvs, TIMEOUT)


@pytest.mark.parametrize('case', range(len(CASES)), ids=[' '.join(a) for a, _ in CASES])
def test_a_bad_saved_map_or_initial_pose_stops_the_node_with_one_line(outcomes, case):
    assert_refused_in_one_line(outcomes[case], CASES[case][1])


def test_the_node_never_saves_over_the_map_it_started_from(saved_map, office, tmp_path):
    # A new-user audit: with map_output_path the saved map itself (or a link to it) ~/save_map
    # and save_map_on_shutdown replaced it; mapping into it from a wrong start, that was the
    # only copy. The node warns at start, refuses both writes, and exits 1 when the map it was
    # to save on shutdown is not on disk.
    saved = tmp_path / 'office.json'
    saved.write_bytes(saved_map.read_bytes())
    link = tmp_path / 'link.json'
    link.symlink_to(saved)
    before = saved.read_bytes()
    start = se2_compose(np.asarray(office.poses[0]), se2_inverse(np.asarray(SIM_MOUNT)))
    node = NodeProcess(tmp_path, {'map_input_path': str(saved), 'map_output_path': str(link),
                                  'initial_pose': [float(v) for v in start],
                                  'save_map_on_shutdown': True})
    peer = Peer('test_peer_no_overwrite')
    try:
        assert peer.wait_for_node(TIMEOUT), 'the node did not come up:\n' + node.stderr()
        messages = [(t, topic, record) for topic, record, t in drifted_messages(office, 1)]
        peer.play(messages[:200], RATE)
        response = peer.call('/polyline_mapper_node/save_map', Trigger)
        assert response is not None and not response.success, node.stderr()[-3000:]
        assert 'is an input of this run' in response.message
    finally:
        peer.close()
        code = node.stop()
    assert code == 1, node.stderr()[-3000:]
    assert node.lines('map_output_path is the saved map the node starts from'), node.stderr()
    assert saved.read_bytes() == before and link.is_symlink()
